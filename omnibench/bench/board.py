"""What the procedures need from a motor board, and nothing about bytes.

`BenchBoard` is the interface the runner drives. `omnibench.bench.link_adapter` implements it
over the board client of omnibench.link (real serial port, `sim://` simulated board, or the
pseudo-terminal of `omnibench sim serve`); tests may pass any object with these methods.
This module imports nothing of the link (the adapter imports it, not the other way round).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol


@dataclass(frozen=True)
class Telemetry:
    """One board sample (SI units). `t` is board time in s (unwrapped), `seq` the frame counter."""

    t: float
    seq: int
    encoder: tuple[int, int, int, int]
    motor_current: tuple[float, float, float, float] | None
    battery_voltage: float | None
    battery_current: float | None
    faults: int
    duty: tuple[float, float, float, float]


class BenchBoard(Protocol):
    """The board as the procedures see it."""

    hello: Mapping[str, Any]  # protocol/firmware version, board id, boot id, counts_per_rev, ...
    is_simulator: bool
    has_battery_current: bool
    has_motor_current: bool

    def configure(self, *, telemetry_hz: float, watchdog_s: float) -> None: ...

    def reset_encoders(self) -> None: ...

    def latched_faults(self) -> int:
        """Fault bits latched on the board now (telemetry on)."""
        ...

    def clear_faults(self) -> None:
        """Clear latched faults; called only after the operator agreed."""
        ...

    def set_duties(self, duties: Sequence[float]) -> float | None:
        """Apply four duties; returns the board time (s) they were applied (None: unknown)."""
        ...

    def stop(self) -> float | None:
        """Stop the motors; returns the board time (s) of the stop (None: unknown)."""
        ...

    def read(self, timeout: float) -> Telemetry:
        """The next telemetry sample (BoardError if none within `timeout` host seconds)."""
        ...

    def discard_pending(self) -> int:
        """Drop telemetry that queued up while the operator worked; returns how many."""
        ...

    def keepalive(self) -> None:
        """Feed the board's watchdog: the runner calls it from its loop as it makes progress."""
        ...

    def sim_set_world(self, *, mode: str | None = None, payload: float | None = None,
                      wheel_mass: Sequence[float] | None = None) -> None: ...

    def sim_truth(self) -> tuple[float, float, float]:
        """True pose (x m, y m, psi rad) of the simulated robot."""
        ...
