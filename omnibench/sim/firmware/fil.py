"""ctypes binding of the simavr harness (firmware/sim/fil.c, built as libomnibot_fil.so)."""

from __future__ import annotations

import ctypes
import math
from pathlib import Path

from omnibench.errors import UserError
from omnibench.sim.firmware.build import FIRMWARE_DIR

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
    "fil_s1_config": ([_P, _I, ctypes.c_char, _I, ctypes.c_double, _I], None),
    "fil_s1_bytes": ([_P, _P, _P, _I], _I),
    "fil_s1_baud": ([_P], ctypes.c_double),
    "fil_counters": ([_P, _P], None),
    "fil_encoder_pins": ([_P, _P], None),
    "fil_set_counters": ([_P, _P, _P], None),
    "fil_set_adc_mv": ([_P, _I, ctypes.c_uint32], None),
    "fil_pin_high": ([_P, ctypes.c_char, _I], _I),
}


def harness_library(elf: Path) -> Path:
    """libomnibot_fil.so beside the .elf (or in firmware/build); UserError saying how to build it."""
    for cand in (elf.parent / "libomnibot_fil.so", FIRMWARE_DIR / "build" / "libomnibot_fil.so"):
        if cand.exists():
            return cand
    raise UserError(f"the simavr harness (libomnibot_fil.so) is not beside {elf} nor in firmware/build: "
                    f"run make -C firmware fil (BUILD={elf.parent} for this firmware)")



AVCC_MV = 5000     #: the ADC's reference (AVCC, as the rig powers the chip), mV
ADC_CODES = 1024   #: the ATmega2560's 10-bit conversion: code = floor(V_in * 1024 / V_ref)


def chip_code_mv(code: int) -> int:
    """The whole millivolts simavr converts to ADC `code` (simavr: floor(mv * 1023 / AVCC))."""
    mv = -(-code * AVCC_MV // (ADC_CODES - 1))  # ceil
    while mv > 0 and (mv - 1) * (ADC_CODES - 1) // AVCC_MV >= code:
        mv -= 1
    return int(mv)

class Harness:
    """One simulated ATmega2560 running `elf`, with the robot's electronics around it."""

    def __init__(self, elf: str | Path) -> None:
        elf = Path(elf)
        if not elf.is_file():
            raise UserError(f"no firmware at {elf} (build it with: make -C firmware)")
        lib = harness_library(elf)
        try:
            self.lib = ctypes.CDLL(str(lib))
            for name in _SIGNATURES:
                getattr(self.lib, name)
        except (OSError, AttributeError) as exc:
            raise UserError(f"cannot load the simavr harness {lib} ({exc}): run make -C firmware fil "
                            f"(an old one is rebuilt; it needs libsimavr)") from None
        for name, (args, res) in _SIGNATURES.items():
            fn = getattr(self.lib, name)
            fn.argtypes, fn.restype = args, res
        err = ctypes.create_string_buffer(256)
        self.h = self.lib.fil_open(str(elf).encode(), err, 256)
        if not self.h:
            raise UserError(f"simavr could not load {elf}: {err.value.decode()}")
        self._buf = ctypes.create_string_buffer(65536)
        self._cyc = (ctypes.c_uint64 * 65536)()
        self._s1 = (ctypes.create_string_buffer(8192), (ctypes.c_uint64 * 8192)())

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

    def s1_config(self, pin: tuple[str, int] | None, baud: float, autobaud: bool) -> None:
        """The drivers' S1 line: a pin (port letter, bit) sampled at `baud`, or None for USART1
        (TX1); with `autobaud` the rate comes from the first 0xAA instead."""
        port, bit = pin or ("D", 3)
        self.lib.fil_s1_config(self.h, 1 if pin else 2, port.encode(), bit, float(baud), int(autobaud))

    def s1_bytes(self) -> list[tuple[int, int]]:
        """(cycle, byte) the drivers received on S1 since the last call."""
        buf, cyc = self._s1
        n = self.lib.fil_s1_bytes(self.h, buf, cyc, 8192)
        return [(cyc[i], buf.raw[i]) for i in range(n)]

    @property
    def s1_baud(self) -> float:
        """The rate the drivers listen at (0: autobauding drivers still wait for 0xAA)."""
        return self.lib.fil_s1_baud(self.h)

    def counters(self) -> dict[str, float]:
        """What the rig saw on the wires (for a diagnosis when the drivers hear nothing)."""
        out = (ctypes.c_double * 7)()
        self.lib.fil_counters(self.h, out)
        keys = ("s1_framing_errors", "s1_wrong_rate_bytes", "pin6_edges", "usart1_bytes", "spi_contention",
                "s1_bytes_lost", "usart1_baud")
        return dict(zip(keys, list(out)))

    def encoder_pins(self, pins) -> None:
        """LS7366R chip i sits on Arduino pin pins[i] (42..49)."""
        self.lib.fil_encoder_pins(self.h, (ctypes.c_int * 4)(*[int(p) for p in pins]))

    def set_counters(self, counts, rates) -> None:
        """The four LS7366R chips' counts (raw counter sense) now and their rates (counts/s)."""
        c = (ctypes.c_double * 4)(*[float(x) for x in counts])
        r = (ctypes.c_double * 4)(*[float(x) for x in rates])
        self.lib.fil_set_counters(self.h, c, r)

    def set_adc_mv(self, channel: int, mv: float) -> None:
        """Put `mv` (AVCC 5 V reference) on analog input `channel` so that the conversion reads
        what the ATmega2560 reads, floor(mv * 1024 / 5000): simavr takes whole millivolts and
        converts with 1023 (one code low at mid-scale), so the rig hands it the smallest whole
        millivolt that simavr converts to the chip's code."""
        code = min(max(math.floor(float(mv) * ADC_CODES / AVCC_MV), 0), ADC_CODES - 1)
        self.lib.fil_set_adc_mv(self.h, channel, chip_code_mv(code))

    def pin_high(self, port: str, bit: int) -> bool:
        """1 if the firmware drives this pin high as an output."""
        return bool(self.lib.fil_pin_high(self.h, port.encode(), bit))
