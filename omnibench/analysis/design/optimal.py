"""The continuous optimal design: how many repetitions of each candidate, as real numbers.

With w_k >= 0 the (real) number of pairs of candidate k, the information is M(w) = M0 + sum w_k M_k
and the predicted variance of target i is V_ii(w) = [M(w)^-1]_ii. The cheapest design that meets
every target,

    minimise  sum_k cost_k w_k   subject to   V_ii(w) <= t_i^2,   lo_k <= w_k <= hi_k,

is a convex problem (V_ii is convex in w; the constraints are the weighted A-criterion target by
target), so a local solver finds its global optimum. Its Lagrangian is the weighted A-optimal
design with the multipliers as weights; scipy's SLSQP solves it with the exact gradients
dV_ii/dw_k = -(V M_k V)_ii. The real weights are then rounded to whole pairs by the planner.
Why not only the greedy: one step at a time, a greedy buys early what later steps make redundant
and cannot trade two cheap steps against one dear one; the convex optimum sees all at once.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

#: A design counts as meeting a target when V_ii <= (1 + TOL) t_i^2 (the solver's tolerance).
TOL = 1e-3


def cheapest_weights(M0: np.ndarray, infos: np.ndarray, cost: np.ndarray, tidx: np.ndarray, t2: np.ndarray,
                     lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
    """Real repetitions w (lo <= w <= hi) of each candidate (infos: (K, n, n)) of least total
    cost (cost: (K,) s per pair) with V_ii <= t2 for every target index in tidx; None when the
    bounds cannot reach the targets or the solver fails."""
    K = len(infos)
    if not K or not len(tidx):
        return None
    scale_c = max(float(np.max(cost)), 1e-12)
    c = cost / scale_c

    def var(w: np.ndarray) -> np.ndarray:
        return np.linalg.inv(M0 + np.einsum("k,kij->ij", w, infos))

    def cons(w: np.ndarray) -> np.ndarray:
        return 1.0 - np.diag(var(w))[tidx] / t2

    def cons_jac(w: np.ndarray) -> np.ndarray:
        v = var(w)[:, tidx]
        return np.einsum("ni,knm,mi->ik", v, infos, v) / t2[:, None]

    if np.any(cons(hi) < -TOL):
        return None  # even the most the bounds allow does not reach every target
    w0 = np.clip(np.maximum(lo, 0.5 * hi), lo, hi)
    try:
        r = minimize(lambda w: float(c @ w), w0, jac=lambda w: c, method="SLSQP", bounds=list(zip(lo, hi)),
                     constraints=[{"type": "ineq", "fun": cons, "jac": cons_jac}],
                     options={"maxiter": 300, "ftol": 1e-9})
    except (np.linalg.LinAlgError, ValueError):
        return None
    w = np.clip(r.x, lo, hi)
    # SLSQP may stop with a line-search message at a point that is feasible and optimal to its tolerance
    if not np.all(np.isfinite(w)) or np.any(cons(w) < -10 * TOL):
        return None
    return w
