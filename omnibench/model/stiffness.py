"""Stiffness of the model at rest: how fast its speeds decay, with every enabled term.

The explicit integrators are stable while h * lambda stays below their limit
(`simulator.STABILITY_LIMITS`), where lambda is the largest decay rate of the linearised
dynamics. It is largest at rest: there the regularised sign x / sqrt(x^2 + eps^2) has slope
1 / eps, so every Coulomb-type term (b, b_r, C_r, Stribeck, per-wheel friction...) acts like a
viscous term of coefficient (size / eps). That holds on the ground; upside down the wheels stick
and slip with an exact sign (kernel.EXACT_SIGN_WIDTH), the dry friction is a constant torque
while slipping and the stick probe decides the rest, so there the rates are taken just above zero. Rather than summing formulas term by term, this
differentiates the kernel's own derivative at rest (central differences of one tiny Heun step),
so an effect added later is counted without touching this module.

Counted: every term's effect on the speeds (body velocity on the ground, wheel speeds upside
down). Not counted: terms' own states (winding temperature, time constant >= 1 s) and forces
that depend on position (cogging: oscillation at sqrt(A_c n_c / I_w) <= ~1e3 rad/s); with the
library's parameter bounds both stay far below the speeds' decay rates.
"""

from __future__ import annotations

import numpy as np

from omnibench.model import kernel
from omnibench.model.terms import Layout

H_PROBE = 1e-9  # s: the probe step; its own bias is removed exactly (see _decay_rates)
NUDGE = 1e-4  # speed perturbation as a fraction of the narrowest sign width it reaches
UPSIDE_DOWN_NUDGE = 0.1  # rad/s: the nudge's reference speed upside down (x NUDGE)
STICK_OFFSET = 10.0  # upside down: probe about this many nudges above zero speed
GROUND_DOFS = (kernel.X_V, kernel.X_V + 1, kernel.X_V + 2)  # body velocity v1, v2, psi_dot
UPSIDE_DOWN_DOFS = tuple(kernel.X_PHID + j for j in range(4))  # free wheel speeds


def decay_rates(X0, RV, P, EN, Rm, Sm, Minv, M, lay: Layout) -> np.ndarray:
    """Largest decay rate (1/s) of the speeds' dynamics at rest with zero duty, for B prepared
    trajectories (the kernel's stacked input arrays): max real part of the eigenvalues of
    -d(speed_dot)/d(speed)."""
    B = X0.shape[0]
    lam = np.zeros(B)
    rv = {name: RV[:, k] for k, name in enumerate(kernel.RV_NAMES)}
    upside = rv["mode"] != 0.0
    # a nudge of every speed far inside the regularised signs' widths: wheel speeds (rad/s)
    # respond to body velocity through R (|R| <= (1 + L + l) / r), roller slip through S (<= ~1.5)
    eps_phi, eps_sigma = rv["sign_width_phi"], rv["sign_width_sigma"]
    ground_nudge = NUDGE * np.minimum(eps_phi * rv["r"] / (1.0 + rv["L"] + rv["l"]), eps_sigma / 1.5)
    # Upside down the signs are exact and sticking is decided by the kernel's stick probe, so
    # the dry friction is no stiffness there: the speeds are nudged about a small positive speed
    # (STICK_OFFSET x the probe nudge), on one side of the sign's jump.
    up_nudge = NUDGE * np.full_like(eps_phi, UPSIDE_DOWN_NUDGE)
    for rows, dofs, nudge, offset in ((np.flatnonzero(~upside), GROUND_DOFS, ground_nudge, 0.0),
                                      (np.flatnonzero(upside), UPSIDE_DOWN_DOFS, up_nudge, STICK_OFFSET)):
        if rows.size:
            lam[rows] = _decay_rates(rows, dofs, nudge[rows], X0, RV, P, EN, Rm, Sm, Minv, M, lay, offset)
    return lam


def _decay_rates(rows, dofs, nudge, X0, RV, P, EN, Rm, Sm, Minv, M, lay: Layout, offset: float = 0.0) -> np.ndarray:
    d = len(dofs)
    n = rows.size * 2 * d  # each trajectory with each speed nudged up and down
    take = lambda a: np.ascontiguousarray(np.repeat(a[rows], 2 * d, axis=0))  # noqa: E731
    X = take(X0)
    X[:, list(dofs)] = 0.0
    sign = np.zeros((2 * d, d))
    for j in range(d):
        sign[2 * j, j], sign[2 * j + 1, j] = 1.0, -1.0
    X[:, list(dofs)] += np.tile(sign + offset, (rows.size, 1)) * np.repeat(nudge, 2 * d)[:, None]
    XF = kernel.load_kernel(lay).run_serial(
        X, take(RV), take(P), take(EN), take(Rm), take(Sm), take(Minv), take(M),
        np.zeros(1, dtype=np.int64), np.zeros((1, 1, 4)), 0.0, H_PROBE, np.ones(1, dtype=np.int64),
        kernel.METHOD_HEUN, 1, np.zeros((n, 0, 1)))
    f = ((XF - X)[:, list(dofs)] / H_PROBE).reshape(rows.size, d, 2, d)  # (traj, nudged dof, +/-, rate)
    # A[b, i, j] = d(rate_i)/d(speed_j). One Heun step of x' = J x gives (x(h) - x)/h =
    # (J + h J^2 / 2) x, so each eigenvalue mu of A is z + h z^2 / 2 for an eigenvalue z of J:
    # invert that exactly instead of carrying a bias of h lambda / 2
    A = np.transpose((f[:, :, 0, :] - f[:, :, 1, :]) / (2.0 * nudge[:, None, None]), (0, 2, 1))
    mu = np.linalg.eigvals(A).astype(complex)
    z = 2.0 * mu / (1.0 + np.sqrt(1.0 + 2.0 * H_PROBE * mu))
    return np.real(-z).max(axis=1)
