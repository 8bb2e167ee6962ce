"""Held-out losses judged against their noise (analysis/heldout_noise.py)."""

import numpy as np

from omnibench.analysis.heldout_noise import change_se, worse_beyond_noise


def _trace(seed: int = 0, n: int = 400):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.03
    m = 10 * np.sign(np.sin(2 * np.pi * t / 2.0))[:, None] * np.ones((1, 4)) + 0.3 * rng.normal(size=(n, 4))
    return m, rng


def test_a_clear_loss_is_beyond_noise_and_a_reshuffle_of_the_same_noise_is_not():
    m, rng = _trace()
    a = m + 0.5 * rng.normal(size=m.shape)
    same = m + 0.5 * rng.normal(size=m.shape)  # as good as a, different noise
    worse = m + 0.5 * rng.normal(size=m.shape) + 0.6  # a bias on every sample
    assert worse_beyond_noise(m, a, worse)
    assert not worse_beyond_noise(m, a, same)


def test_correlated_errors_make_the_change_noisier():
    """The same extra error in 40-sample runs (a transient wrong for a while) rather than sample
    by sample: the block bootstrap sees fewer independent pieces, a larger standard error."""
    m, rng = _trace(1)
    a = m + 0.5 * rng.normal(size=m.shape)
    white = [change_se(m, a, a + rng.normal(size=m.shape)) for _ in range(5)]
    slow = [change_se(m, a, a + np.repeat(rng.normal(size=(10, 4)), 40, axis=0)) for _ in range(5)]
    assert np.mean(slow) > 2 * np.mean(white)
