"""How often does a corrupt frame pass the frame check? Computed, and measured by fuzzing.

`fuzz_frames` sends telemetry frames through a byte-corrupting wire (each byte replaced by
another random byte with probability `byte_error`) into the real deframer and codec, and
counts the frames accepted that the board never sent. `predicted_rate` is the model: a frame
is corrupted with probability 1 - (1 - p)^L (L wire bytes), and a corrupted frame passes a
w-bit CRC with probability about 2^-w (the id and exact-length checks only lower it). A
32-bit check cannot be measured at 1e-10 in a test, so it is measured at a smaller width
(same frames, CRC cut to 8 or 16 bits) where accepts are frequent, the model is checked
there, and scaled by 2^-(32 - w).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from omnibench.link.codec import Codec
from omnibench.link.framing import FrameError
from omnibench.link.spec import CrcSpec, ProtocolSpec, load_protocol

#: narrower catalogue CRCs with the same role, to measure at a width where accepts happen
NARROW = {
    8: CrcSpec("CRC-8/SMBUS", 8, 0x07, 0x00, False, False, 0x00, 0xF4),
    16: CrcSpec("CRC-16/CCITT-FALSE", 16, 0x1021, 0xFFFF, False, False, 0x0000, 0x29B1),
}


@dataclass
class FuzzResult:
    crc: str
    width: int
    frames: int           #: frames sent
    corrupted: int        #: frames with at least one byte changed on the wire
    accepted_bad: int     #: frames accepted (CRC, id and length valid) that were never sent
    accepted_good: int    #: frames accepted intact

    @property
    def rate(self) -> float:
        """Accepted corrupt frames per frame sent."""
        return self.accepted_bad / self.frames


def predicted_rate(wire_bytes: int, byte_error: float, width: int) -> float:
    """Accepted corrupt frames per frame sent: P(frame corrupted) * 2^-width (an upper bound)."""
    return (1.0 - (1.0 - byte_error) ** wire_bytes) * 2.0 ** -width


def spec_with_width(width: int, spec: ProtocolSpec | None = None) -> ProtocolSpec:
    """The protocol with its frame check replaced by a catalogue CRC of `width` bits."""
    spec = spec or load_protocol()
    return spec if spec.crc.width == width else dataclasses.replace(spec, crc=NARROW[width])


def fuzz_frames(n: int, byte_error: float = 0.01, *, width: int | None = None, seed: int = 0,
                batch: int = 2000) -> FuzzResult:
    """Send `n` TELEMETRY frames (random field values) over a wire that replaces each byte
    with probability `byte_error`; count what the host's deframer + codec accept."""
    spec = load_protocol()
    spec = spec_with_width(width or spec.crc.width, spec)
    codec = Codec(spec)
    rng = np.random.default_rng(seed)
    deframer = codec.deframer()
    m = spec.message("TELEMETRY")
    ranges = [(f, f.raw_range) for f in m.fields]
    bad = good = corrupted = 0
    done = 0
    while done < n:
        k = min(batch, n - done)
        frames, bodies = [], set()
        for i in range(k):
            raw = {f.name: (rng.integers(lo, hi + 1, f.count).tolist() if f.count > 1
                            else int(rng.integers(lo, hi + 1))) for f, (lo, hi) in ranges}
            seq = (done + i) & 0xFFFF
            bodies.add(codec.encode_raw("TELEMETRY", seq, raw))
            frames.append(codec.frame_raw("TELEMETRY", seq, raw))
        wire = np.frombuffer(b"".join(frames), dtype=np.uint8).copy()
        hit = rng.random(wire.size) < byte_error
        wire[hit] = (wire[hit] + rng.integers(1, 256, int(hit.sum()))) % 256  # always another byte
        ends = np.cumsum([len(f) for f in frames])
        corrupted += int(np.count_nonzero(np.add.reduceat(hit, np.r_[0, ends[:-1]])))
        for body in deframer.feed(wire.tobytes()):
            try:
                codec.decode_raw(body)
            except FrameError:
                continue  # the host drops it too (unknown id or wrong length)
            if body in bodies:
                good += 1
            else:
                bad += 1
        done += k
    return FuzzResult(spec.crc.name, spec.crc.width, n, corrupted, bad, good)
