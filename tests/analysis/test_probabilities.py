"""The diagnosis' tail probabilities (scipy.special) equal scipy.stats' bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from omnibench.analysis.diagnosis.probabilities import chi2_isf, chi2_sf, f_sf, norm_cdf

XS = [-5.0, -1e-12, 0.0, 1e-300, 1e-9, 0.3, 1.0, 2.5, 10.0, 50.0, 200.0, 1e4, math.inf, math.nan]


def same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == b


@pytest.mark.parametrize("dof", [1, 2, 3, 7, 15, 60])
def test_chi_square_tails_equal_scipy_stats(dof):
    assert all(same(chi2_sf(x, dof), float(stats.chi2.sf(x, dof))) for x in XS)
    ps = [1e-300, 1e-12, 1e-4, 0.05, 0.5, 0.999, 1.0, 0.0]
    assert all(same(chi2_isf(p, dof), float(stats.chi2.isf(p, dof))) for p in ps)


@pytest.mark.parametrize("dfn", [1, 3, 12])
@pytest.mark.parametrize("dfd", [3, 40, 1000])
def test_f_tail_equals_scipy_stats(dfn, dfd):
    assert all(same(f_sf(x, dfn, dfd), float(stats.f.sf(x, dfn, dfd))) for x in XS)


def test_normal_cdf_equals_scipy_stats():
    assert all(same(norm_cdf(z), float(stats.norm.cdf(z))) for z in [-x for x in XS] + XS)
    assert norm_cdf(0.0) == 0.5 and np.isclose(norm_cdf(1.959963984540054), 0.975)
