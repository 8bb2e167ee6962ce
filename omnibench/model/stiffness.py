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

from typing import Any

import numpy as np

from omnibench.model import kernel
from omnibench.model.terms import Layout

H_PROBE = 1e-9  # s: the probe step; its own bias is removed exactly (see _decay_rates)
NUDGE = 1e-4  # speed perturbation as a fraction of the narrowest sign width it reaches
UPSIDE_DOWN_NUDGE = 0.1  # rad/s: the nudge's reference speed upside down (x NUDGE)
STICK_OFFSET = 10.0  # upside down: probe at least this many nudges above zero speed
#: Upside down, the probe's slowest speed must stay this many times the speed its probe step
#: takes off (dry friction over the inertia, x H_PROBE) above zero: a probe step that reaches
#: zero sticks the wheel, and the "rate" read is 1 / H_PROBE (1e9 /s: 400 000 sub-steps per
#: 1 ms physics step, one simulation of the 2019 square waves for hours) instead of the
#: viscous one. At STICK_OFFSET nudges (1e-4 rad/s) a wheel with b = 0.38 N m sticks so for
#: any I_w below 3.8e-6 kg m^2 (b H_PROBE / I_w = 1e-4 rad/s), which a fit's trial step can
#: ask for (I_w's lower bound is 1e-6): tests/model/test_stiffness_light_wheel.py.
STICK_MARGIN = 4.0
STICK_PROBES = 6  # probes at most (offsets up to ~4^5 STICK_OFFSET)
GROUND_DOFS = (kernel.X_V, kernel.X_V + 1, kernel.X_V + 2)  # body velocity v1, v2, psi_dot
UPSIDE_DOWN_DOFS = tuple(kernel.X_PHID + j for j in range(4))  # free wheel speeds


def decay_rates(X0, RV, P, EN, Rm, Sm, Minv, M, lay: Layout) -> np.ndarray:
    """Largest decay rate (1/s) of the speeds' dynamics at rest with zero duty, for B prepared
    trajectories (the kernel's stacked input arrays): max real part of the eigenvalues of
    -d(speed_dot)/d(speed).

    A fit asks for the rates of the same rows again and again (every trajectory of every
    parameter set at each simulate_batch call, and Predictor.substeps; most rows of a call
    differ only in their commands, which the rates do not see): each distinct row (all its
    inputs, byte for byte) is computed once per process and remembered (issue 34: 0.5-1 s of
    CPU of an `omnibench fit`)."""
    B = X0.shape[0]
    arrays = (X0, RV, P, EN, Rm, Sm, Minv, M)
    cache = _rates_cache(lay)
    keys = _row_keys(arrays, B)
    todo: dict[bytes, int] = {}
    for b, key in enumerate(keys):
        if key not in cache and key not in todo:
            todo[key] = b
    if todo:
        rows = np.fromiter(todo.values(), dtype=np.int64, count=len(todo))
        X0r, RVr, Pr, ENr, Rmr, Smr, Minvr, Mr = (np.ascontiguousarray(a[rows]) for a in arrays)
        lam = _decay_rates_of_rows(X0r, RVr, Pr, ENr, Rmr, Smr, Minvr, Mr, lay)
        if len(cache) + len(todo) > 100_000:
            cache.clear()
        for key, x in zip(todo, lam):
            cache[key] = float(x)
    return np.array([cache[key] for key in keys], dtype=float)


def _row_keys(arrays, B: int) -> list[bytes]:
    """Each row's bytes over every array, in order (row b of each, as `tobytes`), as one string
    per row: the same key as joining each array's row, built with one copy instead of B x arrays."""
    if B == 0:
        return []
    rows = np.concatenate([np.ascontiguousarray(a).reshape(B, -1).view(np.uint8) for a in arrays], axis=1)
    return [r.tobytes() for r in rows]


_RATES: dict[int, tuple[Layout, dict[bytes, float]]] = {}


def _rates_cache(lay: Layout) -> dict[bytes, float]:
    """The remembered rates of one layout (its kernel)."""
    got = _RATES.get(id(lay))
    if got is None or got[0] is not lay:
        got = _RATES[id(lay)] = (lay, {})
    return got[1]


def _decay_rates_of_rows(X0, RV, P, EN, Rm, Sm, Minv, M, lay: Layout) -> np.ndarray:
    """`decay_rates` computed (no cache)."""
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
    # (STICK_OFFSET x the probe nudge, more for a light wheel: _upside_down_rates), on one side
    # of the sign's jump.
    up_nudge = NUDGE * np.full_like(eps_phi, UPSIDE_DOWN_NUDGE)
    rows = np.flatnonzero(~upside)
    if rows.size:
        lam[rows] = _decay_rates(rows, GROUND_DOFS, ground_nudge[rows], X0, RV, P, EN, Rm, Sm, Minv, M, lay)
    rows = np.flatnonzero(upside)
    if rows.size:
        lam[rows] = _upside_down_rates(rows, up_nudge[rows], X0, RV, P, EN, Rm, Sm, Minv, M, lay)
    return lam


def _upside_down_rates(rows, nudge, X0, RV, P, EN, Rm, Sm, Minv, M, lay: Layout) -> np.ndarray:
    """Decay rates upside down, probed about a small positive speed: STICK_OFFSET nudges, or more
    where the probe step's own fall of speed would bring the slowest probe within STICK_MARGIN
    times that fall of zero (a light wheel with dry friction: the probe must not stick). A probe
    that stuck saw only part of the fall (to zero), so such rows are probed again from an offset
    of at least STICK_MARGIN times what they saw, until the margin holds (at most STICK_PROBES
    probes; the fall barely depends on the speed this close to zero, so once a probe does not
    stick the next keeps the margin)."""
    lam = np.zeros(rows.size)
    offset = np.full(rows.size, STICK_OFFSET)
    todo = np.arange(rows.size)
    for _ in range(STICK_PROBES):
        got, drop = _decay_rates(rows[todo], UPSIDE_DOWN_DOFS, nudge[todo], X0, RV, P, EN, Rm, Sm, Minv, M, lay,
                                 offset[todo], with_drop=True)
        lam[todo] = got
        need = 1.0 + STICK_MARGIN * drop / nudge[todo]  # offset (in nudges) that keeps the margin
        short = need > offset[todo]
        offset[todo[short]] = need[short]
        todo = todo[short]
        if not todo.size:
            break
    return lam


def _decay_rates(rows, dofs, nudge, X0, RV, P, EN, Rm, Sm, Minv, M, lay: Layout,
                 offset: float | np.ndarray = 0.0, center: np.ndarray | None = None,
                 with_drop: bool = False) -> Any:
    """The rates of `rows`, their speeds `dofs` nudged by `nudge` (per row) about rest, or
    about `center` ((rows, d) speeds), shifted by `offset` nudges (a number, or one per row).
    with_drop: (rates, per row the largest fall of a probed speed in the probe step)."""
    d = len(dofs)
    n = rows.size * 2 * d  # each trajectory with each speed nudged up and down
    take = lambda a: np.ascontiguousarray(np.repeat(a[rows], 2 * d, axis=0))  # noqa: E731
    X = take(X0)
    X[:, list(dofs)] = 0.0 if center is None else np.repeat(center, 2 * d, axis=0)
    sign = np.zeros((2 * d, d))
    for j in range(d):
        sign[2 * j, j], sign[2 * j + 1, j] = 1.0, -1.0
    shift = np.repeat(np.broadcast_to(np.asarray(offset, dtype=float), (rows.size,)), 2 * d)[:, None]
    X[:, list(dofs)] += (np.tile(sign, (rows.size, 1)) + shift) * np.repeat(nudge, 2 * d)[:, None]
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
    lam = np.real(-z).max(axis=1)
    if not with_drop:
        return lam
    fall = (X - XF)[:, list(dofs)].reshape(rows.size, 2 * d * d).max(axis=1)
    return lam, np.maximum(fall, 0.0)


#: Factor on the sign widths that takes the signs' slope out of the rate (ground_split).
WIDE = 1e4
#: Wheel speeds (in sign widths) where ground_split checks its bound.
SPEEDS = (3.0, 10.0, 30.0, 100.0)


def ground_split(lam: np.ndarray, X0, RV, P, EN, Rm, Sm, Minv, M, lay: Layout) -> np.ndarray:
    """RV with its lam_base, lam_phi, lam_sigma filled for ground trajectories (kernel's
    adaptive sub-steps, kernel.ADAPT_LIMITS): the decay rate at rest without the signs' slope
    (both widths x WIDE), and what the wheel signs and the roller signs each add to it. The
    parts are scaled up, when they fall short, so that they add up to at least `lam` (the rate
    at rest with both, `decay_rates`): the kernel's bound is never below the fixed count's."""
    RV = np.array(RV, dtype=float, copy=True)
    ground = np.flatnonzero(RV[:, kernel.RV["mode"]] == 0.0)
    if not ground.size:
        return RV
    # the rates do not depend on the supply (zero duty at rest): rows that differ only in it,
    # and rows seen before, are computed once
    keep = np.ones(RV.shape[1], dtype=bool)
    keep[[kernel.RV["V_batt"], kernel.RV["lam_base"], kernel.RV["lam_phi"], kernel.RV["lam_sigma"]]] = False
    lam = np.asarray(lam, dtype=float)
    keys = _row_keys((RV[ground][:, keep], P[ground], EN[ground], Rm[ground], Sm[ground], M[ground], lam[ground]),
                     ground.size)
    todo: dict[bytes, int] = {}
    for key, b in zip(keys, ground):
        if key not in _SPLITS and key not in todo:
            todo[key] = int(b)
    if todo:
        rows = np.array(list(todo.values()))
        parts = _ground_split(lam[rows], X0[rows], RV[rows], P[rows], EN[rows], Rm[rows], Sm[rows], Minv[rows],
                              M[rows], lay)
        if len(_SPLITS) + len(todo) > 100_000:
            _SPLITS.clear()
        for key, part in zip(todo, parts):
            _SPLITS[key] = part
    for key, b in zip(keys, ground):
        RV[b, [kernel.RV["lam_base"], kernel.RV["lam_phi"], kernel.RV["lam_sigma"]]] = _SPLITS[key]
    return RV


_SPLITS: dict[bytes, np.ndarray] = {}


def _ground_split(lam, X0, RV, P, EN, Rm, Sm, Minv, M, lay: Layout) -> np.ndarray:
    """(lam_base, lam_phi, lam_sigma) (n, 3) of ground rows (`ground_split`)."""
    ground = np.arange(RV.shape[0])
    iphi, isig = kernel.RV["sign_width_phi"], kernel.RV["sign_width_sigma"]
    take = lambda a: np.ascontiguousarray(a[ground])  # noqa: E731
    X0g, RVg, Pg, ENg, Rmg, Smg, Minvg, Mg = (take(a) for a in (X0, RV, P, EN, Rm, Sm, Minv, M))

    def rate(f_phi: float, f_sig: float) -> np.ndarray:
        rv = RVg.copy()
        rv[:, iphi] *= f_phi
        rv[:, isig] *= f_sig
        return decay_rates(X0g, rv, Pg, ENg, Rmg, Smg, Minvg, Mg, lay)

    base = rate(WIDE, WIDE)
    lam_phi = np.maximum(rate(1.0, WIDE) - base, 0.0)
    lam_sig = np.maximum(rate(WIDE, 1.0) - base, 0.0)
    total = np.asarray(lam, dtype=float)[ground]
    short = total - (base + lam_phi + lam_sig)
    parts = lam_phi + lam_sig
    grow = np.where((short > 0) & (parts > 0), 1.0 + short / np.where(parts > 0, parts, 1.0), 1.0)
    base = np.where((short > 0) & (parts <= 0), total, base)
    lam_phi, lam_sig = lam_phi * grow, lam_sig * grow
    # The bound assumes every sign-like term has the robot's widths and forms (tanh on wheel
    # speeds, algebraic on roller slip); a term with a wider sign of its own (Stribeck's
    # max(eps, w_s / 2)) keeps more slope away from zero. Check the bound where the robot
    # moves (wheels at SPEEDS x eps_phi, forward, sideways and turning) against the rate
    # measured there, and raise lam_base by any shortfall.
    rv = RVg
    eps_phi, eps_sig = rv[:, iphi], rv[:, isig]
    r = rv[:, kernel.RV["r"]]
    n = ground.size
    probes = [(x, axis) for x in SPEEDS for axis in range(3)]
    centers = np.zeros((len(probes), n, 3))
    for c, (x, axis) in enumerate(probes):
        centers[c, :, axis] = x * eps_phi * r * (1.0 if axis < 2 else 1.0 / (rv[:, kernel.RV["L"]] + rv[:, kernel.RV["l"]]))
    nudge = NUDGE * np.minimum(eps_phi * r / (1.0 + rv[:, kernel.RV["L"]] + rv[:, kernel.RV["l"]]), eps_sig / 1.5)
    # every probe's rates in one kernel call (the rows repeated per probe): `got` does not
    # depend on the bound that the loop below raises
    rows = np.tile(np.arange(n), len(probes))
    got_all = _decay_rates(rows, GROUND_DOFS, np.tile(nudge, len(probes)), X0g, RVg, Pg, ENg, Rmg, Smg, Minvg, Mg,
                           lay, center=centers.reshape(-1, 3)).reshape(len(probes), n)
    for c, center in enumerate(centers):
        got = got_all[c]
        w = np.einsum("bjk,bk->bj", Rmg, center)
        s = np.einsum("bjk,bk->bj", Smg, center)
        f_phi = np.max(1.0 - np.tanh(np.abs(w) / eps_phi[:, None]) ** 2, axis=1)
        f_sig = np.max((1.0 + (s / eps_sig[:, None]) ** 2) ** -1.5, axis=1)
        bound = base + lam_phi * f_phi + lam_sig * f_sig
        base = base + np.maximum(got - bound, 0.0) * 1.2
    return np.column_stack([base, np.maximum(lam_phi, 1e-300), lam_sig])
