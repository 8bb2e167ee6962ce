"""Residual structure right after a change of duty, signed by the change: the signature of
command timing (and of a wrong inertia).

A latency makes the measured speed lag the model after every change of duty: the residual is
negative after a step up and positive after a step down, so binned by time since the change
(structure.py) it cancels. Here the first SAMPLES speed samples of each wheel after each of its
duty changes are multiplied by the sign of that change, and the signed residual is tested in
cells of wheel x sample index (binned means, F test, as structure.py does): a latency shows as
a signed residual in the first samples, growing by wheel when the wheels are served one after
another.

The samples of a cell are not independent: the first interval after every duty change of one
sign starts at the same angle of the periodic orbit, so it carries the same encoder rounding
error each time (encoder_se.py), ~0.1 rad/s at 20 ms sampling, which a mean over 15 reversals
keeps. Given the run's encoder (`problem` and predictions `f`), each cell mean's variance is
widened by the rounding covariance of its samples; without, the samples count as independent.
"""

from __future__ import annotations

import numpy as np

from omnibench.analysis.diagnosis.probabilities import f_sf
from omnibench.analysis.diagnosis.structure import Finding

SAMPLES = 2  # speed samples after a duty change
VARIABLE = "first samples after a duty change x its sign (per wheel)"


def change_signs(t) -> tuple[np.ndarray, np.ndarray]:
    """For step-response entries: sign of their wheel's last duty change (+1 up, -1 down, 0 none)
    and the entry's sample index since that change (0 = the interval starting at it)."""
    out = np.zeros(len(t))
    since = np.full(len(t), -1)
    sr = t["procedure"].to_numpy() == "step_response"
    if not sr.any():
        return out, since
    for _, idx in t[sr].groupby(["run", "wheel"]).groups.items():
        idx = np.asarray(list(idx))
        tt = t.loc[idx, "time"].to_numpy(float)
        uu = t.loc[idx, "u"].to_numpy(float)
        order = np.argsort(tt, kind="stable")
        sign, prev, n = 0.0, np.nan, -1
        for k in order:
            if np.isfinite(prev) and uu[k] != prev:
                sign, n = float(np.sign(uu[k] - prev)), 0
            elif n >= 0:
                n += 1
            prev = uu[k]
            out[idx[k]] = sign
            since[idx[k]] = n
    return out, since


def _rounding_inflation(problem, f: np.ndarray, w: np.ndarray, m: np.ndarray, keys: np.ndarray,
                        cells: np.ndarray, signs: np.ndarray) -> np.ndarray:
    """Per cell: variance of its mean of signed z under the encoder-rounding covariance over that
    of independent samples (>= 1; ones when the runs carry no encoder resolution)."""
    from omnibench.analysis.diagnosis.encoder_se import meat

    used = problem.used
    rows = np.flatnonzero(m)
    pos = np.full(len(used), -1)
    pos[used] = np.arange(int(used.sum()))
    A = np.zeros((int(used.sum()), len(cells)))
    for c, cell in enumerate(cells):
        sel = keys == cell
        A[pos[rows[sel]], c] = signs[sel] / sel.sum()
    M = meat(problem, f, A, w)
    if M is None:
        return np.ones(len(cells))
    white = np.sum(A ** 2, axis=0)
    return np.maximum(np.diag(M) / np.where(white > 0, white, 1.0), 1.0)


def findings(table, residual: np.ndarray, z: np.ndarray, used: np.ndarray, group: np.ndarray,
             problem=None, f: np.ndarray | None = None, w: np.ndarray | None = None) -> list[Finding]:
    """One finding per step-response group: signed z of the first SAMPLES samples after each
    duty change, binned by wheel x sample index (cell means' variances widened by the encoder
    rounding the samples share when `problem`, predictions `f` and weights `w` are given)."""
    if not (table["procedure"].to_numpy() == "step_response").any():
        return []
    sign, since = change_signs(table)
    wheel = table["wheel"].to_numpy(dtype=float)
    out = []
    for g in sorted({x for x in group[used] if str(x).startswith("step_response/")}):
        m = used & (group == g) & np.isfinite(z) & (since >= 0) & (since < SAMPLES) & (sign != 0)
        if m.sum() < 4 * SAMPLES * 3:
            continue
        zs, rs = z[m] * sign[m], residual[m] * sign[m]
        wv = wheel[m]
        keys = wv * 10 + since[m]
        cells = np.unique(keys)
        means = np.array([zs[keys == c].mean() for c in cells])
        counts = np.array([np.sum(keys == c) for c in cells])
        within = sum(float(np.sum((zs[keys == c] - mu) ** 2)) for c, mu in zip(cells, means))
        dof_w = max(int(counts.sum()) - len(cells), 1)
        s2 = max(within / dof_w, 1e-12)
        infl = (_rounding_inflation(problem, f, w, m, keys, cells, sign[m]) if problem is not None and f is not None
                and w is not None else np.ones(len(cells)))
        zb = means / np.sqrt(s2 / counts * infl)
        T = float(np.sum(zb ** 2))
        p = f_sf(T / len(cells), len(cells), dof_w)
        where = []
        for k in np.argsort(-np.abs(zb))[:4]:
            if abs(zb[k]) < 3.0:
                continue
            sel = keys == cells[k]
            where.append({"range": [float(cells[k] % 10), float(cells[k] % 10)],
                          "variable_unit": f"(0 = first interval), wheel {int(cells[k] // 10)}",
                          "unit": str(table["unit"].to_numpy()[m][0]), "mean": float(rs[sel].mean()),
                          "z": float(zb[k]), "n": int(sel.sum()), "wheel": int(cells[k] // 10)})
        out.append(Finding(str(g), VARIABLE, "binned means", T, p, int(m.sum()), where))
    return out
