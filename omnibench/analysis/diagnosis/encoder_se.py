"""Standard errors that know the encoder: quantised angles revisited by a periodic motion.

A step-response speed sample is a finite difference of two angles read in whole counts,
(n_k+1 - n_k) / (counts_per_rev/2pi) / dt. Each angle's rounding error e = floor(x + o) - x (x the
true angle in counts, o the encoder's unknown mounting phase) is a fixed function of the
angle, not fresh noise: a square wave brings each wheel back to the same angle at every
reversal of the same sign (the sample at a duty change is at the same place of the same
periodic orbit every cycle), so those samples carry the same rounding error all run long and
averaging over reversals does not shrink it. The textbook covariance counts them as
independent and reports latencies several times too precise (benchmarks/diagnose.py: 1 of 5
`per_wheel_latency` fits within 3 SE; a Monte Carlo over the mounting phase, tests/analysis,
gives the spread this covariance predicts).

Over a uniform phase o, two rounding errors d counts apart have covariance
C(d) = 1/12 - f(1 - f)/2, f = frac(d) (the sawtooth's autocovariance; in Fourier form
sum_n cos(2 pi n d) / (2 pi^2 n^2)). The true angle differences are known only through the
model, to within a fraction of the distance travelled: each Fourier term is averaged over a
Gaussian uncertainty sigma = rho |d| (factor exp(-2 pi^2 n^2 sigma^2)), so angles many counts
apart decorrelate and exact revisits keep their full correlation. rho, per run and wheel, is
the fit's own relative misfit of the travel between duty changes (measured - predicted, over
the predicted), not a tuned constant.

The covariance replaces the white-noise share of the speed samples' residual that rounding
explains (1/6 count^2 / dt^2 per sample, at most the profiled scale); what is left of the
residual stays white. Engine.fit_model reports max(this, the cluster-robust SE).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from numba import njit

from omnibench.analysis.quantisation import FOURIER_DENOMINATORS, sawtooth_cov, sawtooth_damped_one

MIN_RHO = 1e-4  # relative uncertainty of predicted angle differences never taken below this


def _sample_times(obs, run: str) -> np.ndarray | None:
    parts = [tr for (r, _), tr in obs.traces.items() if r == run]
    if not parts:
        return None
    return np.sort(pd.concat(parts, ignore_index=True)["t"].to_numpy(dtype=float))


def _relative_misfit(phi_pred: np.ndarray, phi_meas: np.ndarray, u: np.ndarray) -> float:
    """rho: RMS of (measured - predicted) travel between duty changes over the RMS predicted travel."""
    cut = np.flatnonzero(np.diff(u) != 0) + 1
    edges = np.unique(np.concatenate([[0], cut, [len(phi_pred) - 1]]))
    if len(edges) < 3:
        return 1.0
    tp = np.diff(phi_pred[edges])
    tm = np.diff(phi_meas[edges])
    den = math.sqrt(float(np.mean(tp ** 2)))
    if den <= 0:
        return 1.0
    return float(np.clip(math.sqrt(float(np.mean((tm - tp) ** 2))) / den, MIN_RHO, 1.0))


def meat(problem, f: np.ndarray, Jw: np.ndarray, w: np.ndarray, cov: np.ndarray | None = None) -> np.ndarray | None:
    """The sandwich's middle J_w' Sigma J_w over the used entries, with Sigma the identity except
    for the step-response speed samples of runs with a known encoder resolution, where the
    rounding share of each sample's variance is replaced by the rounding covariance above.
    `f` predictions of every entry, `Jw` (used entries x p) weighted Jacobian, `w` weights of
    every entry. None when no entry has a rounding model (the textbook covariance applies)."""
    t = problem.table
    used = problem.used
    row_of = np.full(len(used), -1)
    row_of[used] = np.arange(int(used.sum()))
    sr = used & (t["procedure"].to_numpy() == "step_response") & (t["signal"].to_numpy() == "omega")
    if not sr.any():
        return None
    M = Jw.T @ Jw
    touched = False
    for (run, wheel), g in t[sr].groupby(["run", "wheel"], sort=False):
        cpr = problem.obs.runs.get(run, {}).get("counts_per_rev")
        ts = _sample_times(problem.obs, run)
        if cpr is None or not (isinstance(cpr, (int, float)) and math.isfinite(cpr) and cpr > 0) or ts is None:
            continue
        idx = g.index.to_numpy()[np.argsort(g["time"].to_numpy(dtype=float), kind="stable")]
        dt = np.diff(ts)
        if len(dt) != len(idx) or np.any(dt <= 0):
            continue  # entries do not map one-to-one on the run's intervals: no rounding model
        k = float(cpr) / (2.0 * math.pi)
        phi = np.concatenate([[0.0], np.cumsum(f[idx] * dt)]) * k  # predicted angle, counts
        phi_meas = np.concatenate([[0.0], np.cumsum(problem.y[idx] * dt)]) * k
        u = np.concatenate([[t.loc[idx[0], "u"]], t.loc[idx, "u"].to_numpy(dtype=float)])
        rho = _relative_misfit(phi, phi_meas, u)
        ww = w[idx]
        rows = row_of[idx]
        Jb = Jw[rows]
        # speed n = a_n (e_n+1 - e_n), a_n = 1 / (k dt_n): sensitivities move onto the angles
        a = ww / (k * dt)
        G = np.zeros((len(dt) + 1, Jb.shape[1]))
        np.add.at(G, np.arange(len(dt)) + 1, a[:, None] * Jb)
        np.add.at(G, np.arange(len(dt)), -a[:, None] * Jb)
        # each sample's (weighted) rounding variance; if rounding would explain more than the
        # whole residual on average, the profiled scale wins and the rounding model is scaled down
        step = np.diff(phi)
        v = a ** 2 * 2.0 * (sawtooth_cov(np.zeros(1))[0] - sawtooth_cov(step, rho * np.abs(step)))
        scale = min(1.0, 1.0 / max(float(np.mean(v)), 1e-300))
        # the fit's own uncertainty of each predicted angle (parameter covariance `cov` carried
        # through the angle sensitivities): L_a . L_b is the covariance of angles a and b
        if cov is not None:
            Jphi = np.concatenate([np.zeros((1, Jb.shape[1])), np.cumsum(Jb / ww[:, None] * dt[:, None], axis=0)]) * k
            ev, V = np.linalg.eigh(0.5 * (cov + cov.T))
            L = Jphi @ (V * np.sqrt(np.maximum(ev, 0.0)))
        else:
            L = np.zeros((len(phi), 1))
        Mq = G.T @ rounding_cov_times(phi, rho, np.ascontiguousarray(L), np.ascontiguousarray(G), FOURIER_DENOMINATORS)
        M = M + scale * (Mq - (Jb * v[:, None]).T @ Jb)
        touched = True
    return M if touched else None


@njit(cache=True)
def rounding_cov_times(phi: np.ndarray, rho: float, L: np.ndarray, G: np.ndarray, denominator: np.ndarray) -> np.ndarray:
    """C @ G, C the rounding covariance of the angles `phi` (counts): C_ab = sawtooth_cov(phi_a -
    phi_b) damped by the variance of that difference, (rho (phi_a - phi_b))^2 + |L_a - L_b|^2 (L:
    the fit's uncertainty of each angle). C is symmetric and never stored: each pair once, O(n p)
    memory (a 1100-sample run's C is 10 MB; numpy built it in row chunks, twice per pair)."""
    n, p = G.shape
    out = np.zeros((n, p))
    for a in range(n):
        for b in range(a, n):
            d = phi[a] - phi[b]
            var = (rho * d) ** 2
            for k in range(L.shape[1]):
                var += (L[a, k] - L[b, k]) ** 2
            c = sawtooth_damped_one(d, var, denominator)
            for j in range(p):
                out[a, j] += c * G[b, j]
            if b != a:
                for j in range(p):
                    out[b, j] += c * G[a, j]
    return out


PASSES = 2  # the trajectory's uncertainty is the covariance being computed: iterate from the textbook one


def encoder_se(problem, f: np.ndarray, Jw: np.ndarray, w: np.ndarray) -> np.ndarray | None:
    """Standard errors of the parameters with the rounding covariance (None: no rounding model)."""
    bread = np.linalg.pinv(Jw.T @ Jw)
    cov = bread
    for _ in range(PASSES):
        M = meat(problem, f, Jw, w, cov)
        if M is None:
            return None
        cov = bread @ M @ bread
    return np.sqrt(np.maximum(np.diag(cov), 0.0))
