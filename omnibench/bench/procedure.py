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
from typing import Any, Callable

import numpy as np

from omnibench.errors import UserError
from omnibench.files import read_text
from omnibench.model.units import to_si

MAX_STEP_S = 3600.0   #: longest time a procedure file may give (s)
MAX_COUNT = 1000      #: largest whole number (repetitions) a procedure file may give
MAX_MASS_KG = 100.0   #: heaviest wheel or payload a procedure file may give
MAX_LENGTH_M = 1.0    #: largest tolerance or tape noise a procedure file may give (m)

PROCEDURES = ("upside_down_sweep", "forward_runs", "lateral_runs", "energy_trajectories")

#: The procedure file a command uses when --procedure is not given.
DEFAULT_FILES = {
    "upside_down_sweep": "upside_down_sweep.toml",
    "forward_runs": "forward_runs.toml",
    "lateral_runs": "lateral_runs.toml",
    "energy_trajectories": "energy_trajectories.toml",
}


# --------------------------------------------------------------------------- the plan
@dataclass(frozen=True)
class World:
    """What the operator has set up: robot pose class, wheel set, payload on top (kg)."""

    mode: str = "ground"  # "ground" | "upside_down"
    wheel_set: str = "standard"
    wheel_mass: tuple[float, float, float, float] | None = None  # kg per wheel, None: robot's own
    payload: float = 0.0  # kg

    def describe(self) -> str:
        where = "upside down" if self.mode == "upside_down" else "on the ground"
        s = f"robot {where}, wheel set {self.wheel_set!r}"
        if self.wheel_mass is not None:
            s += f" ({_fmt_masses(self.wheel_mass)})"
        if self.payload:
            s += f", payload {self.payload:g} kg"
        return s


def _fmt_masses(m: tuple[float, ...]) -> str:
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
    schedule: list[tuple[float, tuple[float, float, float, float]]]
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

    def fail(self, section: str | None, key: str, message: str) -> None:
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


def default_procedure_path(procedure: str) -> Path:
    """The shipped procedure file (procedures/<name>.toml)."""
    from omnibench.resources import data_dir

    return data_dir("procedures") / DEFAULT_FILES[procedure]


def load_plan(path: str | Path, robot: Any, expect: str | None = None) -> Plan:
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
    plan = EXPANDERS[name](pf, robot)
    plan.settings["max_distance_m"] = _space(pf)
    check_limits(plan, robot, pf)
    return plan


#: Default of `[space] max_distance`: the furthest a ground step may take the robot from where
#: it started (m); a lab floor, not a corridor.
DEFAULT_MAX_DISTANCE_M = 3.0


def _space(pf: ProcedureFile) -> float:
    """`[space] max_distance` (m): the lab's space for one ground step (default 3 m)."""
    t = pf.table("space", required=False)
    pf.check_keys("space", t, ["max_distance"])
    return pf.quantity("space", t, "max_distance", "m", DEFAULT_MAX_DISTANCE_M, lo=0, lo_open=True,
                       hi=100.0)


# --------------------------------------------------------------------------- shared sections
def _telemetry(pf: ProcedureFile) -> dict[str, float]:
    t = pf.table("telemetry", required=False)
    pf.check_keys("telemetry", t, ["rate", "watchdog"])
    return {
        "telemetry_hz": pf.quantity("telemetry", t, "rate", "Hz", 100.0, lo=1, hi=1000),
        "watchdog_s": pf.quantity("telemetry", t, "watchdog", "s", 0.5, lo=0.02, hi=10),
    }


def _sim_operator(pf: ProcedureFile) -> dict[str, float]:
    t = pf.table("simulated_operator", required=False)
    pf.check_keys("simulated_operator", t, ["measurement_noise", "seed"])
    return {
        "measurement_noise": pf.quantity("simulated_operator", t, "measurement_noise", "m", 0.002, lo=0, hi=MAX_LENGTH_M),
        "seed": pf.integer("simulated_operator", t, "seed", 1),
    }


def _no_slip(pf: ProcedureFile) -> dict[str, float]:
    t = pf.table("no_slip", required=False)
    pf.check_keys("no_slip", t, ["tolerance", "relative_tolerance"])
    return {
        "tolerance": pf.quantity("no_slip", t, "tolerance", "m", 0.01, lo=0, hi=MAX_LENGTH_M),
        "relative_tolerance": pf.quantity("no_slip", t, "relative_tolerance", "1", 0.02, lo=0, hi=1),
    }


def _top(pf: ProcedureFile, tables: list[str]) -> None:
    pf.check_keys(None, pf.data, ["procedure", "description", "telemetry", "simulated_operator", "space",
                                  *tables])


def _levels(pf: ProcedureFile, section: str, t: dict[str, Any], robot: Any) -> tuple[list[float], str]:
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


_DIRS = {"forward": 1.0, "backward": -1.0}


# --------------------------------------------------------------------------- III.i
def expand_upside_down_sweep(pf: ProcedureFile, robot: Any) -> Plan:
    """III.i: robot upside down; for each wheel set, each direction, each level: hold the duty
    on all four wheels until every wheel speed is steady (see `steady_state`), record it."""
    _top(pf, ["sweep", "wheel_sets", "steady_state", "rest"])
    sw = pf.table("sweep")
    pf.check_keys("sweep", sw, ["duties", "voltages", "directions", "order"])
    levels, given_as = _levels(pf, "sweep", sw, robot)
    directions = pf.choices("sweep", sw, "directions", list(_DIRS), ["forward", "backward"])
    order = sw.get("order", "ascending")
    if order not in ("ascending", "descending", "as_given"):
        pf.fail("sweep", "order", f"expected ascending, descending or as_given, got {order!r}")
    if order == "ascending":
        levels = sorted(levels)
    elif order == "descending":
        levels = sorted(levels, reverse=True)
    sets_raw = pf.data.get("wheel_sets", [{"name": "standard"}])
    if not isinstance(sets_raw, list) or not sets_raw:
        pf.fail(None, "wheel_sets", "expected one or more [[wheel_sets]] tables")
    wheel_sets = []
    for ws in sets_raw:
        if not isinstance(ws, dict):
            pf.fail(None, "wheel_sets", "each [[wheel_sets]] must be a table")
        pf.check_keys("wheel_sets", ws, ["name", "wheel_mass"])
        name = ws.get("name")
        if not isinstance(name, str) or not name:
            pf.fail("wheel_sets", "name", "each wheel set needs a name")
        raw = ws.get("wheel_mass")
        if raw is None:
            masses = tuple(robot.wheel_mass)
        elif isinstance(raw, list):
            if len(raw) != 4:
                pf.fail("wheel_sets", "wheel_mass", "give one mass or four (FL, FR, RL, RR)")
            masses = tuple(pf.convert("wheel_sets", "wheel_mass", v, "kg", lo=0, lo_open=True, hi=MAX_MASS_KG) for v in raw)
        else:
            m = pf.convert("wheel_sets", "wheel_mass", raw, "kg", lo=0, lo_open=True, hi=MAX_MASS_KG)
            masses = (m, m, m, m)
        wheel_sets.append((name, masses))
    ss = pf.table("steady_state", required=False)
    pf.check_keys("steady_state", ss, ["window", "confidence", "noise_factor", "relative_tolerance",
                                       "min_hold", "max_hold", "average"])
    steady = {
        "window": pf.quantity("steady_state", ss, "window", "s", 0.3, lo=0.02, lo_open=True),
        "confidence": pf.quantity("steady_state", ss, "confidence", "1", 0.95, lo=0.5, hi=0.9999),
        "noise_factor": pf.quantity("steady_state", ss, "noise_factor", "1", 2.0, lo=0, lo_open=True),
        "relative_tolerance": pf.quantity("steady_state", ss, "relative_tolerance", "1", 0.01, lo=0),
        "min_hold": pf.quantity("steady_state", ss, "min_hold", "s", 0.2, lo=0),
        "max_hold": pf.quantity("steady_state", ss, "max_hold", "s", 5.0, lo=0, lo_open=True, hi=3600),
        "average": pf.quantity("steady_state", ss, "average", "s", 0.3, lo=0.02, lo_open=True),
    }
    if steady["max_hold"] < steady["min_hold"] + max(steady["window"], steady["average"]):
        pf.fail("steady_state", "max_hold", "must be at least min_hold + window (and min_hold + average)")
    rest_t = pf.table("rest", required=False)
    pf.check_keys("rest", rest_t, ["between_levels", "between_directions"])
    rest_levels = pf.quantity("rest", rest_t, "between_levels", "s", 0.0, lo=0)
    rest_dirs = pf.quantity("rest", rest_t, "between_directions", "s", 0.5, lo=0)
    steps: list[Step] = []
    for set_name, masses in wheel_sets:
        world = World("upside_down", set_name, masses, 0.0)
        for dname in directions:
            sgn = _DIRS[dname]
            for n, u in enumerate(levels):
                duty = sgn * u
                steps.append(Step(
                    index=len(steps), kind="hold",
                    label=f"{set_name} {dname} duty {duty:+.3f} ({duty * robot.V_batt:+.2f} V)",
                    world=world,
                    params={"wheel_set": set_name, "direction": int(sgn), "duty": duty,
                            "voltage": duty * robot.V_batt,
                            **{f"u{j + 1}": duty for j in range(4)},
                            **{f"wheel_mass{j + 1}": masses[j] for j in range(4)}},
                    schedule=[(0.0, (duty, duty, duty, duty))],
                    duration=steady["max_hold"],
                    settle=rest_dirs if n == 0 else rest_levels,
                ))
    return Plan("upside_down_sweep", pf.path, pf.text, steps,
                {**_telemetry(pf), "steady_state": steady, "levels_given_as": given_as})


# --------------------------------------------------------------------------- III.ii / III.iii
def _runs_common(pf: ProcedureFile, section: str, t: dict[str, Any]) -> dict[str, Any]:
    return {
        "duration": pf.quantity(section, t, "duration", "s", None, lo=0, lo_open=True),
        "repetitions": pf.integer(section, t, "repetitions", 1, lo=1),
        "settle": pf.quantity(section, t, "settle", "s", 1.0, lo=0),
    }


def expand_forward_runs(pf: ProcedureFile, robot: Any) -> Plan:
    """III.ii: on the ground, all four wheels at the same duty for a fixed time, forward and
    backward; the operator measures the distance travelled; the encoders' rolling distance
    r * mean(delta phi) is compared with it (the no-slip check: sigma = 0 when driving straight)."""
    _top(pf, ["runs", "no_slip"])
    t = pf.table("runs")
    pf.check_keys("runs", t, ["duties", "voltages", "directions", "duration", "repetitions", "settle"])
    levels, given_as = _levels(pf, "runs", t, robot)
    directions = pf.choices("runs", t, "directions", list(_DIRS), ["forward", "backward"])
    c = _runs_common(pf, "runs", t)
    world = World("ground", "standard", None, 0.0)
    steps: list[Step] = []
    for rep in range(c["repetitions"]):
        for u in levels:
            for dname in directions:
                duty = _DIRS[dname] * u
                steps.append(Step(
                    index=len(steps), kind="timed",
                    label=f"{dname} at duty {duty:+.3f} for {c['duration']:g} s (repetition {rep + 1})",
                    world=world,
                    params={"direction": int(_DIRS[dname]), "duty": duty, "voltage": duty * robot.V_batt,
                            "duration": c["duration"], "repetition": rep + 1, "payload": 0.0,
                            "heading": 0.0 if duty > 0 else math.pi,
                            **{f"u{j + 1}": duty for j in range(4)}},
                    schedule=[(0.0, (duty, duty, duty, duty))],
                    duration=c["duration"], settle=c["settle"], place=True, measure="distance",
                ))
    return Plan("forward_runs", pf.path, pf.text, steps,
                {**_telemetry(pf), "no_slip": _no_slip(pf), "operator": _sim_operator(pf),
                 "levels_given_as": given_as})


def body_velocity_duties(robot: Any, v: np.ndarray) -> np.ndarray:
    """Open-loop duties (4,) for body velocity v = (v1 m/s, v2 m/s, psi_dot rad/s).

    phi_dot = R v (inverse kinematics, design.md §2), then the motor's no-load relation
    u = k_e phi_dot / V_batt. Friction is not compensated, so the robot drives somewhat slower
    than asked; the run records the duties actually sent, which is what the model needs.
    """
    from omnibench.model.geometry import inverse_kinematics

    R = inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha)
    return robot.k_e * (R @ np.asarray(v, dtype=float)) / robot.V_batt


def expand_lateral_runs(pf: ProcedureFile, robot: Any) -> Plan:
    """III.iii: on the ground with lateral speed (rollers turn, sigma != 0), for each payload;
    the operator places each weight and measures the displacement (forward, left)."""
    _top(pf, ["runs", "directions", "payloads", "no_slip"])
    t = pf.table("runs")
    pf.check_keys("runs", t, ["duration", "repetitions", "settle", "both_ways"])
    c = _runs_common(pf, "runs", t)
    both = pf.boolean("runs", t, "both_ways", True)
    dirs_raw = pf.data.get("directions")
    if not isinstance(dirs_raw, list) or not dirs_raw:
        pf.fail(None, "directions", "expected [[directions]] tables with heading and speed")
    directions = []
    for d in dirs_raw:
        if not isinstance(d, dict):
            pf.fail(None, "directions", "each direction must be a table {heading, speed}")
        pf.check_keys("directions", d, ["heading", "speed"])
        heading = pf.quantity("directions", d, "heading", "rad", None, lo=-2 * math.pi, hi=2 * math.pi)
        speed = pf.quantity("directions", d, "speed", "m/s", None, lo=0, lo_open=True)
        directions.append((heading, speed))
    if "payloads" not in pf.data:
        payloads = [0.0]
    else:
        payloads = pf.quantity_list(None, pf.data, "payloads", "kg", lo=0, hi=MAX_MASS_KG)
    steps: list[Step] = []
    for payload in payloads:
        world = World("ground", "standard", None, payload)
        for rep in range(c["repetitions"]):
            for heading, speed in directions:
                for way in ((1.0, -1.0) if both else (1.0,)):
                    h = heading if way > 0 else heading + math.pi
                    v = np.array([speed * math.cos(h), speed * math.sin(h), 0.0])
                    u = tuple(float(x) for x in body_velocity_duties(robot, v))
                    steps.append(Step(
                        index=len(steps), kind="timed",
                        label=(f"heading {math.degrees(h):+.0f} deg at {speed:g} m/s, payload "
                               f"{payload:g} kg (repetition {rep + 1})"),
                        world=world,
                        params={"heading": h, "speed": speed, "v1": v[0], "v2": v[1], "psi_dot": 0.0,
                                "payload": payload, "duration": c["duration"], "repetition": rep + 1,
                                **{f"u{j + 1}": u[j] for j in range(4)}},
                        schedule=[(0.0, u)], duration=c["duration"], settle=c["settle"],
                        place=True, measure="displacement",
                    ))
    return Plan("lateral_runs", pf.path, pf.text, steps,
                {**_telemetry(pf), "no_slip": _no_slip(pf), "operator": _sim_operator(pf)})


# --------------------------------------------------------------------------- IV
TRAJECTORY_KINDS = ("square", "circle", "figure_eight", "spin", "segments")


def trajectory_segments(pf: ProcedureFile, tr: dict[str, Any]) -> list[tuple[float, np.ndarray]]:
    """Body-velocity segments [(duration s, (v1, v2, psi_dot))] of one named trajectory.

    square: four sides driven without turning (forward, left, back, right), side/speed each.
    circle: forward at `speed` while turning at speed/radius: one lap.
    figure_eight: one lap turning left, one turning right.
    spin: turn in place at `yaw_rate` for `duration`.
    segments: explicit list of {v1, v2, psi_dot, duration}.
    """
    kind = tr.get("kind")
    sec = "trajectories"
    if kind not in TRAJECTORY_KINDS:
        pf.fail(sec, "kind", f"expected one of {', '.join(TRAJECTORY_KINDS)}, got {kind!r}")
    allowed = {"square": ["side", "speed"], "circle": ["radius", "speed"],
               "figure_eight": ["radius", "speed"], "spin": ["yaw_rate", "duration"],
               "segments": ["segments"]}[kind]
    pf.check_keys(sec, tr, ["name", "kind", *allowed])
    if kind == "square":
        side = pf.quantity(sec, tr, "side", "m", None, lo=0, lo_open=True)
        v = pf.quantity(sec, tr, "speed", "m/s", None, lo=0, lo_open=True)
        T = side / v
        return [(T, np.array(d)) for d in ([v, 0, 0], [0, v, 0], [-v, 0, 0], [0, -v, 0])]
    if kind in ("circle", "figure_eight"):
        radius = pf.quantity(sec, tr, "radius", "m", None, lo=0, lo_open=True)
        v = pf.quantity(sec, tr, "speed", "m/s", None, lo=0, lo_open=True)
        T = 2 * math.pi * radius / v
        laps = [1.0] if kind == "circle" else [1.0, -1.0]
        return [(T, np.array([v, 0.0, s * v / radius])) for s in laps]
    if kind == "spin":
        w = pf.quantity(sec, tr, "yaw_rate", "rad/s", None)
        T = pf.quantity(sec, tr, "duration", "s", None, lo=0, lo_open=True)
        return [(T, np.array([0.0, 0.0, w]))]
    segs = tr.get("segments")
    if not isinstance(segs, list) or not segs:
        pf.fail(sec, "segments", "expected a list of {v1, v2, psi_dot, duration}")
    out = []
    for s in segs:
        if not isinstance(s, dict):
            pf.fail(sec, "segments", "each segment must be a table {v1, v2, psi_dot, duration}")
        pf.check_keys(sec, s, ["v1", "v2", "psi_dot", "duration"])
        out.append((pf.quantity(sec, s, "duration", "s", None, lo=0, lo_open=True),
                    np.array([pf.quantity(sec, s, "v1", "m/s", 0.0), pf.quantity(sec, s, "v2", "m/s", 0.0),
                              pf.quantity(sec, s, "psi_dot", "rad/s", 0.0)])))
    return out


def expand_energy_trajectories(pf: ProcedureFile, robot: Any) -> Plan:
    """IV: named open-loop trajectories on the ground, duties from the body velocities through
    the inverse kinematics; the battery current is logged for the energy balance."""
    _top(pf, ["trajectories", "run", "ammeter"])
    run_t = pf.table("run", required=False)
    pf.check_keys("run", run_t, ["repetitions", "settle", "payload"])
    reps = pf.integer("run", run_t, "repetitions", 1, lo=1)
    settle = pf.quantity("run", run_t, "settle", "s", 1.0, lo=0)
    payload = pf.quantity("run", run_t, "payload", "kg", 0.0, lo=0, hi=MAX_MASS_KG)
    am = pf.table("ammeter", required=False)
    pf.check_keys("ammeter", am, ["source", "required"])
    source = am.get("source", "board")
    if source not in ("board",):
        pf.fail("ammeter", "source", "only 'board' (the board's battery current sensor) is supported")
    required = pf.boolean("ammeter", am, "required", False)
    trs = pf.data.get("trajectories")
    if not isinstance(trs, list) or not trs:
        pf.fail(None, "trajectories", "expected [[trajectories]] tables with name and kind")
    world = World("ground", "standard", None, payload)
    names = set()
    expanded = []
    for tr in trs:
        if not isinstance(tr, dict):
            pf.fail(None, "trajectories", "each trajectory must be a table")
        name = tr.get("name")
        if not isinstance(name, str) or not name or name in names:
            pf.fail("trajectories", "name", f"each trajectory needs a unique name, got {name!r}")
        names.add(name)
        expanded.append((name, str(tr.get("kind")), trajectory_segments(pf, tr)))
    steps: list[Step] = []
    for rep in range(reps):
        for name, kind, segs in expanded:
            schedule = []
            t0 = 0.0
            for T, v in segs:
                u = tuple(float(x) for x in body_velocity_duties(robot, v))
                schedule.append((t0, u))
                t0 += T
            steps.append(Step(
                index=len(steps), kind="trajectory",
                label=f"{name} ({kind}, {t0:.1f} s, repetition {rep + 1})", world=world,
                params={"trajectory": name, "trajectory_kind": kind, "duration": t0,
                        "repetition": rep + 1, "payload": payload, "n_segments": len(segs),
                        "segments": [[T, *v.tolist()] for T, v in segs]},
                schedule=schedule, duration=t0, settle=settle, place=True, measure=None,
            ))
    return Plan("energy_trajectories", pf.path, pf.text, steps,
                {**_telemetry(pf), "ammeter_required": required, "operator": _sim_operator(pf)})


EXPANDERS: dict[str, Callable[[ProcedureFile, Any], Plan]] = {
    "upside_down_sweep": expand_upside_down_sweep,
    "forward_runs": expand_forward_runs,
    "lateral_runs": expand_lateral_runs,
    "energy_trajectories": expand_energy_trajectories,
}


# --------------------------------------------------------------------------- limits
def stall_current(robot: Any, duty: float) -> float:
    """Motor current at stall for `duty`: |u| V_batt / R_a (A): the worst case at a step start."""
    return abs(duty) * robot.V_batt / robot.R_a


def duty_limit(robot: Any) -> float:
    """Largest |duty| the robot file allows: its max_duty, and the duty whose stall current
    (|u| V_batt / R_a) reaches max_current, whichever is lower."""
    return min(float(robot.max_duty), robot.max_current * robot.R_a / robot.V_batt)


def step_distance_bound(step: Step, robot: Any, dt: float = 0.01) -> float:
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


def check_limits(plan: Plan, robot: Any, pf: ProcedureFile | None = None) -> None:
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
