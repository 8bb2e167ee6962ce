"""Fisher information of candidate steps and of the data already taken, in the fit's terms.

Each candidate is turned into the observation rows its runs would produce (the same tables
the fit reads), predicted through the fit's own `Predictor` at the current parameter values,
and differentiated by the fit's own forward differences (`least_squares.weighted_residuals`,
the engine fit and diagnose share): one source of truth for what an observation depends on.
With J_k the weighted Jacobian of candidate k's entries (scaled parameters x = theta / scale),
its information is M_k = J_k^T J_k / s2_g, where s2_g is the noise scale the fit found for that
observation group (chi^2/dof, with its correlation inflation), so the predicted SE is the one
the fit will report.

Expected noise of an entry (before any data of its group, s2_g = 1): steady speed and drive
speeds as the fit will state them, the rounding error of a straight line through encoder
angles at the predicted speed over the step's window (omnibench.analysis.quantisation), motor
current 0.01 A per sample averaged, tape 2 mm.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from omnibench.analysis.design.space import Candidate
from omnibench.analysis.fitting import (
    MIN_SWEEP_SPEED,
    REWEIGHT_MIN_DOF,
    FitResult,
    creeping_ground_speeds,
)
from omnibench.analysis.least_squares import param_scale, weighted_residuals
from omnibench.analysis.observations import (
    DEFAULT_TAPE_SE,
    RUN_COLUMNS,
    STEADY_AVERAGE,
    SWEEP_COLUMNS,
    Observations,
    drive_window,
    quantisation_se,
)
from omnibench.analysis.predictor import Predictor
from omnibench.analysis.quantisation import quantised_slope
from omnibench.model.context import GRAVITY

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

TELEMETRY_HZ = 100.0
CURRENT_NOISE = 0.01  # A per telemetry sample (the simulated board; a real board's is read from its data)
#: Prior standard deviation of every parameter before any data, in units of its scale (100 %).
PRIOR_SD = 1.0


def slope_se(duration: float, floor: float, rate: float = TELEMETRY_HZ) -> float:
    """SE (rad/s) of a speed from a straight line fitted to `duration` s of angles at `rate` Hz
    whose scatter is the quantisation floor (rad): floor / sqrt(sum (t - tbar)^2). The
    placeholder before the speed is predicted (`expected_speed_se` replaces it)."""
    n = max(int(round(duration * rate)), 3)
    t = np.arange(n) / rate
    return floor / math.sqrt(float(np.sum((t - t.mean()) ** 2)))


SPEED_ROUNDING = 1e-4  # rad/s: predicted speeds are rounded to this for the cache (the band is ~1e-3)


@lru_cache(maxsize=4096)
def _speed_se(omega: float, duration: float, counts_per_rev: float, rate: float) -> float:
    n = max(int(round(duration * rate)), 3)
    v, _ = quantised_slope(np.arange(n) / rate, omega, counts_per_rev)
    return math.sqrt(v)


def expected_speed_se(omega: float, duration: float, counts_per_rev: float, rate: float = TELEMETRY_HZ) -> float:
    """SE (rad/s) the fit will state for a steady speed omega (rad/s) read over `duration` s of
    encoder angles at `rate` Hz: the rounding error of the straight-line fit at that speed."""
    w = round(abs(float(omega)) / SPEED_ROUNDING) * SPEED_ROUNDING
    return _speed_se(w, round(float(duration), 6), float(counts_per_rev), float(rate))


def sweep_average(c: Candidate) -> float:
    """Time (s) a sweep candidate's speed is averaged over (its duration; the default if unset)."""
    return c.duration if c.duration > 0 else STEADY_AVERAGE


def _rows(cands: Sequence[Candidate], robot: Robot, current: bool) -> Observations:
    floor = quantisation_se(robot.counts_per_rev)
    sweep: list[dict[str, Any]] = []
    forward: list[dict[str, Any]] = []
    lateral: list[dict[str, Any]] = []
    for k, c in enumerate(cands):
        rid = f"candidate-{k}"
        average = sweep_average(c)
        w_se = slope_se(average, floor)
        i_se = CURRENT_NOISE / math.sqrt(average * TELEMETRY_HZ)
        for s, u in enumerate(c.duties(robot)):
            if c.procedure == "sweep":
                for j in range(4):
                    m = float(c.world.wheel_mass[j])  # type: ignore[index]
                    sweep.append({"run": rid, "step": s, "wheel": j + 1, "u": u[j], "direction": float(np.sign(u[j])),
                                  "wheel_mass": m, "F_N": m * GRAVITY, "omega": 1.0, "omega_se": w_se,
                                  "current": 0.0 if current else np.nan, "current_se": i_se if current else np.nan,
                                  "n": 30, "steady": True, "time": np.nan})
                continue
            a, b = drive_window(c.duration)
            ws = slope_se(b - a, floor)
            row = {"run": rid, "step": s, **{f"u{j + 1}": u[j] for j in range(4)}, "duration": c.duration,
                   "t_total": c.duration + c.settle, "payload": c.world.payload, "heading": c.heading,
                   "measured_forward": 0.0, "measured_left": 0.0 if c.procedure == "lateral" else np.nan,
                   "measured_se": DEFAULT_TAPE_SE, **{f"w{j}": 1.0 for j in range(1, 5)},
                   **{f"w_se{j}": ws for j in range(1, 5)}, "w_t0": a, "w_t1": b, "time": np.nan}
            (forward if c.procedure == "forward" else lateral).append(row)
    return Observations(sweep=pd.DataFrame(sweep, columns=SWEEP_COLUMNS),
                        forward=pd.DataFrame(forward, columns=RUN_COLUMNS),
                        lateral=pd.DataFrame(lateral, columns=RUN_COLUMNS))


#: The estimator behind each observation group: groups of one estimator share its error.
ESTIMATOR = {"sweep/omega": "encoder speed", "forward/w": "encoder speed", "lateral/w": "encoder speed",
             "forward/forward": "tape", "lateral/forward": "tape", "lateral/left": "tape",
             "sweep/current": "current"}


def expected_s2(group_s2: Mapping[str, float], group_dof: Mapping[str, float] | None = None) -> dict[str, float]:
    """Noise scale (chi^2/dof) each group is expected to show: the fit's where the group has data;
    before that, the largest one the fit found for a group of the same estimator (the encoder
    speeds of the sweep and of the ground runs come from the same straight-line fit of encoder
    angles, whose error is stated from its rounding at each speed: about 1 on the simulated robot,
    more on a real one with speed ripple); 1 (the stated noise) when the estimator has no data yet.
    With `group_dof`, only a group with at least REWEIGHT_MIN_DOF degrees of freedom lends its
    figure to another (the fit's own rule for weighting a group by its noise): the chi^2/dof of
    one forward pair (two tape distances, one degree of freedom after C_r) is a chi^2_1 draw,
    0.13-0.2 on two benchmark seeds where the lateral tape groups then showed 0.5-1.3."""
    out = {g: float(v) for g, v in group_s2.items() if v and math.isfinite(v) and v > 0}
    lenders = {g: v for g, v in out.items() if group_dof is None or group_dof.get(g, 0.0) >= REWEIGHT_MIN_DOF}
    for g, est in ESTIMATOR.items():
        if g in out:
            continue
        seen = [v for h, v in lenders.items() if ESTIMATOR.get(h) == est]
        if seen:
            out[g] = max(seen)
    return out


@dataclass
class CandidateInformation:
    """Per-candidate information matrices (scaled parameters) and the scale used."""

    names: list[str]
    scale: np.ndarray
    info: np.ndarray  # (K, n, n)
    usable: np.ndarray  # (K,) bool: gives the fit any usable observation


@dataclass(frozen=True)
class _Sensitivity:
    """What candidate_information simulates: the stated-noise Jacobian of every usable row (scaled
    parameters), the candidate and observation group of each row. The noise scales apply after."""

    J: np.ndarray
    cand_of: np.ndarray
    groups: np.ndarray


#: The last few sensitivities, by (robot, candidates, names, current): an adaptive round asks for
#: the same one up to three times (the plan, its re-plan at calibrated targets, the current pose's
#: deferral), each a Jacobian of every candidate's rows (8 s CPU for the 95 default candidates).
_SENSITIVITIES: dict[tuple, _Sensitivity] = {}
_SENSITIVITIES_KEPT = 8


def _sensitivity(robot: Robot, cands: Sequence[Candidate], names: list[str], scale: np.ndarray,
                 current: bool) -> _Sensitivity:
    key = (repr(robot), tuple(cands), tuple(names), current)
    hit = _SENSITIVITIES.pop(key, None)
    if hit is None:
        hit = _simulate_sensitivity(robot, cands, names, scale, current)
    _SENSITIVITIES[key] = hit  # most recent last
    while len(_SENSITIVITIES) > _SENSITIVITIES_KEPT:
        _SENSITIVITIES.pop(next(iter(_SENSITIVITIES)))
    return hit


def candidate_information(robot: Robot, cands: Sequence[Candidate], names: Sequence[str], *, current: bool = True,
                          group_s2: Mapping[str, float] | None = None,
                          group_dof: Mapping[str, float] | None = None) -> CandidateInformation:
    """Information each candidate adds about `names` at `robot`'s parameter values (each group's
    noise scale from `expected_s2(group_s2, group_dof)`)."""
    names = list(names)
    scale = np.array([param_scale(robot, p) for p in names])
    K, n = len(cands), len(names)
    info = np.zeros((K, n, n))
    usable = np.zeros(K, dtype=bool)
    if not K:
        return CandidateInformation(names, scale, info, usable)
    sens = _sensitivity(robot, cands, names, scale, current)
    s2 = np.ones(len(sens.groups))
    for g, v in expected_s2(group_s2 or {}, group_dof).items():
        if v and math.isfinite(v) and v > 0:
            s2[sens.groups == g] = v
    Jw = sens.J / np.sqrt(s2)[:, None]
    for k in range(K):
        m = sens.cand_of == k
        if m.any():
            usable[k] = True
            info[k] = Jw[m].T @ Jw[m]
    return CandidateInformation(names, scale, info, usable)


def split_by_end(pred: Predictor) -> Predictor:
    """`pred` with each timed-run group (forward, lateral) split into one group per end time
    (in place). A group is simulated to its latest end: merged, a 1.5 s candidate run was
    simulated on to the 4.5 s runs' end (4.7 s), 3 s at rest, where the adaptive sub-steps take
    their full count (near zero speed): 95 % of a plan's simulation time. Each trajectory's
    numbers are those of the merged group bit for bit (the robot rests within COAST s; the kernel
    does not mix lanes; tests/analysis/test_design.py checks it); the scenarios, hence the
    sub-steps, are the same. (The split belongs in Predictor itself, where the fit's ground runs
    of several durations pay the same; predictor.py is outside the planner's files.)"""
    groups: dict[tuple, Any] = {}
    for key, g in pred.groups.items():
        if key[0] not in ("forward", "lateral"):
            groups[key] = g
            continue
        for k, end in enumerate(g.t_ends):
            sub = groups.setdefault(key + (end,), type(g)(record_every=g.record_every, round_end=g.round_end))
            sub.add(*g.schedules[k], end, g.scen[k], g.extract[k], g.v_batt[k])
    pred.groups = groups
    return pred


def _simulate_sensitivity(robot: Robot, cands: Sequence[Candidate], names: list[str], scale: np.ndarray,
                          current: bool) -> _Sensitivity:
    obs = _rows(cands, robot, current)
    pred = split_by_end(Predictor(obs, [p for p in ("sweep", "forward", "lateral") if len(obs.table(p))]))
    f0 = pred.predict([robot])[0]
    t = pred.table
    sweep_speed = (t["procedure"] == "sweep").to_numpy() & (t["signal"] == "omega").to_numpy()
    pred.sigma = pred.sigma.copy()
    _speed_sigma(pred, obs, f0, robot.counts_per_rev, [sweep_average(c) for c in cands])
    used = np.isfinite(f0) & np.isfinite(pred.sigma) & (pred.sigma > 0)
    # a sweep level too slow for the fit (stuck, inside the regularised sign) informs nothing
    slow = np.zeros(len(t), dtype=bool)
    for (run, step), idx in t.groupby(["run", "step"]).groups.items():
        ix = np.asarray(list(idx))
        if t.loc[ix[0], "procedure"] == "sweep":
            sp = np.abs(f0[ix][sweep_speed[ix]])
            if sp.size and sp.min() < MIN_SWEEP_SPEED:
                slow[ix] = True
    used &= ~slow & ~creeping_ground_speeds(t, f0, robot)  # a wheel predicted stuck on the ground: the fit leaves it out
    groups = (t["procedure"].astype(str) + "/" + t["signal"].astype(str)).to_numpy()
    pred.measured = f0.copy()
    prob = weighted_residuals(robot, pred, names, used, pred.sigma, scale=scale)
    J = prob.jacobian(np.array([float(_value(robot, p)) for p in names]) / scale)
    rows = np.flatnonzero(used)
    cand_of = np.array([int(str(r).split("-")[1]) for r in t["run"].to_numpy()[rows]])
    J.flags.writeable = False  # shared by every caller of the cache
    return _Sensitivity(J, cand_of, groups[rows])


def _speed_sigma(pred: Predictor, obs: Observations, f0: np.ndarray, counts_per_rev: float,
                 averages: Sequence[float]) -> None:
    """Each encoder speed's stated SE at its predicted speed and window (in place on pred.sigma);
    `averages`: each candidate's sweep averaging time, s."""
    t = pred.table
    sig = t["signal"].to_numpy()
    proc = t["procedure"].to_numpy()
    window = {}
    for name in ("forward", "lateral"):
        tab = obs.table(name)
        for r in tab.itertuples(index=False):
            window[(r.run, int(r.step))] = float(r.w_t1) - float(r.w_t0)
    for k in np.flatnonzero(((proc == "sweep") & (sig == "omega")) | (sig == "w")):
        if not math.isfinite(f0[k]):
            continue
        run = str(t.at[k, "run"])
        dur = averages[int(run.split("-")[1])] if proc[k] == "sweep" else window.get((run, int(t.at[k, "step"])))
        if dur:
            pred.sigma[k] = expected_speed_se(f0[k], dur, counts_per_rev)


def _value(robot: Robot, name: str) -> float:
    from omnibench.analysis.least_squares import param_value

    return param_value(robot, name)


def prior_information(res: FitResult | None, names: Sequence[str], scale: np.ndarray,
                      obs: Observations | None = None) -> np.ndarray:
    """Information already in hand (scaled) plus a weak prior (SD = PRIOR_SD scales) on every
    parameter. The data's information is J^T J / s2_g of the fit's own observations over *all*
    `names` at the fitted values (not the inverse of the fit's covariance: that one is conditional
    on the parameters the fit held fixed, and would count their data twice)."""
    n = len(names)
    M = np.eye(n) / PRIOR_SD ** 2
    if res is None or obs is None or not len(res.residuals):
        return M
    pred = Predictor(obs, res.procedures)
    r = res.residuals
    if len(r) != len(pred):
        return M
    used = r["used"].to_numpy(bool) & np.isfinite(r["sigma"].to_numpy(float))
    sigma = r["sigma"].to_numpy(float)
    groups = (r["procedure"].astype(str) + "/" + r["signal"].astype(str)).to_numpy()
    s2 = np.array([res.group_s2.get(g, 1.0) or 1.0 for g in groups])
    prob = weighted_residuals(res.robot, pred, list(names), used, sigma, scale=scale)
    J = prob.jacobian(np.array([float(_value(res.robot, p)) for p in names]) / scale)
    Jw = J / np.sqrt(s2[used])[:, None]
    return M + Jw.T @ Jw
