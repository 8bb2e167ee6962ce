"""Replay logged runs through the model and compare with what was measured.

`replay(robot, obs, run, step)` simulates one logged step (or a whole step-response run) with the
duties the board logged (zero-order hold between samples), in the world of its procedure
(upside down for sweeps and step responses in the air, on the ground for step responses on
the floor and with the payload otherwise; the run's measured supply and firmware timing), and
returns measured and predicted signals at the sample times.

`predict_runs(robot, obs)` gives, per run, the NRMSE of every signal that was measured:

- wheel_speed: speed from successive encoder readings, (phi_k+1 - phi_k) / (t_k+1 - t_k), rad/s
  (the model's angle goes through the same difference, so quantisation is the only extra noise);
- position: wheel angle since the start of the step, rad;
- current: motor currents, A (where logged); battery_current: I_batt, A (where logged);
- steady_speed (sweeps): the steady wheel speeds of the sweep table; energy (energy runs), J.

NRMSE = RMS(measured - predicted) / RMS(measured), pooled over wheels and steps (0.05 = 5 %).

Firmware timing (issue 36): every run is replayed with its own firmware's command timing, the
send order and command offset `import tfm` recorded for the sketch that wrote it (the model's
latencies follow that order: omnibench/model/timing.py). A run whose firmware is unknown (the
2019 floor runs) is replayed with each documented sketch's timing and scored with the one that
predicts it better, and says so (`RunPrediction.firmware`, `firmware_profiled`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from omnibench.analysis.observations import Observations
from omnibench.analysis.predictor import commands_from_trace, run_mode, with_supply
from omnibench.model.robot import Robot
from omnibench.model.scenario import Scenario
from omnibench.model.simulator import simulate

PHYSICS_DT = 1e-3


def nrmse(measured: np.ndarray, predicted: np.ndarray) -> float:
    """RMS(measured - predicted) / RMS(measured) over finite pairs (NaN if none)."""
    m = np.asarray(measured, dtype=float).ravel()
    p = np.asarray(predicted, dtype=float).ravel()
    ok = np.isfinite(m) & np.isfinite(p)
    if not ok.any():
        return float("nan")
    den = float(np.sqrt(np.mean(m[ok] ** 2)))
    return float(np.sqrt(np.mean((m[ok] - p[ok]) ** 2))) / den if den > 0 else float("nan")


def _scenario(obs: Observations, proc: str, run: str, step: int) -> Scenario:
    sc = _scenario_world(obs, proc, run, step)
    delays = obs.runs.get(run, {}).get("command_delays")
    return replace(sc, command_delays=tuple(delays)) if delays is not None else sc


def _scenario_world(obs: Observations, proc: str, run: str, step: int) -> Scenario:
    order = obs.runs.get(run, {}).get("command_order")
    if proc in ("sweep", "step_response"):
        if proc == "sweep" and len(obs.sweep):
            rows = obs.sweep[(obs.sweep["run"] == run) & (obs.sweep["step"] == step)]
            if len(rows) == 4:
                return Scenario(mode="upside_down", wheel_mass=tuple(rows.sort_values("wheel")["wheel_mass"]),
                                command_order=order)
        return Scenario(mode=run_mode(obs, run) if proc == "step_response" else "upside_down", command_order=order)
    table = obs.table(proc)
    rows = table[(table["run"] == run) & (table["step"] == step)]
    payload = float(rows["payload"].iloc[0]) if len(rows) and math.isfinite(rows["payload"].iloc[0]) else 0.0
    return Scenario(mode="ground", payload=payload, command_order=order)


def replay(robot: Robot, trace: pd.DataFrame, scenario: Scenario, timing: str = "from_sample",
           offset: float = 0.0) -> pd.DataFrame:
    """Simulate the trace's logged duties (`timing`: see predictor.DUTY_TIMINGS); measured and
    predicted signals at the sample times. `offset` (s) shifts the logged schedule (the
    firmware's command offset, predictor.run_commands).

    Columns: t, phi{j}_meas / phi{j}_pred (rad since the first sample), w{j}_meas / w{j}_pred
    (rad/s, successive-reading differences, at the interval midpoints; last row NaN),
    i{j}_meas / i{j}_pred (A), I_batt_meas / I_batt_pred (A), V_batt_meas / V_batt_pred (V),
    E_pred (J since the first sample, the model's exact integral)."""
    tr = trace.sort_values("t").reset_index(drop=True)
    t = tr["t"].to_numpy(dtype=float)
    t0 = t[0]
    ts = t - t0
    t_cmd, U = commands_from_trace(tr.assign(t=ts), timing)
    t_cmd = t_cmd + offset
    shift = max(0.0, -float(t_cmd[0]))
    sim = simulate(robot, scenario, t_cmd + shift, U, float(ts[-1]) + shift + 2 * PHYSICS_DT, dt=PHYSICS_DT)
    st = sim["t"].to_numpy() - shift
    # Currents and voltage jump when a duty changes. With "interval_before" a sample at a change
    # instant was read before the new command acted: take the model's value just before (one
    # physics step earlier) for these algebraic signals; angles are continuous.
    ta = ts - PHYSICS_DT if timing == "interval_before" else ts
    out = pd.DataFrame({"t": t})
    dts = np.diff(ts)
    for j in range(1, 5):
        pm = tr[f"phi{j}"].to_numpy(dtype=float)
        pm = pm - pm[0]
        pp = np.interp(ts, st, sim[f"phi{j}"].to_numpy())
        pp = pp - pp[0]
        out[f"phi{j}_meas"], out[f"phi{j}_pred"] = pm, pp
        wm = np.append(np.diff(pm) / dts, np.nan)
        wp = np.append(np.diff(pp) / dts, np.nan)
        out[f"w{j}_meas"], out[f"w{j}_pred"] = wm, wp
        out[f"i{j}_meas"] = tr[f"i{j}"].to_numpy(dtype=float)
        out[f"i{j}_pred"] = np.interp(ta, st, sim[f"i{j}"].to_numpy())
    out["I_batt_meas"] = tr["I_batt"].to_numpy(dtype=float)
    out["I_batt_pred"] = np.interp(ta, st, sim["I_batt"].to_numpy())
    out["V_batt_meas"] = tr["V_batt"].to_numpy(dtype=float)
    out["V_batt_pred"] = np.interp(ta, st, sim["V_batt"].to_numpy())
    E = np.interp(ts, st, sim["E_batt"].to_numpy())
    out["E_pred"] = E - E[0]
    return out


@dataclass
class RunPrediction:
    """One run's comparison: NRMSE per signal and the replayed traces (for plots)."""

    run: str
    procedure: str
    nrmse: dict[str, float]
    traces: dict[int, pd.DataFrame] = field(default_factory=dict)
    entries: pd.DataFrame | None = None
    #: the firmware timing the run was replayed with (its sketch; for an unknown firmware, the
    #: documented sketch whose timing predicted it better)
    firmware: str = ""
    #: unknown firmware: wheel-speed NRMSE under each documented sketch's timing (sketch -> NRMSE)
    firmware_profiled: dict[str, float] = field(default_factory=dict)
    #: unknown mode (where the robot was): the mode it was replayed in, the better of the two
    mode: str = ""
    #: unknown mode: wheel-speed NRMSE replayed in the air and on the floor (mode -> NRMSE)
    mode_profiled: dict[str, float] = field(default_factory=dict)

    def mode_text(self) -> str:
        """Where the run was replayed, in words, when its mode is unknown (else "")."""
        if not self.mode_profiled:
            return ""
        words = {"upside_down": "in the air", "ground": "on the floor"}
        return (f"where unknown: replayed in the air and on the floor, chose {words.get(self.mode, self.mode)} ("
                + ", ".join(f"{words.get(k, k)} {100 * v:.2f} %" for k, v in self.mode_profiled.items()) + ")")

    def firmware_text(self) -> str:
        """The firmware timing used, in words."""
        if not self.firmware_profiled:
            return f"firmware timing of {self.firmware}" if self.firmware else ""
        return (f"firmware unknown: profiled over the documented sketches, chose {self.firmware} ("
                + ", ".join(f"{k} {100 * v:.2f} %" for k, v in self.firmware_profiled.items()) + ")")


def duty_timing(obs: Observations, run: str) -> str:
    """The run's duty timing convention (predictor.DUTY_TIMINGS)."""
    return str(obs.runs.get(run, {}).get("duty_timing", "from_sample"))


def _trace_groups(obs: Observations, run: str, proc: str) -> dict[int, pd.DataFrame]:
    keys = sorted(k for k in obs.traces if k[0] == run)
    if proc == "step_response" and keys:
        return {-1: pd.concat([obs.traces[k] for k in keys], ignore_index=True).sort_values("t").reset_index(drop=True)}
    return {k[1]: obs.traces[k] for k in keys if len(obs.traces[k]) >= 3}


def predict_runs(robot: Robot, obs: Observations, *, profile_timing: bool = False) -> list[RunPrediction]:
    """Every run of `obs` replayed through `robot` with its own firmware timing; with
    `profile_timing`, a run of unknown firmware under each documented sketch's timing, the better
    one kept (module docstring; leave-one-run-out profiles its own way, heldout_runs.py). A run
    whose mode is unknown (where the robot was: `mode` None) is always replayed both in the air
    and on the floor, the better kept, and says so (`RunPrediction.mode`, `mode_profiled`): an
    unknown mode never takes a default."""
    out = []
    for run in obs.run_ids:
        info = obs.runs.get(run, {})
        modes: list[str | None] = ["upside_down", "ground"] if "mode" in info and info["mode"] is None else [None]
        best: RunPrediction | None = None
        by_mode: dict[str, float] = {}
        for mode in modes:
            o = obs if mode is None else replace(obs, runs={**obs.runs, run: {**info, "mode": mode}})
            rp = _predict_timings(robot, o, run, profile_timing)
            if mode is None:
                best = rp
                continue
            rp.mode = mode
            score = _score(rp)
            by_mode[mode] = score
            if best is None or (math.isfinite(score) and not score >= _score(best)):
                best = rp
        assert best is not None
        best.mode_profiled = by_mode
        out.append(best)
    return out


def _score(rp: RunPrediction) -> float:
    """The NRMSE that chooses between a run's replays: wheel speed, else its first signal."""
    key = "wheel_speed" if "wheel_speed" in rp.nrmse else next(iter(rp.nrmse), None)
    return float(rp.nrmse.get(key, float("nan"))) if key is not None else float("nan")


def _predict_timings(robot: Robot, obs: Observations, run: str, profile_timing: bool) -> RunPrediction:
    """One run replayed with its firmware timing or, with `profile_timing` and an unknown
    firmware, under each documented sketch's timing, the better kept."""
    info = obs.runs.get(run, {})
    alts = info.get("timing_alternatives") or []
    first = _predict_run(robot, obs, run)
    first.firmware = str(info.get("timing_sketch") or info.get("sketch") or "")
    if not alts or not profile_timing:
        return first
    options = [first]
    for alt in alts:
        o = replace(obs, runs={**obs.runs, run: {**info, "command_order": alt["command_order"],
                                                 "command_offset": alt["command_offset"]}})
        rp = _predict_run(robot, o, run)
        rp.firmware = str(alt.get("sketch", "?"))
        options.append(rp)
    # no signal scored: every option scores NaN
    scores = {o.firmware: _score(o) for o in options}
    best = min(options, key=lambda o: (not math.isfinite(scores[o.firmware]), scores[o.firmware]))
    best.firmware_profiled = scores
    return best


def _predict_run(robot: Robot, obs: Observations, run: str) -> RunPrediction:
    """One run of `obs` replayed through `robot` with the timing `obs` records for it."""
    from omnibench.analysis.fitting import predict_observations

    proc = next(p for p in ("sweep", "forward", "lateral", "energy", "step_response")
                if (obs.table(p)["run"] == run).any())
    sub = obs.select(runs=[run])
    rp = RunPrediction(run=run, procedure=proc, nrmse={})
    pooled: dict[str, tuple[list, list]] = {}

    def add(name: str, m: np.ndarray, p: np.ndarray) -> None:
        a, b = pooled.setdefault(name, ([], []))
        a.append(np.asarray(m, dtype=float).ravel())
        b.append(np.asarray(p, dtype=float).ravel())

    for step, tr in _trace_groups(sub, run, proc).items():
        info = obs.runs.get(run, {})
        rep = replay(with_supply(robot, float(info.get("V_batt", float("nan")))), tr,
                     _scenario(sub, proc, run, step), duty_timing(obs, run),
                     float(info.get("command_offset", 0.0) or 0.0))
        rp.traces[step] = rep
        add("wheel_speed", rep[[f"w{j}_meas" for j in range(1, 5)]].to_numpy(),
            rep[[f"w{j}_pred" for j in range(1, 5)]].to_numpy())
        add("position", rep[[f"phi{j}_meas" for j in range(1, 5)]].to_numpy(),
            rep[[f"phi{j}_pred" for j in range(1, 5)]].to_numpy())
        im = rep[[f"i{j}_meas" for j in range(1, 5)]].to_numpy()
        if np.isfinite(im).any() and np.nanmax(np.abs(im)) > 0:
            add("current", im, rep[[f"i{j}_pred" for j in range(1, 5)]].to_numpy())
        Ib = rep["I_batt_meas"].to_numpy()
        if np.isfinite(Ib).any() and np.nanmax(np.abs(Ib)) > 0:
            add("battery_current", Ib, rep["I_batt_pred"].to_numpy())
    if proc in ("sweep", "energy", "forward", "lateral"):
        ent = predict_observations(robot, sub, [proc])
        rp.entries = ent
        names = {"omega": "steady_speed", "current": "steady_current", "energy": "energy", "w": "drive_speed",
                 "forward": "displacement", "left": "displacement"}
        for sig, g in ent.groupby("signal"):
            add(names.get(str(sig), str(sig)), g["measured"].to_numpy(), g["predicted"].to_numpy())
    rp.nrmse = {k: nrmse(np.concatenate(a), np.concatenate(b)) for k, (a, b) in pooled.items()}
    return rp
