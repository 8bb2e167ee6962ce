"""The world the robot is in: on the ground or upside down, payload, wheel sets, extra effects."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Literal

Mode = Literal["ground", "upside_down"]


@dataclass(frozen=True)
class Scenario:
    """What the operator set up. `effects` are terms the world carries beyond the robot's own
    declared ones ({term name: {param: value}}); the simulator uses them, a fit does not know them.
    `wheel_mass` (kg, FL FR RL RR) overrides the robot's when other wheel sets are swapped in."""

    mode: Mode = "ground"
    payload: float = 0.0
    wheel_mass: tuple[float, float, float, float] | None = None
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    #: wheels (1..4) in the order the firmware sends their commands (serial_command_latency);
    #: None: FL, FR, RL, RR
    command_order: tuple[int, int, int, int] | None = None
    #: the known latency of each wheel's command (s, FL FR RL RR) in the firmware that recorded
    #: the run (its packet time and send order), added to any timing terms; None: none known
    command_delays: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.mode not in ("ground", "upside_down"):
            raise ValueError(f"mode must be 'ground' or 'upside_down', not {self.mode!r}")
        if self.payload < 0:
            raise ValueError("payload must not be negative")
        if self.wheel_mass is not None and (len(self.wheel_mass) != 4 or min(self.wheel_mass) <= 0):
            raise ValueError("wheel_mass must be 4 positive masses (kg)")
        if self.command_delays is not None and (len(self.command_delays) != 4 or min(self.command_delays) < 0):
            raise ValueError("command_delays must be 4 latencies >= 0 (s)")


def operator_change(sc: Scenario, mode: str | None = None, payload: float | None = None,
                    wheel_mass: tuple[float, ...] | None = None) -> Scenario:
    """The scenario after an operator action (flip, payload, wheel swap); None keeps a setting."""
    changes: dict[str, Any] = {}
    if mode is not None:
        changes["mode"] = mode
    if payload is not None:
        changes["payload"] = float(payload)
    if wheel_mass is not None:
        changes["wheel_mass"] = tuple(float(m) for m in wheel_mass)
    return replace(sc, **changes)
