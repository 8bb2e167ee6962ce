"""Stiffness of the model at rest, from every enabled term: how fast the velocity dynamics decay.

The explicit integrators are stable while h * lambda stays below their limit
(`simulator.STABILITY_LIMITS`), where lambda is the largest decay rate of the linearised
dynamics. It is largest at rest: there the regularised sign x / sqrt(x^2 + eps^2) has slope
1 / eps, so every Coulomb-type term (b, b_r, C_r, Stribeck, per-wheel friction...) acts like a
viscous term of coefficient (size / eps). Rather than summing formulas term by term, this
differentiates the kernel's own derivative at rest (central differences of one tiny Heun step),
so an effect added later is counted without touching this module.
"""

from __future__ import annotations

import numpy as np

from omnibench.model import kernel
from omnibench.model.terms import Layout

H_PROBE = 1e-9  # s: one Heun step this short returns X + h f(X) to ~1e-9 relative
DELTA = 1e-6  # perturbation of each speed (m/s, rad/s): far inside the sign widths (>= 1e-3)
GROUND_DOFS = (kernel.X_V, kernel.X_V + 1, kernel.X_V + 2)  # body velocity v1, v2, psi_dot
UPSIDE_DOWN_DOFS = tuple(kernel.X_PHID + j for j in range(4))  # free wheel speeds


def decay_rates(X0, RV, P, EN, Rm, Sm, Minv, M, lay: Layout) -> np.ndarray:
    """Largest decay rate (1/s) of the speeds' dynamics at rest with zero duty, for B prepared
    trajectories (the kernel's stacked input arrays): max real part of the eigenvalues of
    -d(speed_dot)/d(speed)."""
    B = X0.shape[0]
    lam = np.zeros(B)
    upside = RV[:, kernel.RV["mode"]] != 0.0
    for rows, dofs in ((np.flatnonzero(~upside), GROUND_DOFS), (np.flatnonzero(upside), UPSIDE_DOWN_DOFS)):
        if rows.size:
            lam[rows] = _decay_rates(rows, dofs, X0, RV, P, EN, Rm, Sm, Minv, M, lay)
    return lam


def _decay_rates(rows, dofs, X0, RV, P, EN, Rm, Sm, Minv, M, lay: Layout) -> np.ndarray:
    d = len(dofs)
    n = rows.size * 2 * d  # each trajectory with each speed nudged up and down
    take = lambda a: np.ascontiguousarray(np.repeat(a[rows], 2 * d, axis=0))  # noqa: E731
    X = take(X0)
    X[:, list(dofs)] = 0.0
    bump = np.zeros((2 * d, len(dofs)))
    for j in range(d):
        bump[2 * j, j], bump[2 * j + 1, j] = DELTA, -DELTA
    X[:, list(dofs)] += np.tile(bump, (rows.size, 1))
    XF = kernel.load_kernel(lay).run_serial(
        X, take(RV), take(P), take(EN), take(Rm), take(Sm), take(Minv), take(M),
        np.zeros(1, dtype=np.int64), np.zeros((1, 1, 4)), 0.0, H_PROBE, np.ones(1, dtype=np.int64),
        kernel.METHOD_HEUN, 1, np.zeros((n, 0, 1)))
    f = ((XF - X)[:, list(dofs)] / H_PROBE).reshape(rows.size, d, 2, d)  # (traj, nudged dof, +/-, rate)
    J = np.transpose((f[:, :, 0, :] - f[:, :, 1, :]) / (2.0 * DELTA), (0, 2, 1))  # J[b, i, j] = d f_i / d x_j
    return np.real(np.linalg.eigvals(-J)).max(axis=1)
