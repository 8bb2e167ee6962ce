"""Black-box baselines the physics model has to beat: per wheel, a first-order lag with a
Coulomb offset, with or without a dead time.

    T_j dω_j/dt = K_j u_j(t − d_j) − c_j sgn(ω_j) − ω_j        (rad/s)

K_j (rad/s per unit duty) is the steady gain, T_j (s) the time constant, c_j (rad/s) the
Coulomb offset (a wheel at rest stays at rest while |K_j u| ≤ c_j: it sticks), d_j (s) the dead
time (0 without). Three numbers per wheel, four with the dead time. Simulated on a 1 ms grid
(exact first-order step per millisecond, the duty schedule of the run as the physics model
sees it: the firmware's command offset applied, a dead time inside a millisecond averaged as in
omnibench.effects.timing), compared on the same finite-difference wheel speeds as `predict`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from omnibench.analysis.observations import Observations
from omnibench.analysis.predict import nrmse
from omnibench.analysis.predictor import run_commands
from omnibench.effects.timing import delay_schedules

DT = 1e-3  # s


@njit(cache=True)
def _lag_coulomb(u, K, T, c, dt):  # pragma: no cover - compiled
    """Wheel angle (n+1,) of one wheel driven by duties u (n,) held one dt each."""
    n = u.shape[0]
    phi = np.zeros(n + 1)
    w = 0.0
    a = math.exp(-dt / T)
    for k in range(n):
        drive = K * u[k]
        if w == 0.0 and abs(drive) <= c:
            w_new = 0.0
        else:
            s = 1.0 if w > 0.0 else (-1.0 if w < 0.0 else (1.0 if drive > 0.0 else -1.0))
            target = drive - c * s
            w_new = target + (w - target) * a
            if w != 0.0 and w_new * w < 0.0:  # reached rest inside the step: it sticks there
                w_new = 0.0
            elif w == 0.0 and w_new * s < 0.0:
                w_new = 0.0
        phi[k + 1] = phi[k] + 0.5 * (w + w_new) * dt
        w = w_new
    return phi


@dataclass
class Trace:
    """One run's logged trace: sample times ts (s from the first), measured wheel angles (n, 4),
    and the run's duty schedule (t_cmd (K,), U (K, 4)) in the same time frame."""

    run: str
    ts: np.ndarray
    phi: np.ndarray
    t_cmd: np.ndarray
    U: np.ndarray

    @property
    def speeds(self) -> np.ndarray:
        """Measured finite-difference wheel speeds (n-1, 4), rad/s."""
        return np.diff(self.phi, axis=0) / np.diff(self.ts)[:, None]


def traces(obs: Observations, runs: Sequence[str] | None = None) -> list[Trace]:
    """The step-response / random-duty traces of `obs` (one per run), wheels in the air only."""
    out = []
    for run in runs or obs.run_ids:
        keys = sorted(k for k in obs.traces if k[0] == run)
        if not keys or obs.runs.get(run, {}).get("mode", "upside_down") != "upside_down" \
                or not (obs.step_response["run"] == run).any():
            continue
        import pandas as pd

        tr = pd.concat([obs.traces[k] for k in keys], ignore_index=True).sort_values("t").reset_index(drop=True)
        ts = tr["t"].to_numpy(dtype=float) - float(tr["t"].iloc[0])
        t_cmd, U = run_commands(obs, run, tr.assign(t=ts))
        phi = tr[[f"phi{j}" for j in range(1, 5)]].to_numpy(dtype=float)
        out.append(Trace(run, ts, phi - phi[0], t_cmd, U))
    return out


def wheel_speeds(tr: Trace, j: int, K: float, T: float, c: float, d: float = 0.0) -> np.ndarray:
    """Black-box speeds (n-1,) of wheel j (0..3) at the trace's sample intervals, rad/s."""
    shift = max(0.0, -float(tr.t_cmd[0]))
    t_end = float(tr.ts[-1]) + shift + 2 * DT
    delays = np.zeros((1, 4))
    delays[0, j] = d
    times, Ud = delay_schedules(tr.t_cmd + shift, tr.U[None], delays, DT)
    grid = np.arange(int(round(t_end / DT))) * DT
    idx = np.searchsorted(times, grid + 1e-9 * DT, side="right") - 1
    u = np.where(idx >= 0, Ud[0][np.maximum(idx, 0), j], 0.0)
    phi = _lag_coulomb(np.ascontiguousarray(u), K, T, c, DT)
    p = np.interp(tr.ts, np.append(grid, grid[-1] + DT) - shift, phi)
    return np.diff(p) / np.diff(tr.ts)


def predict_trace(params: np.ndarray, tr: Trace) -> np.ndarray:
    """Black-box wheel speeds (n-1, 4); params (4, 3) rows K, T, c or (4, 4) rows K, T, c, d."""
    params = np.asarray(params, dtype=float)
    return np.stack([wheel_speeds(tr, j, *params[j]) for j in range(4)], axis=1)


@dataclass
class BlackBox:
    """Fitted per-wheel parameters (4, 3 or 4): K (rad/s), T (s), c (rad/s)[, d (s)]."""

    params: np.ndarray
    dead_time: bool

    def nrmse(self, tr: Trace) -> float:
        return nrmse(tr.speeds, predict_trace(self.params, tr))


def fit_black_box(train: Sequence[Trace], dead_time: bool) -> BlackBox:
    """Least squares (scipy, bounded), wheel by wheel, of the black box on the training traces'
    finite-difference speeds."""
    n_p = 4 if dead_time else 3
    lo = np.array([0.0, 1e-3, 0.0, 0.0][:n_p])
    hi = np.array([100.0, 2.0, 10.0, 0.2][:n_p])
    out = np.zeros((4, n_p))
    for j in range(4):
        meas = [tr.speeds[:, j] for tr in train]
        # start: the steady gain of the largest logged duty, 50 ms lag, small offset, 10 ms dead time
        x0 = np.array([12.0, 0.05, 0.2, 0.01][:n_p])

        def residual(x: np.ndarray, j: int = j, meas: list = meas) -> np.ndarray:
            r = np.concatenate([wheel_speeds(tr, j, *x) - m for tr, m in zip(train, meas)])
            return np.where(np.isfinite(r), r, 0.0)

        sol = least_squares(residual, x0, bounds=(lo, hi), x_scale="jac", diff_step=1e-3, max_nfev=200)
        out[j] = sol.x
    return BlackBox(out, dead_time)
