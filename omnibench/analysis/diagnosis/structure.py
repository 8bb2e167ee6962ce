"""Structure left in residuals: where a model is still wrong.

For every group of entries (procedure/signal) and every variable the residual may depend on
(speed, duty, load F_N, direction, wheel, time, current, payload, step order), two tests on
the normalised residuals z = (y - f) / (s_g sigma):

- binned means: the entries are binned by the variable (its distinct values when few, else
  up to 8 quantile bins); T = sum_b (mean_b / SE_b)^2 with SE_b from the pooled within-bin
  scatter is chi^2(B) when every bin mean is zero (no structure). Bins whose mean is more than
  3 SE from zero are reported as the location.
- runs test (continuous variables): the signs of z sorted by the variable (block means of
  up to 40 blocks); too few runs (Wald-Wolfowitz, one-sided) means the residual has a smooth
  shape along it.

A finding is significant when its p-value is below ALPHA divided by the number of tests made
(Bonferroni), so a clean model has about ALPHA probability of showing any structure at all.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from omnibench.analysis.diagnosis.probabilities import f_sf, norm_cdf

ALPHA = 1e-3
MAX_BINS = 8
MIN_ENTRIES = 8
VARIABLES = {
    # variable: (table column, unit, continuous)
    "speed": ("speed", "rad/s", True),
    "duty": ("u", "1", True),
    "load": ("F_N", "N", False),
    "direction": ("direction", "", False),
    "wheel": ("wheel", "", False),
    "wheel x direction": ("wheel_direction", "", False),
    "time": ("time", "s", True),
    "time since duty change": ("since_step", "s", True),
    "current": ("current", "A", True),
    "payload": ("payload", "kg", False),
    "step": ("step", "", True),
}


@dataclass
class Finding:
    """One significant (or tested) residual structure."""

    group: str
    variable: str
    test: str
    statistic: float
    p: float
    n: int
    where: list[dict[str, Any]]

    @property
    def score(self) -> float:
        """-log10 p (capped), a size for comparing structure before and after."""
        return float(min(-math.log10(max(self.p, 1e-300)), 300.0))

    def location(self) -> str:
        """Words: where it shows."""
        proc, _, sig = self.group.partition("/")
        sig = sig.replace("/no-se", "")
        if not self.where:
            return f"{proc} {sig} along {self.variable} ({self.test})"
        parts = []
        for w in self.where[:3]:
            rng = w["range"]
            span = f"{rng[0]:.3g}" if rng[0] == rng[1] else f"{rng[0]:.3g}..{rng[1]:.3g}"
            span += f" {w['variable_unit']}" if w.get("variable_unit") and w["variable_unit"] != "1" else ""
            parts.append(f"{self.variable} {span}: mean residual {w['mean']:+.3g} {w['unit']} ({w['z']:+.1f} SE, n={w['n']})")
        return f"{proc} {sig}: " + "; ".join(parts)

    def to_json(self) -> dict[str, Any]:
        return {"group": self.group, "variable": self.variable, "test": self.test, "statistic": self.statistic,
                "p": self.p, "n": self.n, "where": self.where, "location": self.location()}


def _bins(v: np.ndarray, continuous: bool) -> np.ndarray:
    uniq = np.unique(v)
    if len(uniq) <= 6 or not continuous:
        return np.searchsorted(uniq, v)
    nb = int(min(MAX_BINS, max(2, len(v) // 6)))
    edges = np.unique(np.quantile(v, np.linspace(0, 1, nb + 1)))
    return np.clip(np.searchsorted(edges, v, side="right") - 1, 0, len(edges) - 2)


RUNS_BLOCKS = 40


def _block_means(z_sorted: np.ndarray) -> np.ndarray:
    """Means of consecutive blocks (at most RUNS_BLOCKS of them): the runs test then sees the
    residual's shape, not the short-range pattern of encoder quantisation in finite-difference
    speeds."""
    n = len(z_sorted)
    if n <= RUNS_BLOCKS * 2:
        return z_sorted
    edges = np.linspace(0, n, RUNS_BLOCKS + 1).astype(int)
    return np.array([z_sorted[a:b].mean() for a, b in zip(edges[:-1], edges[1:])])


def _runs_p(z_sorted: np.ndarray) -> float:
    s = z_sorted > 0
    n1, n2 = int(s.sum()), int((~s).sum())
    n = n1 + n2
    if n1 == 0 or n2 == 0 or n < 10:
        return 1.0
    runs = 1 + int(np.sum(s[1:] != s[:-1]))
    mu = 2.0 * n1 * n2 / n + 1
    var = 2.0 * n1 * n2 * (2.0 * n1 * n2 - n) / (n * n * (n - 1))
    if var <= 0:
        return 1.0
    return norm_cdf((runs - mu) / math.sqrt(var))


SPEED_SIGNALS = ("omega", "w")
CURRENT_SIGNALS = ("current",)


def analyse(table, residual: np.ndarray, z: np.ndarray, used: np.ndarray, group: np.ndarray,
            alpha: float = ALPHA, variables: Sequence[str] = tuple(VARIABLES),
            predicted: np.ndarray | None = None) -> tuple[list[Finding], int]:
    """All structure tests on (residual, z). Returns (every test's finding, number of tests).

    Binning a residual by its own measured value (a noisy speed by speed) makes structure out
    of noise (regression to the mean), so for speed and current entries the speed / current
    variable is the model's `predicted` value when given."""
    out: list[Finding] = []
    table = table.copy()
    if predicted is not None and "signal" in table.columns:
        sig = table["signal"].astype(str).to_numpy()
        if "speed" in table.columns:
            table["speed"] = np.where(np.isin(sig, SPEED_SIGNALS), predicted, table["speed"].to_numpy(float))
        if "current" in table.columns:
            table["current"] = np.where(np.isin(sig, CURRENT_SIGNALS), predicted, table["current"].to_numpy(float))
    for g in sorted(set(group[used])):
        m = used & (group == g) & np.isfinite(z)
        if m.sum() < MIN_ENTRIES:
            continue
        runit = str(table["unit"].to_numpy()[m][0]) if "unit" in table.columns else ""
        for var in variables:
            col, unit, continuous = VARIABLES[var]
            if col == "wheel_direction" and {"wheel", "direction"} <= set(table.columns):
                v = table["wheel"].to_numpy(dtype=float) * np.sign(table["direction"].to_numpy(dtype=float))
            elif col not in table.columns:
                continue
            else:
                v = table[col].to_numpy(dtype=float)
            mm = m & np.isfinite(v)
            if mm.sum() < MIN_ENTRIES or len(np.unique(v[mm])) < 2:
                continue
            vv, zz, rr = v[mm], z[mm], residual[mm]
            b = _bins(vv, continuous)
            nb = int(b.max()) + 1
            means = np.array([zz[b == k].mean() if np.any(b == k) else 0.0 for k in range(nb)])
            counts = np.array([np.sum(b == k) for k in range(nb)])
            within = sum(float(np.sum((zz[b == k] - means[k]) ** 2)) for k in range(nb))
            dof_w = max(int(counts.sum()) - nb, 1)
            s2 = max(within / dof_w, 1e-12)
            ok = counts > 0
            zb = np.where(ok, means / np.sqrt(s2 / np.maximum(counts, 1)), 0.0)
            T = float(np.sum(zb[ok] ** 2))
            dof = int(ok.sum())
            # with few entries per bin use the F distribution (the scatter is estimated)
            p = f_sf(T / dof, dof, dof_w)
            where = []
            for k in np.argsort(-np.abs(zb)):
                if not ok[k] or abs(zb[k]) < 3.0:
                    continue
                sel = b == k
                where.append({"range": [float(vv[sel].min()), float(vv[sel].max())], "variable_unit": unit,
                              "unit": runit, "mean": float(rr[sel].mean()), "z": float(zb[k]), "n": int(sel.sum())})
            out.append(Finding(g, var, "binned means", T, p, int(mm.sum()), where))
            if continuous and len(np.unique(vv)) > 6:
                order = np.argsort(vv, kind="stable")
                p_r = _runs_p(_block_means(zz[order]))
                out.append(Finding(g, var, "runs test", float("nan"), p_r, int(mm.sum()), where if p_r < alpha else []))
    return out, len(out)


def significant(findings: list[Finding], n_tests: int, alpha: float = ALPHA) -> list[Finding]:
    """Findings below the Bonferroni threshold alpha / n_tests, strongest first."""
    thr = alpha / max(n_tests, 1)
    return sorted([f for f in findings if f.p < thr], key=lambda f: f.p)
