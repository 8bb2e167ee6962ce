"""Cluster-robust standard errors (diagnosis/robust_se.py) against Monte-Carlo spreads."""

import numpy as np

from omnibench.analysis.diagnosis.robust_se import cluster_se


def _trials(block_noise: float, n_trials: int = 300, seed: int = 0):
    """Fit y = x0 + x1 t by least squares with unit white noise plus a per-block offset of
    std `block_noise` (residuals correlated inside each of 40 blocks of 25 samples)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 1000)
    clusters = np.repeat(np.arange(40), 25)
    J = np.column_stack([np.ones_like(t), t])
    est, ses = [], []
    for _ in range(n_trials):
        y = rng.normal(size=t.size) + block_noise * rng.normal(size=40)[clusters]
        x, *_ = np.linalg.lstsq(J, y, rcond=None)
        r = y - J @ x
        s = np.sqrt(np.mean(r ** 2))  # profiled scale, as diagnosis weights its residuals
        est.append(x)
        ses.append(cluster_se(J / s, r / s, clusters))
    return np.std(est, axis=0), np.median(ses, axis=0), np.sqrt(np.diag(np.linalg.pinv(J.T @ J)))


def test_independent_residuals_keep_the_textbook_se():
    spread, se, _ = _trials(0.0)
    assert np.all(np.abs(se / spread - 1) < 0.25)


def test_block_correlated_residuals_widen_the_se_to_the_true_spread():
    spread, se, textbook = _trials(1.0)
    assert np.all(spread > 2.5 * textbook)  # the textbook value is far too small here
    assert np.all(np.abs(se / spread - 1) < 0.3)


def test_too_few_clusters_fall_back_to_the_textbook_se():
    J = np.column_stack([np.ones(10), np.arange(10.0)])
    r = np.ones(10)
    se = cluster_se(J, r, np.zeros(10))
    assert np.allclose(se, np.sqrt(np.diag(np.linalg.pinv(J.T @ J))))
