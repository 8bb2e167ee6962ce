"""A simulated bench ammeter on its own serial port, speaking SCPI lines.

It measures the true battery current of a `SimBoard`'s robot (plus its own noise and
resolution), independent of the board's current sensor. Commands (one per line, "\n"):

    *IDN?            -> "OMNIBENCH,SIM-AMMETER,<board id hex>,1.0"
    MEAS:CURR:DC?    -> "+1.234500E+00"   (A; also MEASure:CURRent:DC? and READ?)
    *RST, *CLS       -> (no reply)
    SYST:ERR?        -> '0,"No error"' or the oldest queued error
"""

from __future__ import annotations

import threading

import numpy as np

from omnibench.sim.board import SimBoard


class SimAmmeter:
    """SCPI ammeter wired in series with the simulated robot's battery."""

    def __init__(self, board: SimBoard, noise: float = 0.002, lsb: float = 1e-4, seed: int = 0) -> None:
        self.board = board
        self.noise = noise
        self.lsb = lsb
        self.rng = np.random.default_rng(seed + 7919)
        self._in = bytearray()
        self._out = bytearray()
        self._errors: list[str] = []
        self._lock = threading.Lock()

    def feed(self, data: bytes) -> None:
        """Bytes from the host; each complete line is executed."""
        with self._lock:
            self._in += data
            while b"\n" in self._in:
                line, _, rest = bytes(self._in).partition(b"\n")
                self._in = bytearray(rest)
                reply = self.execute(line.decode("ascii", "replace").strip())
                if reply is not None:
                    self._out += (reply + "\n").encode("ascii")

    def take_output(self) -> bytes:
        """Bytes the ammeter has sent."""
        with self._lock:
            data = bytes(self._out)
            self._out.clear()
            return data

    def measure(self) -> float:
        """One reading of the battery current, A."""
        i = self.board.truth()["I_batt"] + self.rng.normal(0.0, self.noise)
        return float(np.round(i / self.lsb) * self.lsb) if self.lsb > 0 else float(i)

    def execute(self, line: str) -> str | None:
        """Reply to one SCPI command line (None: no reply)."""
        cmd = line.upper().replace("MEASURE", "MEAS").replace("CURRENT", "CURR")
        if not cmd:
            return None
        if cmd == "*IDN?":
            return f"OMNIBENCH,SIM-AMMETER,{self.board.world.board_id:08X},1.0"
        if cmd in ("MEAS:CURR:DC?", "MEAS:CURR?", "READ?"):
            return f"{self.measure():+.6E}"
        if cmd in ("*RST", "*CLS"):
            self._errors.clear()
            return None
        if cmd in ("SYST:ERR?", "SYSTEM:ERROR?"):
            return self._errors.pop(0) if self._errors else '0,"No error"'
        self._errors.append('-113,"Undefined header"')
        return None
