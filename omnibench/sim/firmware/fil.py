"""ctypes binding of the simavr harness (firmware/sim/fil.c, built as libomnibot_fil.so)."""

from __future__ import annotations

import ctypes
from pathlib import Path

from omnibench.errors import UserError
from omnibench.sim.firmware.build import FIRMWARE_DIR, make, require

F_CPU = 16_000_000
_P, _U64, _I = ctypes.c_void_p, ctypes.c_uint64, ctypes.c_int
_SIGNATURES = {
    "fil_open": ([ctypes.c_char_p, ctypes.c_char_p, _I], _P),
    "fil_close": ([_P], None),
    "fil_run_until": ([_P, _U64], _I),
    "fil_cycles": ([_P], _U64),
    "fil_sleep_cycles": ([_P], _U64),
    "fil_host_write": ([_P, ctypes.c_char_p, _I], _I),
    "fil_host_pending": ([_P], ctypes.c_uint32),
    "fil_host_read": ([_P, ctypes.c_char_p, _P, _I], _I),
    "fil_packets": ([_P, _P, _P, _P, _P, _I], _I),
    "fil_packets_bad": ([_P], ctypes.c_uint32),
    "fil_set_counters": ([_P, _P, _P], None),
    "fil_set_adc_mv": ([_P, _I, ctypes.c_uint32], None),
    "fil_pin7": ([_P], _I),
}


def harness_library(elf: Path) -> Path:
    """libomnibot_fil.so beside the .elf (or in firmware/build), built with make if missing."""
    for cand in (elf.parent / "libomnibot_fil.so", FIRMWARE_DIR / "build" / "libomnibot_fil.so"):
        if cand.exists():
            return cand
    require("fil")
    return make("fil", elf.parent) / "libomnibot_fil.so"


class Harness:
    """One simulated ATmega2560 running `elf`, with the robot's electronics around it."""

    def __init__(self, elf: str | Path) -> None:
        elf = Path(elf)
        if not elf.is_file():
            raise UserError(f"no firmware at {elf} (build it with: make -C firmware)")
        self.lib = ctypes.CDLL(str(harness_library(elf)))
        for name, (args, res) in _SIGNATURES.items():
            fn = getattr(self.lib, name)
            fn.argtypes, fn.restype = args, res
        err = ctypes.create_string_buffer(256)
        self.h = self.lib.fil_open(str(elf).encode(), err, 256)
        if not self.h:
            raise UserError(f"simavr could not load {elf}: {err.value.decode()}")
        self._buf = ctypes.create_string_buffer(65536)
        self._cyc = (ctypes.c_uint64 * 65536)()
        self._pk = [(ctypes.c_uint64 * 4096)(), (ctypes.c_uint8 * 4096)(), (ctypes.c_uint8 * 4096)(),
                    (ctypes.c_uint8 * 4096)()]

    def close(self) -> None:
        if self.h:
            self.lib.fil_close(self.h)
            self.h = None

    def run_until(self, cycle: int) -> int:
        """Run the chip up to `cycle` (it may overshoot to the end of a sleep); returns simavr's state."""
        return self.lib.fil_run_until(self.h, int(cycle))

    @property
    def cycles(self) -> int:
        return self.lib.fil_cycles(self.h)

    @property
    def sleep_cycles(self) -> int:
        return self.lib.fil_sleep_cycles(self.h)

    def host_write(self, data: bytes) -> None:
        self.lib.fil_host_write(self.h, bytes(data), len(data))

    def host_pending(self) -> int:
        return self.lib.fil_host_pending(self.h)

    def host_read(self) -> tuple[bytes, list[int]]:
        """Bytes the firmware sent on UART0 and the cycle each was written."""
        n = self.lib.fil_host_read(self.h, self._buf, self._cyc, 65536)
        return self._buf.raw[:n], list(self._cyc[:n])

    def packets(self) -> list[tuple[int, int, int, int]]:
        """Sabertooth packets (cycle, address, command, value) decoded since the last call."""
        c, a, m, v = self._pk
        n = self.lib.fil_packets(self.h, c, a, m, v, 4096)
        return [(c[i], a[i], m[i], v[i]) for i in range(n)]

    @property
    def packets_bad(self) -> int:
        return self.lib.fil_packets_bad(self.h)

    def set_counters(self, counts, rates) -> None:
        """LS7366R counts (raw counter sense) now and their rates (counts/s)."""
        c = (ctypes.c_double * 4)(*[float(x) for x in counts])
        r = (ctypes.c_double * 4)(*[float(x) for x in rates])
        self.lib.fil_set_counters(self.h, c, r)

    def set_adc_mv(self, channel: int, mv: float) -> None:
        self.lib.fil_set_adc_mv(self.h, channel, int(min(max(mv, 0), 5000)))

    @property
    def drivers_enabled(self) -> bool:
        return bool(self.lib.fil_pin7(self.h))
