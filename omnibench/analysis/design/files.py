"""From the lab's procedure files to a design space, and from a design back to procedure files.

The lab's files (procedures/*.toml or a --procedures folder) say what the lab owns and how it
measures: the wheel sets it can mount, the payloads it can place, the steady-state settings,
the run duration and settle time. A design is written as ordinary procedure files, one per
world (a wheel set upside down; the ground with one payload) and duration (a sweep's: the time
its speeds are averaged over), each a copy of the lab's file with only the levels, directions,
wheel sets, payloads, durations and averaging time replaced; the runner
executes them unchanged (`omnibench sweep --procedure FILE`, ...).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import tomli_w

from omnibench.analysis.design.planner import Unit
from omnibench.analysis.design.space import (
    FORWARD_DUTIES,
    LATERAL_SPEEDS,
    SWEEP_DUTIES,
    Candidate,
    Limits,
    Space,
    build_space,
    sweep_hold,
)
from omnibench.procedures import COMMAND_OF, load_plan

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

FILE_OF = {"sweep": "upside_down_sweep", "forward": "forward_runs", "lateral": "lateral_runs"}


def space_from_files(robot: Robot, files: Mapping[str, str | Path], limits: Limits = Limits()) -> Space:
    """The candidate steps the lab's procedure files allow (their wheel sets and payloads, their
    steady-state and settle settings; durations: the file's, twice and three times it; duties up
    to the highest the files use), within `limits`."""
    sweep = load_plan(files["upside_down_sweep"], robot, expect="upside_down_sweep")
    fwd = load_plan(files["forward_runs"], robot, expect="forward_runs")
    lat = load_plan(files["lateral_runs"], robot, expect="lateral_runs")
    wheel_sets = list(dict.fromkeys((s.world.wheel_set, tuple(s.world.wheel_mass or robot.wheel_mass))
                                    for s in sweep.steps))
    payloads = sorted({s.world.payload for s in lat.steps} | {0.0})
    d = fwd.steps[0].duration if fwd.steps else 1.5
    settle = fwd.steps[0].settle if fwd.steps else 1.0
    # never beyond the highest duty the lab's own files use: the model is tested up to there (on the
    # simulated robot the residuals at 0.95 carry structure the fit then reads as model error)
    top = max([abs(s.peak_duty) for s in sweep.steps + fwd.steps] or [limits.max_duty])
    limits = replace(limits, max_duty=min(limits.max_duty, top))
    sweep_duties = sorted({round(abs(s.params["duty"]), 6) for s in sweep.steps} | set(SWEEP_DUTIES))
    forward_duties = sorted({round(abs(s.params["duty"]), 6) for s in fwd.steps} | set(FORWARD_DUTIES))
    # lateral speeds within the span of the lab's file: faster, the simulated rollers stick under 4 kg and
    # the wheel speeds misfit; slower, on the independent physics a cheap plan's 0.2 m/s pair (the lab's
    # 0.3) put the roller terms 3-4 SE off on every noise draw, and the same heading at 0.3 m/s within 1.7
    file_v = [float(s.params["speed"]) for s in lat.steps] or list(LATERAL_SPEEDS)
    speeds = tuple(sorted({v for v in LATERAL_SPEEDS if min(file_v) - 1e-9 <= v <= max(file_v) + 1e-9}
                          | {round(v, 6) for v in file_v}))
    return build_space(robot, wheel_sets=wheel_sets, payloads=payloads, steady=sweep.settings["steady_state"],
                       limits=limits, durations=(d, 2 * d, 3 * d), settle=settle, sweep_duties=tuple(sweep_duties),
                       forward_duties=tuple(forward_duties), speeds=speeds)


def _read(path: str | Path) -> dict[str, Any]:
    return tomllib.loads(Path(path).read_text(encoding="utf-8"))


def _blocks(units: list[Unit]) -> list[tuple[str, Any, float, list[Unit]]]:
    """Consecutive units that one file can hold: same procedure, world and duration."""
    out: list[tuple[str, Any, float, list[Unit]]] = []
    for u in units:
        c = u.candidate
        key = (c.procedure, c.world, c.duration)
        if out and out[-1][:3] == key:
            out[-1][3].append(u)
        else:
            out.append((c.procedure, c.world, c.duration, [u]))
    return out


def write_procedures(units: list[Unit], files: Mapping[str, str | Path], folder: Path, robot: Robot,
                     prefix: str = "", seed: int = 0) -> list[tuple[str, Path]]:
    """Write the units as procedure files in `folder` (in run order); returns [(procedure, path)].
    Each file is loaded back through the runner's own reader (limits checked) before returning.
    `seed` offsets the simulated operator's seed so that files of later rounds draw new tape noise."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for n, (proc, world, duration, us) in enumerate(_blocks(units), start=1):
        fname = FILE_OF[proc]
        data = _read(files[fname])
        if proc == "sweep":
            masses = list(world.wheel_mass)
            data["wheel_sets"] = [{"name": world.wheel_set,
                                   "wheel_mass": masses[0] if len(set(masses)) == 1 else masses}]
            sw = {k: v for k, v in data.get("sweep", {}).items() if k not in ("duties", "voltages")}
            sw["duties"] = [round(u.candidate.duty, 6) for u in us for _ in range(u.reps)]
            sw["directions"] = ["forward", "backward"]
            sw["order"] = "ascending"
            data["sweep"] = sw
            steady = dict(data.get("steady_state", {}))
            steady["average"] = f"{duration:g} s"
            data["steady_state"] = steady
            what = f"wheel set {world.wheel_set}, {len(sw['duties'])} levels both ways, speeds over {duration:g} s"
        elif proc == "forward":
            runs = {k: v for k, v in data.get("runs", {}).items() if k not in ("duties", "voltages")}
            runs.update({"duties": [round(u.candidate.duty, 6) for u in us for _ in range(u.reps)],
                         "directions": ["forward", "backward"], "duration": f"{duration:g} s", "repetitions": 1})
            data["runs"] = runs
            what = f"{len(runs['duties'])} duties forward and backward for {duration:g} s"
        else:
            runs = dict(data.get("runs", {}))
            runs.update({"duration": f"{duration:g} s", "repetitions": 1, "both_ways": True})
            data["runs"] = runs
            data["payloads"] = [f"{world.payload:g} kg"]
            data["directions"] = [{"heading": f"{math.degrees(u.candidate.heading):g} deg",
                                   "speed": f"{u.candidate.speed:g} m/s"} for u in us for _ in range(u.reps)]
            what = f"{len(data['directions'])} headings both ways, payload {world.payload:g} kg, {duration:g} s"
        data["description"] = f"omnibench plan: {what}"
        if proc != "sweep":
            op = dict(data.get("simulated_operator", {}))
            # a new tape-noise draw per round and file, inside the runner's seed range (0..1000)
            op["seed"] = (int(op.get("seed", 1)) + 31 * seed + n) % 1001
            data["simulated_operator"] = op
        path = folder / f"{prefix}{n:02d}_{fname}.toml"
        header = (f"# Written by `omnibench plan` from {Path(files[fname]).name}: only the levels, directions,\n"
                  "# wheel sets, payloads, durations and the speed's averaging time differ from it. Run it with:\n"
                  f"#   omnibench {COMMAND_OF[fname]} --port PORT --procedure {path.name}\n")
        path.write_text(header + tomli_w.dumps(data), encoding="utf-8")
        load_plan(path, robot, expect=fname)  # the runner must accept it as is
        out.append((fname, path))
    return out


def fixed_grid_units(robot: Robot, files: Mapping[str, str | Path]) -> list[Unit]:
    """The lab's own procedure files (the paper's fixed grid) as design units, in their run order,
    so the design's information and cost model can price them too."""
    out: list[Unit] = []
    sweep = load_plan(files["upside_down_sweep"], robot, expect="upside_down_sweep")
    steady = sweep.settings["steady_state"]
    seen: dict[Candidate, Unit] = {}

    def put(c: Candidate) -> None:
        if c in seen:
            seen[c].reps += 1
        else:
            seen[c] = Unit(c, 1, len(out))
            out.append(seen[c])

    for s in sweep.steps:
        if s.params["direction"] > 0:
            w = s.world
            put(Candidate("sweep", w, duty=abs(s.params["duty"]), duration=steady["average"],
                          robot_seconds=2 * sweep_hold(steady, steady["average"])))
    for fname in ("forward_runs", "lateral_runs"):
        plan = load_plan(files[fname], robot, expect=fname)
        for s in plan.steps:
            if fname == "forward_runs":
                if s.params["direction"] < 0:
                    continue
                c = Candidate("forward", s.world, duty=abs(s.params["duty"]), duration=s.duration, settle=s.settle,
                              robot_seconds=2 * (s.duration + s.settle), measurements=2)
            else:
                if _is_return(plan, s):
                    continue
                h = s.params["heading"]
                c = Candidate("lateral", s.world, heading=h, speed=s.params["speed"], duration=s.duration,
                              settle=s.settle, robot_seconds=2 * (s.duration + s.settle), measurements=2)
            put(c)
    return out


def _is_return(plan: Any, s: Any) -> bool:
    """The reversed half of a both-ways lateral pair (heading + 180 deg of the step before)."""
    prev = plan.steps[s.index - 1] if s.index > 0 else None
    return prev is not None and abs((s.params["heading"] - prev.params["heading"]) - math.pi) < 1e-9


def diagnostic_floor(robot: Robot, files: Mapping[str, str | Path], space: Space) -> list[Candidate]:
    """Steps always run, whatever their information: the lab's sweep levels on its first wheel set
    (low duties show a deadband or Stribeck friction, the spread shows curvature: diagnosis needs
    them, an optimal design alone would keep only the extremes) and one forward pair at the lab's
    middle duty (the fit frees C_r with forward runs; diagnosis reads them for a slope or a
    centre-of-mass offset). The planner leaves out a level at which the model predicts the wheel
    stuck (the lab's ±0.06 at the robot file's friction): the fit reads a level only where the wheel
    turns, so the planner prices it at no information (docs/design.md). Sweep levels are held at
    the longest averaging time the space offers (`_longest_average`)."""
    fixed = [u.candidate for u in fixed_grid_units(robot, files)]
    first = next((c.world.wheel_set for c in fixed if c.procedure == "sweep"), None)
    out = [c for c in fixed if c.procedure == "sweep" and c.world.wheel_set == first]
    # one level on every other wheel set: the load term c is then seen in the sweep itself (the
    # ground runs see it only through c b, together with C_r and the roller terms)
    for ws in dict.fromkeys(c.world for c in fixed if c.procedure == "sweep" and c.world.wheel_set != first):
        out.append(max((c for c in fixed if c.world == ws), key=lambda c: c.duty))
    fwd = [c for c in fixed if c.procedure == "forward"]
    if fwd:
        mid = sorted(fwd, key=lambda c: c.duty)[len(fwd) // 2]
        out.append(next((c for c in space.candidates if c.procedure == "forward" and c.duration == mid.duration
                         and abs(c.duty - mid.duty) < 1e-9), mid))
    return [_longest_average(c, space) if c.procedure == "sweep" else c for c in out if c in space.candidates]


def _longest_average(c: Candidate, space: Space) -> Candidate:
    """The space's twin of a sweep level with the longest averaging time: the floor's levels run
    whatever their information, and a longer average is the cheapest information a level can add
    (the speed's rounding error: 6-13 x the information for 1.55 x the hold at twice the average)."""
    twins = [x for x in space.candidates if x.procedure == "sweep" and x.world == c.world
             and abs(x.duty - c.duty) < 1e-9]
    return max(twins, key=lambda x: x.duration, default=c)
