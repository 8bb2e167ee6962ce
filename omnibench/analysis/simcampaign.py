"""A measurement campaign simulated straight from the model, read through the same sensor
models and estimators as a real run (for tests, benchmarks and newcomers without a robot).

Sensor models (those of the simulated board, omnibench/sim/world.py): encoder counts are the
floor of phi * counts_per_rev / 2 pi with a random mounting offset per step (so quantisation
is a random error), motor currents carry N(0, 0.01 A) noise and a 1 mA resolution, the battery
voltage N(0, 5 mV), the battery current N(0, 0.01 A); the operator's tape N(0, 2 mm).
Telemetry at 100 Hz; physics at 1 ms.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from omnibench.analysis.observations import (
    DEFAULT_TAPE_SE,
    ENERGY_COLUMNS,
    RUN_COLUMNS,
    STEADY_AVERAGE,
    SWEEP_COLUMNS,
    TRACE_COLUMNS,
    Observations,
    timed_row,
)
from omnibench.analysis.quantisation import encoder_slope_fit, line_fit
from omnibench.model.context import GRAVITY
from omnibench.model.scenario import Scenario
from omnibench.model.simulator import simulate_batch
from omnibench.procedures import REGISTRY

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

TELEMETRY_DT = 0.01  # s
PHYSICS_DT = 1e-3  # s
CURRENT_NOISE = 0.01  # A
CURRENT_LSB = 1e-3  # A
VOLTAGE_NOISE = 0.005  # V
BATTERY_CURRENT_NOISE = 0.01  # A
SWEEP_HOLD = 0.6  # s held per sweep level (the model is steady after ~30 ms upside down)

_FILE_OF = {p.observes: p.name for p in REGISTRY}  # Observations table -> procedure


def _plan(proc: str, robot: Robot, files: Mapping[str, str | Path] | None):
    from omnibench.procedures import default_procedure_path, load_plan

    path = (files or {}).get(proc) or default_procedure_path(_FILE_OF[proc])
    return load_plan(path, robot, expect=_FILE_OF[proc])


def _sensors(rng: np.random.Generator, res, b: int, cpr: float, current: bool, t_cmd, U) -> pd.DataFrame:
    """Recorded trajectory b (commands t_cmd (K,), U (K, 4)) -> a trace as the board would log it."""
    t = res.t
    off = rng.uniform(0, 2 * math.pi, 4)
    k = cpr / (2 * math.pi)
    out = {"t": t}
    idx = np.searchsorted(np.asarray(t_cmd, dtype=float), t + 1e-9, side="right") - 1
    Ub = np.asarray(U, dtype=float)
    for j in range(4):
        out[f"u{j + 1}"] = np.where(idx >= 0, Ub[np.maximum(idx, 0), j], 0.0)
    for j in range(4):
        counts = np.floor((res.signal(f"phi{j + 1}")[b] + off[j]) * k)
        out[f"phi{j + 1}"] = (counts - counts[0]) / k
    for j in range(4):
        if current:
            i = res.signal(f"i{j + 1}")[b] + rng.normal(0, CURRENT_NOISE, len(t))
            out[f"i{j + 1}"] = np.round(i / CURRENT_LSB) * CURRENT_LSB
        else:
            out[f"i{j + 1}"] = np.full(len(t), np.nan)
    out["V_batt"] = res.signal("V_batt")[b] + rng.normal(0, VOLTAGE_NOISE, len(t))
    out["I_batt"] = res.signal("I_batt")[b] + rng.normal(0, BATTERY_CURRENT_NOISE, len(t))
    return pd.DataFrame(out, columns=TRACE_COLUMNS)


def plant_simulator(generator: str = "model") -> Callable:
    """`simulate_batch` of the world generator: "model" (omnibench.model, the fit's own
    simulator) or "independent" (omnibench.worlds.independent: physics written for testing only)."""
    if generator == "model":
        return simulate_batch
    if generator == "independent":
        from omnibench.worlds import independent

        return independent.simulate_batch
    raise ValueError(f"unknown world generator {generator!r}; use model or independent")


def simulated_observations(robot: Robot, *, world_effects: Mapping[str, Mapping[str, float]] | None = None,
                           procedures: Sequence[str] = ("sweep", "forward", "lateral", "energy"),
                           seed: int = 0, current: bool = True, files: Mapping[str, str | Path] | None = None,
                           run_prefix: str = "sim", generator: str = "model") -> Observations:
    """A campaign simulated without board or run files: the shipped procedure files (or `files`:
    procedure -> TOML path) expanded for `robot`, each step simulated by `generator` with
    `world_effects` added to the world, then read through the same sensor models (encoder floor
    quantisation, current noise 0.01 A, tape noise 2 mm) and the same estimators as a real run.
    `current=False` leaves motor currents out of the sweep."""
    return simulate_campaign(robot, world_effects=world_effects or {}, procedures=procedures, seed=seed,
                             current=current, files=files, run_prefix=run_prefix,
                             simulate=plant_simulator(generator))


def simulate_campaign(robot: Robot, *, world_effects: Mapping[str, Mapping[str, float]],
                      procedures: Sequence[str], seed: int, current: bool,
                      files: Mapping[str, str | Path] | None, run_prefix: str,
                      simulate: Callable = simulate_batch) -> Observations:
    """See simulated_observations (`simulate`: the world generator's simulate_batch)."""
    rng = np.random.default_rng(seed)
    cpr = float(robot.counts_per_rev)
    obs = Observations()
    every = int(round(TELEMETRY_DT / PHYSICS_DT))
    for proc in procedures:
        if proc not in _FILE_OF:
            raise ValueError(f"cannot simulate procedure {proc!r}")
        plan = _plan(proc, robot, files)
        rid = f"{run_prefix}-{proc}-{seed}"
        obs.runs[rid] = {"procedure": plan.procedure, "path": None, "status": "complete",
                         "counts_per_rev": cpr, "source": "simulated_observations", "imported": False,
                         "duty_timing": "from_sample"}
        steps = plan.steps
        if proc == "sweep":
            scen = [Scenario(mode="upside_down", wheel_mass=s.world.wheel_mass, effects=world_effects) for s in steps]
            U = np.array([[s.schedule[0][1]] for s in steps])
            # the speed is the slope over the file's last `average` s; a longer average holds the level longer
            average = float(plan.settings["steady_state"]["average"])
            hold = SWEEP_HOLD + max(average - STEADY_AVERAGE, 0.0)
            res = simulate(robot, scen, [0.0], U, hold, dt=PHYSICS_DT, record_every=every)
            rows = []
            for b, s in enumerate(steps):
                tr = _sensors(rng, res, b, cpr, current, [0.0], U[b])
                sel = tr["t"].to_numpy() >= hold - average - 1e-9
                t_win, phi_win = tr["t"].to_numpy()[sel], tr[[f"phi{j}" for j in range(1, 5)]].to_numpy()[sel]
                w, w_se = encoder_slope_fit(t_win, phi_win, cpr)
                _, w_s2 = line_fit(t_win, phi_win)
                obs.windows[(rid, s.index)] = t_win
                n = int(sel.sum())
                masses = s.world.wheel_mass or robot.wheel_mass
                for j in range(4):
                    u = float(s.schedule[0][1][j])
                    cur = tr[f"i{j + 1}"].to_numpy()[sel]
                    rows.append({"run": rid, "step": s.index, "wheel": j + 1, "u": u, "direction": float(np.sign(u)),
                                 "wheel_mass": float(masses[j]), "F_N": float(masses[j]) * GRAVITY,
                                 "omega": float(w[j]), "omega_se": float(w_se[j]),
                                 "current": float(cur.mean()) if current else float("nan"),
                                 "current_se": float(max(cur.std(ddof=1), CURRENT_LSB / math.sqrt(12)) / math.sqrt(n))
                                 if current else float("nan"),
                                 "n": n, "steady": True, "time": (s.index + 1) * hold,
                                 "omega_s2": float(w_s2[j])})
            obs.sweep = pd.DataFrame(rows, columns=SWEEP_COLUMNS)
        elif proc in ("forward", "lateral"):
            scen = [Scenario(mode="ground", payload=s.world.payload, effects=world_effects) for s in steps]
            groups: dict[tuple[float, float], list[int]] = {}
            for b, s in enumerate(steps):
                groups.setdefault((s.duration, s.settle), []).append(b)
            rows = []
            for (dur, settle), idx in groups.items():
                U = np.array([[steps[b].schedule[0][1], (0.0, 0.0, 0.0, 0.0)] for b in idx])
                res = simulate(robot, [scen[b] for b in idx], [0.0, dur], U, dur + settle, dt=PHYSICS_DT,
                                     record_every=every)
                for n, b in enumerate(idx):
                    s = steps[b]
                    tr = _sensors(rng, res, n, cpr, current, [0.0, dur], U[n])
                    x = float(res.signal("x")[n, -1]) + rng.normal(0, DEFAULT_TAPE_SE)
                    y = float(res.signal("y")[n, -1]) + rng.normal(0, DEFAULT_TAPE_SE)
                    if proc == "forward":
                        sign = 1.0 if s.schedule[0][1][0] >= 0 else -1.0
                        fwd, left = sign * abs(math.hypot(x, y)), float("nan")
                    else:
                        fwd, left = x, y
                    obs.traces[(rid, s.index)] = tr
                    rows.append(timed_row(rid, s.index, s.schedule[0][1], dur, dur + settle, s.world.payload,
                                          float(s.params.get("heading", 0.0)), fwd, left, tr, robot, cpr,
                                          time=s.index * (dur + settle)))
            rows.sort(key=lambda r: r["step"])
            setattr(obs, proc, pd.DataFrame(rows, columns=RUN_COLUMNS))
        else:  # energy
            rows = []
            for s in steps:
                t_cmd = [t for t, _ in s.schedule] + [s.duration]
                U = np.array([[d for _, d in s.schedule] + [(0.0, 0.0, 0.0, 0.0)]])
                res = simulate(robot, Scenario(mode="ground", payload=s.world.payload, effects=world_effects),
                                     t_cmd, U, s.duration + s.settle, dt=PHYSICS_DT, record_every=every)
                tr = _sensors(rng, res, 0, cpr, current, t_cmd, U[0])
                obs.traces[(rid, s.index)] = tr
                E = float(np.trapezoid(tr["V_batt"].to_numpy() * tr["I_batt"].to_numpy(), tr["t"].to_numpy()))
                rows.append({"run": rid, "step": s.index, "trajectory": str(s.params.get("trajectory")),
                             "duration": s.duration, "t_total": s.duration + s.settle,
                             "payload": s.world.payload, "measured_J": E, "has_current": True})
            obs.energy = pd.DataFrame(rows, columns=ENERGY_COLUMNS)
    return obs
