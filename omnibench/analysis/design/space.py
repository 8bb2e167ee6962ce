"""The design space: every step the planner may choose, what it costs, and the lab's limits.

A `Candidate` is one *pair* of steps the runner executes: a sweep level in both directions, a
forward run there and back, a lateral run both ways. Pairs keep the robot on its floor space
(each run brings it back) and keep both signs of every speed in the data (diagnosis needs
them: an asymmetric effect is invisible in one direction).

What the lab has is taken from its procedure files (the wheel sets it owns, the payloads it
can place, the settings of steady-state detection, the run durations); what the robot may do
from its robot file (max_duty, max_current); the floor from `Limits`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from omnibench.procedures import World, body_velocity_duties, stall_current

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

#: Operator actions and their default cost in seconds of the operator's (and robot's) time.
DEFAULT_ACTION_COSTS = {"flip": 60.0, "wheels": 180.0, "payload": 20.0, "measure": 30.0}
ACTION_WORDS = {"flip": "flip the robot", "wheels": "swap the wheel set", "payload": "change the payload",
                "measure": "place at the start mark and measure with the tape"}


#: Candidate duty levels (besides the lab's own), capped by the limits.
SWEEP_DUTIES = (0.06, 0.1, 0.15, 0.2, 0.3, 0.45, 0.6, 0.8, 0.95)
FORWARD_DUTIES = (0.2, 0.3, 0.45, 0.6, 0.8)
#: Candidate lateral speeds (m/s) besides the lab's own, up to the highest its file uses.
LATERAL_SPEEDS = (0.2, 0.3, 0.45)


@dataclass(frozen=True)
class Costs:
    """The cost model: one robot second costs `robot_second` s; each operator action its own."""

    actions: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_ACTION_COSTS))
    robot_second: float = 1.0

    def of(self, robot_seconds: float, actions: Mapping[str, int]) -> float:
        """Total cost in seconds."""
        return self.robot_second * robot_seconds + sum(self.actions[k] * n for k, n in actions.items())


@dataclass(frozen=True)
class Limits:
    """Safety limits beyond the robot file's: the floor (m) a run may use, and a duty cap."""

    floor_length: float = 2.5  # m of straight travel available from the start mark
    max_duty: float = 0.95  # fraction of V_batt (also capped by the robot's max_duty and max_current)


@dataclass(frozen=True)
class Candidate:
    """A pair of steps (both directions / both ways) in one world.

    procedure: sweep | forward | lateral. duty: sweep/forward duty magnitude; heading (rad),
    speed (m/s): lateral; duration (s): timed runs' drive time, a sweep level's averaging time
    (its speed is the slope over the last `duration` s of the hold). robot_seconds: board time
    of the pair.
    measurements: tape measurements of the pair (each with a start-mark placement)."""

    procedure: str
    world: World
    duty: float = 0.0
    heading: float = 0.0
    speed: float = 0.0
    duration: float = 0.0
    settle: float = 0.0
    robot_seconds: float = 0.0
    measurements: int = 0

    @property
    def label(self) -> str:
        if self.procedure == "sweep":
            return f"sweep ±{self.duty:.2f} duty over {self.duration:g} s, wheel set {self.world.wheel_set!r}"
        if self.procedure == "forward":
            return f"forward/backward at duty {self.duty:.2f} for {self.duration:g} s"
        return (f"lateral heading {math.degrees(self.heading):.0f} deg both ways at {self.speed:g} m/s "
                f"for {self.duration:g} s, payload {self.world.payload:g} kg")

    def duties(self, robot: Robot) -> list[tuple[float, ...]]:
        """The duties of its two steps."""
        if self.procedure in ("sweep", "forward"):
            return [(self.duty,) * 4, (-self.duty,) * 4]
        out = []
        for h in (self.heading, self.heading + math.pi):
            v = np.array([self.speed * math.cos(h), self.speed * math.sin(h), 0.0])
            out.append(tuple(float(x) for x in body_velocity_duties(robot, v)))
        return out


@dataclass
class Space:
    """Every candidate plus what a file needs to open each world (rest times, base settings)."""

    candidates: list[Candidate]
    #: robot seconds of rest a sweep file adds per direction (before the first level)
    sweep_rest: float = 0.5
    excluded: list[str] = field(default_factory=list)


def duty_cap(robot: Robot, limits: Limits) -> float:
    """Largest duty magnitude allowed: the robot's max_duty, its max_current at stall, our cap."""
    by_current = robot.max_current * robot.R_a / robot.V_batt
    return min(robot.max_duty, by_current, limits.max_duty)


def world_actions(a: World | None, b: World) -> dict[str, int]:
    """Physical operator actions from world a (None: the rest state) to world b: a flip when the
    pose changes, a wheel swap when the wheel set (by name) changes, a payload change."""
    a = a or REST
    out = {"flip": int(a.mode != b.mode), "wheels": int(a.wheel_set != b.wheel_set),
           "payload": int(a.payload != b.payload and b.mode == "ground")}
    if b.mode == "upside_down" and a.payload != 0:
        out["payload"] = 1  # the weights come off before the flip
    return out


#: Where the robot rests between campaigns: on the ground, its own wheels, no payload.
REST = World("ground", "standard", None, 0.0)


def sequence_actions(worlds: list[World], measurements: int = 0, start: World | None = None,
                     end: World | None = REST) -> dict[str, int]:
    """Operator actions of a sequence of step worlds (and tape measurements), from `start` (None:
    the rest state) and back to `end` (None: left as it is)."""
    tot = {"flip": 0, "wheels": 0, "payload": 0, "measure": measurements}
    cur = start
    for w in list(worlds) + ([end] if end is not None and worlds else []):
        if cur is not None and w == cur:
            continue
        for k, n in world_actions(cur, w).items():
            tot[k] += n
        cur = w
    return tot


def sweep_hold(steady: Mapping[str, float], average: float) -> float:
    """Board time (s) a sweep level is held in one direction when its speed is averaged over
    `average` s: min_hold, then the longer of the steady-state window and the average, plus the
    runner's check cadence."""
    return steady.get("min_hold", 0.2) + max(steady.get("window", 0.3), average) + 0.05


def build_space(robot: Robot, *, wheel_sets: list[tuple[str, tuple[float, ...]]], payloads: list[float],
                steady: Mapping[str, float], limits: Limits = Limits(), durations: tuple[float, ...] = (1.5, 3.0),
                settle: float = 1.0, sweep_duties: tuple[float, ...] | None = None,
                forward_duties: tuple[float, ...] | None = None,
                headings_deg: tuple[float, ...] = (0, 30, 45, 60, 90),
                speeds: tuple[float, ...] = (0.2, 0.3, 0.45), average_factors: tuple[float, ...] = (2.0,)) -> Space:
    """The candidates the lab can run, each within the limits (duty, stall current, floor). A sweep
    level is offered with the file's averaging time and `average_factors` times it (the encoder's
    rounding error of the speed falls as average^-1.5, the hold grows by the extra average)."""
    cap = duty_cap(robot, limits)
    average = steady.get("average", 0.3)
    sweep_duties = sweep_duties or SWEEP_DUTIES
    forward_duties = forward_duties or FORWARD_DUTIES
    out: list[Candidate] = []
    excluded: list[str] = []
    for name, masses in wheel_sets:
        world = World("upside_down", name, tuple(masses), 0.0)
        for u in sweep_duties:
            if u > cap + 1e-12:
                excluded.append(f"sweep duty {u:g}: above the duty cap {cap:.2f} (max_duty, max_current at stall)")
                continue
            for f in (1.0, *average_factors):
                avg = round(average * f, 6)
                out.append(Candidate("sweep", world, duty=u, duration=avg, robot_seconds=2 * sweep_hold(steady, avg)))
    ground = World("ground", wheel_sets[0][0] if wheel_sets else "standard", None, 0.0)
    # speed on the ground: the no-load speed u V / k_e r (friction only slows it): floor check
    for d in durations:
        for u in forward_duties:
            if u > cap + 1e-12:
                continue
            travel = u * robot.V_batt / robot.k_e * robot.r * d
            if travel > limits.floor_length:
                excluded.append(f"forward duty {u:g} for {d:g} s: travels up to {travel:.2f} m, more than the "
                                f"floor length {limits.floor_length:g} m")
                continue
            out.append(Candidate("forward", ground, duty=u, duration=d, settle=settle,
                                 robot_seconds=2 * (d + settle), measurements=2))
    for p in payloads:
        world = World("ground", ground.wheel_set, None, float(p))
        for d in durations:
            for h in headings_deg:
                for v in speeds:
                    c = Candidate("lateral", world, heading=math.radians(h), speed=v, duration=d, settle=settle,
                                  robot_seconds=2 * (d + settle), measurements=2)
                    peak = max(max(abs(x) for x in u) for u in c.duties(robot))
                    if peak > cap + 1e-12 or stall_current(robot, peak) > robot.max_current:
                        continue
                    if v * d > limits.floor_length:
                        excluded.append(f"lateral {v:g} m/s for {d:g} s: {v * d:.2f} m, more than the floor length")
                        continue
                    out.append(c)
    return Space(out, sweep_rest=0.5, excluded=excluded)
