"""Procedure files (TOML) -> validated plans of steps.

A procedure file is what a lab engineer copies from ``procedures/`` and edits. Every value may
carry a unit ("12 V", "2 kg", "3 s", "30 deg"); plain numbers are SI (duties are fractions of
the battery voltage, dimensionless). Every problem is one UserError naming the file, the line
(when it can be found) and the key, raised before any motor moves.

Expanding a procedure gives a `Plan`: a list of `Step` objects. A step is one measurement with
its world (robot on the ground or upside down, wheel set, payload), its duty schedule and its
parameters (copied into the step's record in the run). Operator actions (flip the robot, swap
wheels, place a weight) are not steps: the runner asks for them whenever the next step's
world differs from the current one, which also re-establishes the world after a ``--resume``.
"""

from __future__ import annotations

import difflib
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import numpy as np

from omnibench.errors import UserError
from omnibench.files import read_text
from omnibench.model.units import to_si
from omnibench.procedures.registry import BY_NAME, PROCEDURES

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

MAX_STEP_S = 3600.0   #: longest time a procedure file may give (s)
MAX_COUNT = 1000      #: largest whole number (repetitions) a procedure file may give
MAX_MASS_KG = 100.0   #: heaviest wheel or payload a procedure file may give
MAX_LENGTH_M = 1.0    #: largest tolerance or tape noise a procedure file may give (m)

# --------------------------------------------------------------------------- the plan
@dataclass(frozen=True)
class World:
    """What the operator has set up: robot pose class, wheel set, payload on top (kg)."""

    mode: str = "ground"  # "ground" | "upside_down"
    wheel_set: str = "standard"
    wheel_mass: tuple[float, ...] | None = None  # kg per wheel (4), None: robot's own
    payload: float = 0.0  # kg

    def describe(self) -> str:
        where = "upside down" if self.mode == "upside_down" else "on the ground"
        s = f"robot {where}, wheel set {self.wheel_set!r}"
        if self.wheel_mass is not None:
            s += f" ({format_masses(self.wheel_mass)})"
        if self.payload:
            s += f", payload {self.payload:g} kg"
        return s


def format_masses(m: tuple[float, ...]) -> str:
    if len(set(m)) == 1:
        return f"{m[0]:g} kg per wheel"
    return "/".join(f"{v:g}" for v in m) + " kg"


@dataclass
class Step:
    """One measurement.

    kind: ``hold`` (sweep: hold duties until the wheel speeds are steady, at most max_time),
    ``timed`` (forward/lateral: duties for `duration`, then motors off until at rest; the
    operator measures), ``trajectory`` (energy: a duty schedule). `schedule` is a list of
    (start time s from step start, 4 duties); the last entry lasts until `duration`.
    """

    index: int
    kind: str
    label: str
    world: World
    params: dict[str, Any]
    schedule: list[tuple[float, tuple[float, ...]]]  # 4 duties from each start time
    duration: float  # s of driving (hold: the maximum hold time)
    settle: float = 0.0  # s with motors off after driving (timed/trajectory), or rest before (hold)
    place: bool = False  # ask the operator to put the robot at the start mark first
    measure: str | None = None  # None | "distance" | "displacement"

    @property
    def peak_duty(self) -> float:
        return max((max(abs(u) for u in d) for _, d in self.schedule), default=0.0)

    @property
    def max_time(self) -> float:
        """Upper bound of the step's board time, s."""
        return self.duration + self.settle


@dataclass
class Plan:
    """A procedure expanded into steps, with the settings the runner needs."""

    procedure: str
    path: str
    text: str
    steps: list[Step]
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def max_duration(self) -> float:
        """Upper bound of the driving time (board s), without operator time."""
        return sum(s.max_time for s in self.steps)

    @property
    def peak_duty(self) -> float:
        return max((s.peak_duty for s in self.steps), default=0.0)


# --------------------------------------------------------------------------- file reading
def _line_of(text: str, section: str | None, key: str) -> int | None:
    """1-based line of `key = ...` inside [section] (or [[section]]) of a TOML text."""
    current = None
    for n, line in enumerate(text.splitlines(), start=1):
        head = re.match(r"\s*\[\[?([^\]]+)\]\]?", line)
        if head:
            current = head.group(1).strip()
            continue
        if re.match(rf"\s*{re.escape(key)}\s*=", line) and (section is None or current == section):
            return n
    # keys inside inline tables: `{ heading = ... }`
    for n, line in enumerate(text.splitlines(), start=1):
        if re.search(rf"[{{,]\s*{re.escape(key)}\s*=", line):
            return n
    return None


class ProcedureFile:
    """A parsed procedure file with helpers that fail as `file:line: [section] key: message`."""

    def __init__(self, path: str, text: str) -> None:
        self.path, self.text = path, text
        try:
            self.data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise UserError(f"{path}: not valid TOML: {exc}") from None

    def fail(self, section: str | None, key: str, message: str) -> NoReturn:
        line = _line_of(self.text, section, key)
        where = f"{self.path}:{line}" if line else self.path
        name = f"[{section}] {key}" if section else key
        raise UserError(f"{where}: {name}: {message}")

    def table(self, name: str, required: bool = True) -> dict[str, Any]:
        raw = self.data.get(name)
        if raw is None:
            if required:
                raise UserError(f"{self.path}: missing table [{name}]")
            return {}
        if not isinstance(raw, dict):
            self.fail(None, name, f"[{name}] must be a table")
        return raw

    def check_keys(self, section: str | None, table: dict[str, Any], allowed: list[str]) -> None:
        for k in table:
            if k not in allowed:
                hint = difflib.get_close_matches(k, allowed, n=1)
                self.fail(section, k, "unknown key" + (f" (did you mean {hint[0]}?)" if hint
                                                       else f"; allowed: {', '.join(allowed)}"))

    def quantity(self, section: str | None, table: dict[str, Any], key: str, unit: str,
                 default: Any = None, *, lo: float = -math.inf, hi: float = math.inf,
                 lo_open: bool = False) -> float:
        """A scalar in SI `unit` (strings may carry units); bounds checked. A time is at most
        MAX_STEP_S unless `hi` says otherwise (no step of these procedures lasts an hour)."""
        if unit == "s" and hi == math.inf:
            hi = MAX_STEP_S
        if key not in table:
            if default is None:
                self.fail(section, key, f"missing (a value in {unit})")
            raw = default
        else:
            raw = table[key]
        return self.convert(section, key, raw, unit, lo=lo, hi=hi, lo_open=lo_open)

    def convert(self, section: str | None, key: str, raw: Any, unit: str, *, lo: float = -math.inf,
                hi: float = math.inf, lo_open: bool = False) -> float:
        try:
            v = to_si(raw, unit)
        except ValueError as exc:
            self.fail(section, key, str(exc))
        if not math.isfinite(v):
            self.fail(section, key, f"{raw!r} is not a finite number")
        if v < lo or (lo_open and v <= lo):
            self.fail(section, key, f"must be {'>' if lo_open else '>='} {lo:g} {unit}, got {raw!r}")
        if v > hi:
            self.fail(section, key, f"must be <= {hi:g} {unit}, got {raw!r}")
        return v

    def quantity_list(self, section: str | None, table: dict[str, Any], key: str, unit: str,
                      **bounds: Any) -> list[float]:
        raw = table.get(key)
        if not isinstance(raw, list) or not raw:
            self.fail(section, key, f"expected a non-empty list of values in {unit}")
        return [self.convert(section, key, v, unit, **bounds) for v in raw]

    def integer(self, section: str | None, table: dict[str, Any], key: str, default: int,
                lo: int = 0, hi: int = MAX_COUNT) -> int:
        raw = table.get(key, default)
        if isinstance(raw, bool) or not isinstance(raw, int) or not lo <= raw <= hi:
            self.fail(section, key, f"expected a whole number in {lo}..{hi}, got {raw!r}")
        return raw

    def boolean(self, section: str | None, table: dict[str, Any], key: str, default: bool) -> bool:
        raw = table.get(key, default)
        if not isinstance(raw, bool):
            self.fail(section, key, f"expected true or false, got {raw!r}")
        return raw

    def choices(self, section: str | None, table: dict[str, Any], key: str, allowed: list[str],
                default: list[str]) -> list[str]:
        raw = table.get(key, default)
        if isinstance(raw, str):
            raw = [raw]
        if not isinstance(raw, list) or not raw:
            self.fail(section, key, f"expected a list from {allowed}")
        for v in raw:
            if v not in allowed:
                self.fail(section, key, f"{v!r} is not one of {', '.join(allowed)}")
        return list(raw)


def read_procedure_file(path: str | Path) -> ProcedureFile:
    return ProcedureFile(str(Path(path)), read_text(path, "procedure file"))


#: Default of `[space] max_distance`: the furthest a ground step may take the robot from where
#: it started (m); a lab floor, not a corridor.
DEFAULT_MAX_DISTANCE_M = 3.0


def space_limit(pf: ProcedureFile) -> float:
    """`[space] max_distance` (m): the lab's space for one ground step (default 3 m)."""
    t = pf.table("space", required=False)
    pf.check_keys("space", t, ["max_distance"])
    return pf.quantity("space", t, "max_distance", "m", DEFAULT_MAX_DISTANCE_M, lo=0, lo_open=True,
                       hi=100.0)


# --------------------------------------------------------------------------- shared sections
def telemetry_settings(pf: ProcedureFile) -> dict[str, float]:
    t = pf.table("telemetry", required=False)
    pf.check_keys("telemetry", t, ["rate", "watchdog"])
    return {
        "telemetry_hz": pf.quantity("telemetry", t, "rate", "Hz", 100.0, lo=1, hi=1000),
        "watchdog_s": pf.quantity("telemetry", t, "watchdog", "s", 0.5, lo=0.02, hi=10),
    }


def operator_settings(pf: ProcedureFile) -> dict[str, float]:
    t = pf.table("simulated_operator", required=False)
    pf.check_keys("simulated_operator", t, ["measurement_noise", "seed"])
    return {
        "measurement_noise": pf.quantity("simulated_operator", t, "measurement_noise", "m", 0.002, lo=0, hi=MAX_LENGTH_M),
        "seed": pf.integer("simulated_operator", t, "seed", 1),
    }


def no_slip_settings(pf: ProcedureFile) -> dict[str, float]:
    t = pf.table("no_slip", required=False)
    pf.check_keys("no_slip", t, ["tolerance", "relative_tolerance"])
    return {
        "tolerance": pf.quantity("no_slip", t, "tolerance", "m", 0.01, lo=0, hi=MAX_LENGTH_M),
        "relative_tolerance": pf.quantity("no_slip", t, "relative_tolerance", "1", 0.02, lo=0, hi=1),
    }


def top_keys(pf: ProcedureFile, tables: list[str]) -> None:
    pf.check_keys(None, pf.data, ["procedure", "description", "telemetry", "simulated_operator", "space",
                                  *tables])


def duty_levels(pf: ProcedureFile, section: str, t: dict[str, Any], robot: Robot) -> tuple[list[float], str]:
    """Duty magnitudes from either `duties` (dimensionless) or `voltages` (V) in `section`."""
    if ("duties" in t) == ("voltages" in t):
        pf.fail(section, "duties", "give exactly one of `duties` (fractions of V_batt) or `voltages` (V)")
    if "duties" in t:
        vals = pf.quantity_list(section, t, "duties", "1", lo=0, lo_open=True)
        for v in vals:
            if v > robot.max_duty:
                pf.fail(section, "duties", f"duty {v:.10g} exceeds the robot's max_duty {robot.max_duty:.10g}")
        return vals, "duties"
    vals = pf.quantity_list(section, t, "voltages", "V", lo=0, lo_open=True)
    vmax = robot.max_duty * robot.V_batt
    for v in vals:
        if v > vmax:
            pf.fail(section, "voltages",
                    f"{v:g} V is out of range: the robot allows at most {vmax:g} V "
                    f"(max_duty {robot.max_duty:g} x V_batt {robot.V_batt:g} V)")
    return [v / robot.V_batt for v in vals], "voltages"


DIRECTIONS = {"forward": 1.0, "backward": -1.0}


# --------------------------------------------------------------------------- III.ii / III.iii
def runs_settings(pf: ProcedureFile, section: str, t: dict[str, Any]) -> dict[str, Any]:
    return {
        "duration": pf.quantity(section, t, "duration", "s", None, lo=0, lo_open=True),
        "repetitions": pf.integer(section, t, "repetitions", 1, lo=1),
        "settle": pf.quantity(section, t, "settle", "s", 1.0, lo=0),
    }


def body_velocity_duties(robot: Robot, v: np.ndarray) -> np.ndarray:
    """Open-loop duties (4,) for body velocity v = (v1 m/s, v2 m/s, psi_dot rad/s).

    phi_dot = R v (inverse kinematics, docs/robot-file.md, the model), then the motor's no-load relation
    u = k_e phi_dot / V_batt. Friction is not compensated, so the robot drives somewhat slower
    than asked; the run records the duties actually sent, which is what the model needs.
    """
    from omnibench.model.geometry import inverse_kinematics

    R = inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha)
    return robot.k_e * (R @ np.asarray(v, dtype=float)) / robot.V_batt


# --------------------------------------------------------------------------- limits
def stall_current(robot: Robot, duty: float) -> float:
    """Motor current at stall for `duty`: |u| V_batt / R_a (A): the worst case at a step start."""
    return abs(duty) * robot.V_batt / robot.R_a


def duty_limit(robot: Robot) -> float:
    """Largest |duty| the robot file allows: its max_duty, and the duty whose stall current
    (|u| V_batt / R_a) reaches max_current, whichever is lower."""
    return min(float(robot.max_duty), robot.max_current * robot.R_a / robot.V_batt)


def step_distance_bound(step: Step, robot: Robot, dt: float = 0.01) -> float:
    """Upper bound of how far a ground step takes the robot from where it started, m: the pose
    integrated over the schedule at the body velocity of each entry's no-load wheel speeds
    (u V_batt / k_e: friction only slows the robot), the largest distance from the start."""
    from omnibench.model.geometry import inverse_kinematics

    pinv = np.linalg.pinv(inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha))
    x = y = psi = far = 0.0
    for k, (t0, u) in enumerate(step.schedule):
        t1 = min(step.schedule[k + 1][0] if k + 1 < len(step.schedule) else step.duration, step.duration)
        v1, v2, w = pinv @ (np.asarray(u, dtype=float) * robot.V_batt / robot.k_e)
        n = max(1, int(math.ceil(max(0.0, t1 - t0) / dt)))
        h = max(0.0, t1 - t0) / n
        if abs(w) < 1e-12:  # straight: one stretch
            x += (math.cos(psi) * v1 - math.sin(psi) * v2) * h * n
            y += (math.sin(psi) * v1 + math.cos(psi) * v2) * h * n
            far = max(far, math.hypot(x, y))
            continue
        for _ in range(n):
            mid = psi + 0.5 * w * h
            x += (math.cos(mid) * v1 - math.sin(mid) * v2) * h
            y += (math.sin(mid) * v1 + math.cos(mid) * v2) * h
            psi += w * h
            far = max(far, math.hypot(x, y))
    return far


def check_limits(plan: Plan, robot: Robot, pf: ProcedureFile | None = None) -> None:
    """Refuse (UserError) any step whose duty exceeds max_duty or whose stall current exceeds
    max_current, or a ground step that could drive further than `[space] max_distance`,
    naming the file and the step."""
    where = plan.path
    for s in plan.steps:
        u = s.peak_duty
        if u > robot.max_duty + 1e-12:
            raise UserError(f"{where}: step {s.index} ({s.label}) needs duty {u:.10g} "
                            f"({u * robot.V_batt:.1f} V), above the robot's max_duty {robot.max_duty:.10g}")
        i = stall_current(robot, u)
        if i > robot.max_current + 1e-9:
            raise UserError(f"{where}: step {s.index} ({s.label}) could draw {i:.1f} A at stall, "
                            f"above the robot's max_current {robot.max_current:g} A (the highest duty this "
                            f"robot file allows is {duty_limit(robot):.3f})")
    limit = plan.settings.get("max_distance_m")
    for s in plan.steps:
        if limit is None or s.world.mode != "ground" or not s.schedule:
            continue
        d = step_distance_bound(s, robot)
        if d > limit + 1e-9:
            raise UserError(f"{where}: step {s.index} ({s.label}) could take the robot {d:.3g} m from its start, "
                            f"more than the lab's space ([space] max_distance {limit:g} m): shorten the run or "
                            "lower its speed")


def load_plan(path: str | Path, robot: Robot, expect: str | None = None) -> Plan:
    """Read, validate and expand a procedure file for `robot`; checks the robot's limits.

    `expect`: the procedure the command runs (a sweep file given to `omnibench forward` is an
    error naming the file).
    """
    pf = read_procedure_file(path)
    name = pf.data.get("procedure")
    if name not in PROCEDURES:
        pf.fail(None, "procedure", f"expected one of {', '.join(PROCEDURES)}, got {name!r}")
    if expect is not None and name != expect:
        pf.fail(None, "procedure", f"this file describes {name}, but the command runs {expect}")
    plan = BY_NAME[name].expand(pf, robot)
    plan.settings["max_distance_m"] = space_limit(pf)
    check_limits(plan, robot, pf)
    return plan
