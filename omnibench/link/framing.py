"""Framing: COBS byte stuffing with a 0x00 delimiter and a CRC on every frame.

A frame on the wire is `COBS(body + CRC(body)) + b"\\x00"`; `body` is header + payload; the
CRC (width/8 bytes, little-endian) is the one the protocol description names.
Because 0x00 never appears inside an encoded frame, a receiver that sees garbage simply
waits for the next 0x00 and starts again: it resynchronises within one frame.
"""

from __future__ import annotations

import binascii
from dataclasses import dataclass

from cobs import cobs
from crc import Calculator, Configuration

from omnibench.link.spec import CrcSpec

DELIMITER = b"\x00"


class FrameError(ValueError):
    """A chunk between delimiters that is not a valid frame (bad COBS, length or CRC)."""


class Crc:
    """A CRC calculator built from a `CrcSpec` (the `crc` package does the arithmetic).

    The constructor verifies the spec's check value (CRC of b"123456789"), so a mistyped
    description fails loudly instead of producing frames no board accepts.
    """

    def __init__(self, spec: CrcSpec) -> None:
        self.spec = spec
        self.size = spec.width // 8
        config = Configuration(
            width=spec.width,
            polynomial=spec.poly,
            init_value=spec.init,
            final_xor_value=spec.xorout,
            reverse_input=spec.refin,
            reverse_output=spec.refout,
        )
        self._calc = Calculator(config, optimized=True)
        # Two catalogue variants have a C implementation in the standard library:
        # CRC-16/CCITT-FALSE is binascii.crc_hqx with init 0xFFFF, CRC-32/ISO-HDLC is
        # binascii.crc32. Any other variant uses the `crc` package. Both paths must give the
        # description's check value.
        p = (spec.width, spec.poly, spec.init, spec.refin, spec.refout, spec.xorout)
        self._fast = {(16, 0x1021, 0xFFFF, False, False, 0): "hqx",
                      (32, 0x04C11DB7, 0xFFFFFFFF, True, True, 0xFFFFFFFF): "crc32"}.get(p)
        for fast in ((True, False) if self._fast else (False,)):
            got = self._checksum(b"123456789", fast)
            if got != spec.check:
                raise ValueError(f"CRC {spec.name}: check value is 0x{got:X}, description says 0x{spec.check:X}")

    def _checksum(self, data: bytes, fast: bool) -> int:
        if fast and self._fast == "hqx":
            return binascii.crc_hqx(data, self.spec.init)
        if fast and self._fast == "crc32":
            return binascii.crc32(data)
        return int(self._calc.checksum(data))

    def checksum(self, data: bytes) -> int:
        """CRC of `data` as an integer."""
        return self._checksum(data, self._fast is not None)

    def append(self, body: bytes) -> bytes:
        """`body` followed by its CRC, little-endian."""
        return body + self.checksum(body).to_bytes(self.size, "little")

    def strip(self, data: bytes) -> bytes:
        """Check and remove the trailing CRC; FrameError if it does not match."""
        if len(data) <= self.size:
            raise FrameError("frame shorter than its CRC")
        body, tail = data[: -self.size], data[-self.size :]
        if self.checksum(body) != int.from_bytes(tail, "little"):
            raise FrameError("CRC mismatch")
        return body


def encode_frame(body: bytes, crc: Crc) -> bytes:
    """Wire bytes of one frame: COBS(body + CRC) followed by the 0x00 delimiter."""
    return cobs.encode(crc.append(body)) + DELIMITER


def decode_chunk(chunk: bytes, crc: Crc) -> bytes:
    """Body of one frame from the bytes between two delimiters (FrameError if invalid)."""
    try:
        data = cobs.decode(chunk)
    except cobs.DecodeError as exc:
        raise FrameError(f"bad COBS: {exc}") from exc
    return crc.strip(data)


@dataclass
class DeframerStats:
    """Counters of what a Deframer saw, for link-quality reports."""

    frames: int = 0          #: valid frames delivered
    crc_errors: int = 0      #: chunks that decoded but failed the CRC
    framing_errors: int = 0  #: chunks with bad COBS, too short or too long
    bytes_in: int = 0        #: bytes fed in total


class Deframer:
    """Splits a byte stream into frame bodies; counts and drops everything invalid.

    Feed it bytes as they arrive (any chunking); `feed` returns the bodies of the complete
    valid frames. Of a chunk longer than `max_frame_bytes` (decoded) only the tail is kept,
    so garbage with no delimiter cannot grow memory.
    """

    def __init__(self, crc: Crc, max_frame_bytes: int = 254, frame_sizes: set[int] | None = None) -> None:
        self.crc = crc
        # Decoded sizes (body + CRC) of the protocol's messages: when a chunk is bad, a
        # suffix of exactly such a size may still be an intact frame that line noise
        # (garbage without a delimiter) was glued onto. Checking those few suffixes
        # recovers that frame, so the stream really resynchronises within one frame.
        self.frame_sizes = sorted(frame_sizes or (), reverse=True)
        self.max_encoded = max_frame_bytes + max_frame_bytes // 254 + 1
        self.stats = DeframerStats()
        self._buf = bytearray()
        self._overflow = False
        self._unsynced = False

    def resync(self) -> None:
        """Start again mid-stream (the port opened, or its input was flushed, while the other
        side was sending): the bytes up to the next delimiter may be the tail of a frame. That
        first chunk is delivered if it is a whole valid frame and otherwise dropped without
        counting a CRC or framing error: the link did not corrupt it, the reader came in late."""
        self._buf.clear()
        self._overflow = False
        self._unsynced = True

    def feed(self, data: bytes) -> list[bytes]:
        """Consume `data`; return the bodies (header + payload) of valid frames completed."""
        out: list[bytes] = []
        self.stats.bytes_in += len(data)
        start = 0
        while True:
            end = data.find(0, start)
            if end < 0:
                self._append(data[start:])
                return out
            self._append(data[start:end])
            chunk, overflow = bytes(self._buf), self._overflow
            self._buf.clear()
            self._overflow = False
            start = end + 1
            if self._unsynced and not overflow:
                self._unsynced = False
                try:
                    out.append(decode_chunk(chunk, self.crc))
                    self.stats.frames += 1
                except FrameError:
                    pass  # the tail of a frame sent before this reader started
                continue
            self._unsynced = False
            if overflow:
                # Too long to be one frame: count it, but its tail may be an intact frame
                # whose leading delimiter was lost.
                self.stats.framing_errors += 1
                body = self._salvage(chunk)
                if body is not None:
                    out.append(body)
                    self.stats.frames += 1
            elif chunk:
                try:
                    out.append(decode_chunk(chunk, self.crc))
                    self.stats.frames += 1
                except FrameError as exc:
                    if "CRC" in str(exc):
                        self.stats.crc_errors += 1
                    else:
                        self.stats.framing_errors += 1
                    body = self._salvage(chunk)
                    if body is not None:
                        out.append(body)
                        self.stats.frames += 1

    def _salvage(self, chunk: bytes) -> bytes | None:
        """An intact frame at the end of a bad chunk (garbage glued before it), if any."""
        for n in self.frame_sizes:
            enc = n + 1 + n // 254
            if len(chunk) > enc:
                try:
                    body = decode_chunk(chunk[-enc:], self.crc)
                except FrameError:
                    continue
                if len(body) + self.crc.size == n:
                    return body
        return None

    def _append(self, data: bytes) -> None:
        """Buffer bytes of the current chunk; beyond a frame's size keep only the tail."""
        self._buf += data
        if len(self._buf) > self.max_encoded:
            del self._buf[: len(self._buf) - self.max_encoded]
            self._overflow = True
