"""A simulated measurement campaign for diagnosis tests and benchmarks (seeded, no serial link).

`simulated_campaign(robot, world_effects, seed=..., procedures=...)` returns the fit engineer's
`Observations`:

- sweep / forward / lateral / energy: `simcampaign.simulated_observations` (the shipped procedure files,
  or `files`), i.e. the model run over every step with the simulated board's sensor models:
  encoder counts floored at 980 counts/rev with a random mounting offset, motor current noise
  0.01 A (1 mA resolution), battery voltage 5 mV, battery current 0.01 A, tape 2 mm.
- step_response: a square wave on all four wheels with the robot upside down, simulated as
  one continuous run (so slow states such as winding temperature carry from step to step),
  sampled at irregular intervals like the 2019 logs (`SquareWave`), encoder counts floored;
  motor currents logged only when `SquareWave.current`.

The world carries `world_effects` ({effect: {param: value}}) that the declared model may not.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from omnibench.analysis.observations import STEP_RESPONSE_COLUMNS, TRACE_COLUMNS, Observations
from omnibench.analysis.simcampaign import plant_simulator, simulated_observations
from omnibench.model.scenario import Scenario
from omnibench.model.simulator import simulate_batch

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

CURRENT_NOISE = 0.01  # A, as the simulated board
CURRENT_LSB = 1e-3  # A


@dataclass(frozen=True)
class SquareWave:
    """The step-response experiment: duties cycled every `half_period` s for `duration` s."""

    duties: tuple[float, ...] = (0.8, -0.8)
    half_period: float = 1.0
    duration: float = 12.0
    sample_dt: float = 0.03  # s, mean logging interval
    jitter: float = 0.01  # s, +/- uniform jitter of the interval (the 2019 logs: 17-45 ms)
    current: bool = False


#: Short procedure files for simulated diagnosis campaigns (the shipped ones are for the lab).
SHORT_FILES = {"energy": Path(__file__).with_name("campaigns") / "energy_short.toml"}


@dataclass(frozen=True)
class CampaignSpec:
    """Which experiments a campaign runs (procedure tables, and a square wave or none)."""

    procedures: tuple[str, ...] = ("sweep",)
    step_response: SquareWave | None = None
    short: bool = True  # use SHORT_FILES where one exists


#: The campaign that reveals each library effect: the procedure its physics shows in (docs/effects.md),
#: kept small so a diagnosis runs in seconds. Used by the tests and benchmarks/diagnose.py.
REVEALING: dict[str, CampaignSpec] = {
    "stribeck_friction": CampaignSpec(("sweep",)),
    "driver_deadband": CampaignSpec(("sweep",)),
    "asymmetric_coulomb": CampaignSpec(("sweep",)),
    "per_wheel_friction": CampaignSpec(("sweep",)),
    "quadratic_drag": CampaignSpec(("sweep",)),
    "battery_resistance": CampaignSpec(("sweep",)),
    "cogging_torque": CampaignSpec((), SquareWave(duties=(0.3, -0.3), half_period=1.0, duration=6.0)),
    # fast full-voltage reversals heat the windings; logged at 10 Hz so the encoder's
    # finite-difference noise stays below the thermal drift
    "winding_heating": CampaignSpec((), SquareWave(duties=(1.0, -1.0), half_period=0.25, duration=12.0,
                                                   sample_dt=0.1, jitter=0.02)),
    "com_offset": CampaignSpec(("forward",)),
    # forward runs alone cannot tell a slope from direction-asymmetric gearbox friction
    # (test_diagnose: reported as ambiguous); the upside-down sweep separates them
    "floor_slope": CampaignSpec(("sweep", "forward")),
    "quiescent_current": CampaignSpec(("sweep", "energy")),
    # command timing: reversals logged every 20 ± 5 ms (the 2019 Arduino loop)
    **{name: CampaignSpec((), SquareWave(duties=(0.5, -0.5), half_period=0.25, duration=4.0, sample_dt=0.02,
                                         jitter=0.005))
       for name in ("command_latency", "serial_command_latency", "per_wheel_latency", "actuator_lag")},
}

#: Campaigns for clean-world (no undeclared effect) checks: together they exercise every candidate.
CLEAN: tuple[CampaignSpec, ...] = (
    CampaignSpec(("sweep",)),
    CampaignSpec(("forward", "energy")),
    CampaignSpec((), SquareWave(duties=(0.3, -0.3), half_period=1.0, duration=6.0)),
)


_SWEEP = CampaignSpec(("sweep",))

#: Alternative forms of library effects, as the independent world generator writes them
#: (omnibench/worlds/independent.py): label "effect:form" -> (campaign, world, true values of
#: the fitted parameters that the library's form shares; {} when the forms share none).
FORMS: dict[str, tuple[CampaignSpec, dict, dict]] = {
    "stribeck_friction:exponential decay": (
        _SWEEP, {"stribeck_friction": {"b_s": 0.25, "w_s": 1.0, "c_s": 0.01, "shape": 1.0}},
        {"stribeck_friction.b_s": 0.25}),
    "stribeck_friction:w_s 0.5 rad/s": (
        _SWEEP, {"stribeck_friction": {"b_s": 0.25, "w_s": 0.5, "c_s": 0.01, "shape": 2.0}},
        {"stribeck_friction.b_s": 0.25}),
    "driver_deadband:cut": (_SWEEP, {"driver_deadband": {"u_0": 0.08, "cut": 1.0}}, {"driver_deadband.u_0": 0.08}),
    "asymmetric_coulomb:scaling with load": (_SWEEP, {"asymmetric_coulomb": {"db": 0.06}}, {"asymmetric_coulomb.db": 0.06}),
    "battery_resistance:growing with current": (_SWEEP, {"battery_resistance": {"R_b": 0.3, "k_i": 0.02}}, {}),
    "winding_heating:tau_th 8 s": (
        REVEALING["winding_heating"], {"winding_heating": {"theta": 25.0, "tau_th": 8.0, "alpha_cu": 0.00393}}, {}),
}

#: Two effects at once: label "pair:a+b" -> (campaign, world).
PAIRS: dict[str, tuple[CampaignSpec, dict]] = {
    "pair:battery_resistance+stribeck_friction": (
        _SWEEP, {"battery_resistance": {"R_b": 0.3}, "stribeck_friction": {"b_s": 0.25, "w_s": 1.0, "c_s": 0.01}}),
    "pair:driver_deadband+quadratic_drag": (
        _SWEEP, {"driver_deadband": {"u_0": 0.03, "w_u": 0.002}, "quadratic_drag": {"d_q": 1.5e-3}}),
    "pair:floor_slope+per_wheel_friction": (
        CampaignSpec(("sweep", "forward")),
        {"floor_slope": {"theta_s": 0.0175, "psi_s": 0.0},
         "per_wheel_friction": {"db_1": 0.0, "db_2": 0.08, "db_3": -0.06, "db_4": 0.05,
                                "da_1": 0.0, "da_2": 0.003, "da_3": -0.002, "da_4": 0.0}}),
}

#: Effects outside the library (independent generator only): label -> (campaign, world).
OUT_OF_LIBRARY: dict[str, tuple[CampaignSpec, dict]] = {
    "outside:wheel 1 radius 3 % small": (CampaignSpec(("sweep", "forward")), {"wheel_radius": {"wheel": 1, "scale": 0.97}}),
    "outside:bent axle on wheel 2": (_SWEEP, {"bent_axle": {"wheel": 2, "amplitude": 0.6}}),
    "outside:wheel 4 radius 5 % large": (CampaignSpec(("forward", "lateral")), {"wheel_radius": {"wheel": 4, "scale": 1.05}}),
    # (a set screw slipping on its shaft, `set_screw`, is in the generator but these campaigns
    # cannot see it: the wheels need little torque once rolling)
}


def campaign(robot: Robot, spec: CampaignSpec, world_effects: Mapping[str, Mapping[str, float]] | None = None, *,
             seed: int = 0, generator: str = "model") -> Observations:
    """`simulated_campaign` for a CampaignSpec."""
    files = {k: v for k, v in SHORT_FILES.items() if k in spec.procedures} if spec.short else None
    return simulated_campaign(robot, world_effects, seed=seed, procedures=spec.procedures,
                              step_response=spec.step_response, files=files, generator=generator)


def simulated_campaign(robot: Robot, world_effects: Mapping[str, Mapping[str, float]] | None = None, *,
                       seed: int = 0, procedures: Sequence[str] = ("sweep",),
                       step_response: SquareWave | None = None, current: bool = True,
                       files: Mapping[str, str | Path] | None = None, generator: str = "model") -> Observations:
    """Observations of a campaign on a simulated robot whose world carries `world_effects`.

    procedures: any of sweep, forward, lateral, energy (the shipped procedure files or `files`);
    step_response: add a square-wave run. current: log motor currents in the sweep.
    generator: "model" (the fit's own simulator) or "independent" (omnibench.worlds.independent)."""
    world = {k: dict(v) for k, v in (world_effects or {}).items()}
    procs = [p for p in procedures if p != "step_response"]
    obs = (simulated_observations(robot, world_effects=world, procedures=procs, seed=seed, current=current,
                                  files=files, generator=generator) if procs else Observations())
    if step_response is not None or "step_response" in procedures:
        sr = _square_wave(robot, world, step_response or SquareWave(), seed, plant_simulator(generator))
        obs = Observations.concat([obs, sr])
    return obs


def _square_wave(robot: Robot, world: Mapping[str, Mapping[str, float]], spec: SquareWave, seed: int,
                 simulate: Callable = simulate_batch) -> Observations:
    rng = np.random.default_rng(seed + 7919)
    n_seg = int(math.ceil(spec.duration / spec.half_period))
    t_cmd = [k * spec.half_period for k in range(n_seg)]
    duties = [spec.duties[k % len(spec.duties)] for k in range(n_seg)]
    U = np.array([[d] * 4 for d in duties])
    dt = 1e-3
    res = simulate(robot, Scenario(mode="upside_down", effects=world), t_cmd, U, spec.duration, dt=dt,
                         record_every=1)
    # irregular sample times, like the Arduino's loop; the loop that sends a new command logs
    # it, so every switch time (and the start) is a sample time
    times = [0.0]
    while times[-1] + spec.sample_dt + spec.jitter < spec.duration:
        times.append(times[-1] + spec.sample_dt + rng.uniform(-spec.jitter, spec.jitter))
    ts = np.asarray(times)
    switches = np.asarray(t_cmd, dtype=float)
    near = np.min(np.abs(ts[:, None] - switches[None, :]), axis=1) < 0.5 * spec.sample_dt
    ts = np.unique(np.round(np.concatenate([ts[~near], switches]), 3))  # millisecond clock
    ts = ts[ts < spec.duration]
    idx = np.minimum(np.round(ts / dt).astype(int), len(res.t) - 1)
    k = robot.counts_per_rev / (2 * math.pi)
    off = rng.uniform(0, 1, 4)
    rid = f"sim-step_response-{seed}"
    seg = np.minimum(np.floor(ts / spec.half_period + 1e-9).astype(int), n_seg - 1)
    cols: dict[str, Any] = {"t": ts}
    for j in range(4):
        cols[f"u{j + 1}"] = U[seg, j]
    for j in range(4):
        counts = np.floor(res.signal(f"phi{j + 1}")[0][idx] * k + off[j])
        cols[f"phi{j + 1}"] = counts / k
    for j in range(4):
        if spec.current:
            i = res.signal(f"i{j + 1}")[0][idx] + rng.normal(0, CURRENT_NOISE, len(ts))
            cols[f"i{j + 1}"] = np.round(i / CURRENT_LSB) * CURRENT_LSB
        else:
            cols[f"i{j + 1}"] = np.full(len(ts), np.nan)
    cols["V_batt"] = np.full(len(ts), np.nan)
    cols["I_batt"] = np.full(len(ts), np.nan)
    full = pd.DataFrame(cols, columns=TRACE_COLUMNS)
    obs = Observations(runs={rid: {"procedure": "step_response", "path": None, "status": "complete",
                                   "counts_per_rev": float(robot.counts_per_rev), "source": "simulated_campaign",
                                   "imported": False}})
    rows = []
    for s in range(n_seg):
        m = seg == s
        if not m.any():
            continue
        obs.traces[(rid, s)] = full[m].reset_index(drop=True)
        rows.append({"run": rid, "step": s, "duty": duties[s], "t_start": float(ts[m][0]), "t_end": float(ts[m][-1]),
                     "n": int(m.sum())})
    obs.step_response = pd.DataFrame(rows, columns=STEP_RESPONSE_COLUMNS)
    return obs
