"""The tail probabilities the diagnosis tests need, from scipy.special: the functions
scipy.stats evaluates for them, without importing scipy.stats (~2 s of one thread on the 2-core
machine, in every `omnibench diagnose`; scipy.special comes with scipy.optimize anyway). Equal
to scipy.stats bit for bit, edge cases included (tests/analysis/test_probabilities.py)."""

from __future__ import annotations

import math

from scipy import special


def chi2_sf(x: float, dof: float) -> float:
    """P(X > x) for X ~ chi-square(dof): `stats.chi2.sf` (1 below the support)."""
    return 1.0 if x < 0 else float(special.chdtrc(dof, x))


def chi2_isf(p: float, dof: float) -> float:
    """The x with P(X > x) = p for X ~ chi-square(dof): `stats.chi2.isf`."""
    return float(special.chdtri(dof, p))


def f_sf(x: float, dfn: float, dfd: float) -> float:
    """P(X > x) for X ~ F(dfn, dfd): `stats.f.sf` (1 below the support)."""
    return 1.0 if x < 0 else float(special.fdtrc(dfn, dfd, x))


def norm_cdf(z: float) -> float:
    """P(Z <= z) for a standard normal Z: `stats.norm.cdf`."""
    return float(special.ndtr(z)) if not math.isnan(z) else math.nan
