"""Typed values the board client hands to procedures: identity, samples, pose, link stats.

All physical values are SI (s, A, V, m, rad); times are the BOARD's clock in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Hello:
    """Who the board is (from its HELLO frame)."""

    protocol_version: int
    firmware_version: tuple[int, int, int]
    board_id: int
    boot_id: int                 #: random per boot: a change means the board reset
    counts_per_rev: int          #: encoder counts per wheel revolution
    max_telemetry_rate: int      #: Hz
    capabilities: tuple[str, ...]  #: e.g. ("SIMULATOR", "BATTERY_CURRENT", "MOTOR_CURRENT")

    @property
    def is_simulator(self) -> bool:
        """True for the omnibench simulator (simulator-only messages work)."""
        return "SIMULATOR" in self.capabilities

    @property
    def firmware(self) -> str:
        """Firmware version as "major.minor.patch"."""
        return ".".join(str(v) for v in self.firmware_version)

    def as_dict(self) -> dict:
        """JSON-ready identity (used by `board info --json` and run metadata)."""
        return {
            "protocol_version": self.protocol_version,
            "firmware_version": self.firmware,
            "board_id": f"{self.board_id:08X}",
            "boot_id": f"{self.boot_id:08X}",
            "counts_per_rev": self.counts_per_rev,
            "max_telemetry_rate": self.max_telemetry_rate,
            "capabilities": list(self.capabilities),
        }


@dataclass(frozen=True)
class Sample:
    """One telemetry sample.

    `t` is board time in s since the board booted (32-bit wrap already undone); `seq` is
    the board's frame counter. `ammeter_current` is the external ammeter's reading taken
    right after this sample arrived (NaN when none was taken for this sample).
    """

    t: float
    seq: int
    encoder: tuple[int, int, int, int]                 #: counts, FL FR RL RR
    motor_current: tuple[float, float, float, float]   #: A
    battery_voltage: float                             #: V
    battery_current: float                             #: A (board sensor; 0 if it has none)
    faults: int                                        #: latched fault bits
    duty: tuple[float, float, float, float]            #: duties being applied, [-1, 1]
    ammeter_current: float = math.nan                  #: A, external ammeter (see Board.attach_ammeter)

    def wheel_angles(self, counts_per_rev: int) -> tuple[float, ...]:
        """Wheel angles in rad from the encoder counts."""
        k = 2.0 * math.pi / counts_per_rev
        return tuple(c * k for c in self.encoder)


@dataclass(frozen=True)
class Pose:
    """Ground-truth pose of the simulated robot (the simulated operator's tape measure)."""

    x: float      #: m, world frame
    y: float      #: m
    psi: float    #: rad
    mode: str     #: "ground" or "upside_down"
    t: float      #: board time of the measurement, s


@dataclass
class LinkStats:
    """Counters of link quality since the board was opened."""

    frames: int = 0          #: valid frames received
    telemetry: int = 0       #: telemetry samples received
    lost: int = 0            #: board frames missing (gaps in the board's sequence numbers)
    crc_errors: int = 0      #: chunks with a bad CRC
    framing_errors: int = 0  #: chunks with bad COBS, bad length, unknown id
    retries: int = 0         #: commands sent again because no ACK came
    time_faults: int = 0     #: frames dropped: board time ran backwards or jumped (see Board)
    bytes_in: int = 0
    bytes_out: int = 0
    events: list = field(default_factory=list)  #: (board time, event name, arg)

    def as_dict(self) -> dict:
        """JSON-ready counters."""
        d = dict(self.__dict__)
        d["events"] = [list(e) for e in self.events]
        return d
