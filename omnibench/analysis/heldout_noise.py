"""Is a held-out run's change of error beyond its noise? A moving-block bootstrap.

Two models predict the same held-out trace; their NRMSEs differ by d = NRMSE_b - NRMSE_a. The
residuals of a trace correlate in time (a transient is wrong for several samples together), so
the noise of d is estimated by resampling whole blocks of consecutive samples (Kuensch 1989):
blocks of ceil(sqrt(n)) samples drawn with replacement, both models on the same draw, the
standard deviation of d over the draws is its standard error.
"""

from __future__ import annotations

import math

import numpy as np

N_BOOT = 300
NOISE_SE = 2.0  # a change within this many standard errors of zero is noise


def _nrmse_rows(m: np.ndarray, p: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """NRMSE over the rows of each resample (rows: (B, n) indices); NaNs ignored."""
    mm, pp = m[rows], p[rows]  # (B, n, k)
    ok = np.isfinite(mm) & np.isfinite(pp)
    num = np.sqrt(np.where(ok, (mm - pp) ** 2, 0.0).sum(axis=(1, 2)) / ok.sum(axis=(1, 2)))
    den = np.sqrt(np.where(ok, mm ** 2, 0.0).sum(axis=(1, 2)) / ok.sum(axis=(1, 2)))
    return num / den


def change_se(measured: np.ndarray, pred_a: np.ndarray, pred_b: np.ndarray, seed: int = 0) -> float:
    """Standard error of NRMSE(b) - NRMSE(a) over a trace (rows = samples in time order, columns
    = wheels), by a moving-block bootstrap; NaN for fewer than 10 samples."""
    m = np.asarray(measured, dtype=float).reshape(len(measured), -1)
    a = np.asarray(pred_a, dtype=float).reshape(m.shape)
    b = np.asarray(pred_b, dtype=float).reshape(m.shape)
    n = len(m)
    if n < 10:
        return float("nan")
    L = int(math.ceil(math.sqrt(n)))
    k = int(math.ceil(n / L))
    rng = np.random.default_rng(seed)
    starts = rng.integers(0, n - L + 1, size=(N_BOOT, k))
    rows = (starts[:, :, None] + np.arange(L)[None, None, :]).reshape(N_BOOT, -1)[:, :n]
    return float(np.std(_nrmse_rows(m, b, rows) - _nrmse_rows(m, a, rows), ddof=1))


def worse_beyond_noise(measured: np.ndarray, pred_a: np.ndarray, pred_b: np.ndarray) -> bool:
    """True when model b's NRMSE exceeds a's by more than NOISE_SE bootstrap standard errors."""
    from omnibench.analysis.predict import nrmse

    d = nrmse(measured, pred_b) - nrmse(measured, pred_a)
    se = change_se(measured, pred_a, pred_b)
    return bool(d > NOISE_SE * se) if math.isfinite(se) else d > 0
