"""Byte-level faults on the simulated wire: drops, corruption, garbage bursts, wrong baud.

A `FaultyWire` sits between the simulated board and the host, one per direction. It is
seeded, and it records which output bytes it touched so tests can check exactly which
frames a correct receiver must still accept.
"""

from __future__ import annotations

import numpy as np

from omnibench.sim.world import FaultConfig


class FaultyWire:
    """One direction of the link with the configured fault rates applied."""

    def __init__(self, config: FaultConfig, rng: np.random.Generator, enabled: bool = True) -> None:
        self.config = config
        self.rng = rng
        self.enabled = enabled and (config.drop > 0 or config.corrupt > 0 or config.garbage > 0
                                    or config.wrong_baud)
        self.wrong_baud = config.wrong_baud
        self.bytes_in = 0
        self.dropped = 0
        self.corrupted = 0
        self.garbage_bytes = 0
        #: input byte offsets that were dropped or corrupted, or before which garbage went in
        self.touched: list[int] = []
        self.record = False

    def pass_bytes_garbled(self, n: int) -> bytes:
        """What a receiver at the wrong speed reads for `n` bytes sent (see pass_bytes)."""
        return bytes(self.rng.integers(1, 256, n, dtype=np.uint8))

    def pass_bytes(self, data: bytes) -> bytes:
        """What arrives at the other end when `data` is sent."""
        start = self.bytes_in
        self.bytes_in += len(data)
        if self.wrong_baud:
            # A receiver at the wrong speed samples the wrong bits: unrelated bytes arrive,
            # about as many as were sent, with no 0x00 framing left intact.
            return self.pass_bytes_garbled(len(data))
        if not self.enabled or not data:
            return data
        c = self.config
        n = len(data)
        r = self.rng.random((3, n))
        drop = r[0] < c.drop
        corrupt = (r[1] < c.corrupt) & ~drop
        garbage = r[2] < c.garbage
        if not (drop.any() or corrupt.any() or garbage.any()):
            return data
        out = bytearray()
        for k, b in enumerate(data):
            if garbage[k]:
                burst = self.rng.integers(1, 256, int(self.rng.integers(1, 17)), dtype=np.uint8)
                out += bytes(burst)
                self.garbage_bytes += len(burst)
                self._touch(start + k)
            if drop[k]:
                self.dropped += 1
                self._touch(start + k)
                continue
            if corrupt[k]:
                nb = (b + int(self.rng.integers(1, 256))) % 256  # always a different byte
                out.append(nb)
                self.corrupted += 1
                self._touch(start + k)
            else:
                out.append(b)
        return bytes(out)

    def _touch(self, offset: int) -> None:
        if self.record:
            self.touched.append(offset)
