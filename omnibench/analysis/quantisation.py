"""Encoder quantisation: how much error a speed read from whole counts really carries.

An angle read in whole counts carries the rounding error e = floor(x + o) - x (x the true
angle in counts, o the encoder's unknown mounting phase). It is a fixed function of the angle,
not fresh noise: over a uniform phase o, two readings d counts apart have covariance
C(d) = 1/12 - f(1 - f)/2, f = frac(d) (the sawtooth's autocovariance; in Fourier form
sum_n cos(2 pi n d) / (2 pi^2 n^2)).

A steady wheel speed is the least-squares slope of such angles over a window. The textbook
slope error (residual scatter over sqrt(sum (t - tbar)^2)) treats the rounding errors as
independent; they are not, and the error it states is wrong by a factor that depends on the
speed: on the simulated robot (980 counts/rev, 100 Hz) the true spread is 0.18 x the stated one
at 2.8 rad/s over 3 s, but 0.55-0.6 x at 0.26-0.35 rad/s over 1.5 s. A fit that scales one
noise figure per group (set by the fast wheels) then trusts the slow wheels 2-3 x too much,
and those carry the roller terms (docs/design.md). `encoder_slope_fit` states each slope's
error as the rounding covariance gives it at that speed and window, plus whatever residual
scatter rounding does not explain (ripple, timing), taken as white noise added before the rounding (which it dithers).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

FOURIER_TERMS = 24  # terms damped explicitly; the tail (variance share 1/(2 pi^2 M) ~ 2 %) stays undamped
ROW_CHUNK = 512  # rows of a covariance built at once (memory: chunk x samples doubles)
#: The rounding covariance of a slope swings sharply with the speed near rational steps per
#: sample (a whole count per sample makes every reading round alike), and the slope is read at
#: the estimated speed, not the true one: it is averaged over a Gaussian speed band of
#: SPEED_BAND counts over the window (sd SPEED_BAND lsb / T). Measured over uniform speeds and
#: phases at 980 counts/rev, 100 Hz (0.2-6 rad/s; windows 0.3, 1.5, 3 s), the RMS of error over
#: stated SE is 1.17 / 1.05 / 1.03 at 0.25, but 1.95 / 1.79 / 1.19 at 0.02 (the estimate lands in
#: a resonance's dip that the truth is not in); at 1 a fast wheel's error is over-stated 2 x.
SPEED_BAND = 0.25


def sawtooth_cov(d: np.ndarray, sigma: np.ndarray | float = 0.0) -> np.ndarray:
    """Covariance (count^2) of the rounding errors of two angles d counts apart, uniform
    mounting phase, with the difference known to a Gaussian uncertainty sigma (counts)."""
    d = np.asarray(d, dtype=float)
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), d.shape)
    if not np.any(sigma > 0):
        f = np.mod(d, 1.0)
        return 1.0 / 12.0 - 0.5 * f * (1.0 - f)
    out = np.empty(d.shape)
    # one pass over the elements (diagnose's robust SEs call this on ~1100 x 1100 angle pairs per
    # run and wheel, twice per fit: numpy's 24 terms x 8 array temporaries took half the CPU of
    # `diagnose --loro` on the 2019 logs)
    _sawtooth_damped(np.ascontiguousarray(d).reshape(-1), np.ascontiguousarray(sigma).reshape(-1), out.reshape(-1),
                     FOURIER_DENOMINATORS)
    return out


#: 2 pi^2 n^2, n = 1..FOURIER_TERMS: the sawtooth covariance's Fourier terms are cos(2 pi n d) over these
FOURIER_DENOMINATORS = np.array([2.0 * math.pi ** 2 * n * n for n in range(1, FOURIER_TERMS + 1)])


@njit(cache=True)
def _sawtooth_damped(d: np.ndarray, sigma: np.ndarray, out: np.ndarray, denominator: np.ndarray) -> None:
    """sawtooth_cov element by element (`sawtooth_damped_one`)."""
    for i in range(d.size):
        out[i] = sawtooth_damped_one(d[i], sigma[i] ** 2, denominator)


@njit(cache=True)
def sawtooth_damped_one(d: float, sigma2: float, denominator: np.ndarray) -> float:
    """sawtooth_cov of one angle distance d (counts) known to variance sigma2 (counts^2): the
    closed form minus its first Fourier terms (cos(2 pi n d) / denominator[n-1]) damped by
    exp(-2 pi^2 n^2 sigma2); cos(2 pi n d) by the angle-addition recurrence and the damping
    q^(n^2) by q^((n+1)^2) = q^(n^2) q^(2n+1): three transcendental calls, not 72."""
    f = d - math.floor(d)
    o = 1.0 / 12.0 - 0.5 * f * (1.0 - f)
    c1, s1 = math.cos(2.0 * math.pi * d), math.sin(2.0 * math.pi * d)
    cn, sn = c1, s1
    q = math.exp(-2.0 * math.pi ** 2 * sigma2)
    q2 = q * q
    pn, rn = q, q * q2
    for n in range(denominator.size):
        o -= cn * (1.0 - pn) / denominator[n]
        cn, sn = cn * c1 - sn * s1, sn * c1 + cn * s1
        pn, rn = pn * rn, rn * q2
    return o


def quantised_slope(t: np.ndarray, omega: float, counts_per_rev: float, white: float = 0.0,
                    band: float = SPEED_BAND) -> tuple[float, float]:
    """Error of a least-squares slope fitted to angles read in whole counts at times t (s) of a
    wheel turning steadily at omega (rad/s), over a uniform mounting phase and a Gaussian speed
    band of `band` counts over the window, with white angle noise of variance `white` (rad^2)
    before the rounding (which dithers it): the slope's error variance (rad^2/s^2) and the
    residual scatter per reading it leaves (rad^2)."""
    t = np.asarray(t, dtype=float)
    n = len(t)
    lsb = 2.0 * math.pi / float(counts_per_rev)
    tc = t - t.mean()
    sxx = float(tc @ tc)
    span = float(t.max() - t.min()) if n else 0.0
    if n < 3 or sxx <= 0 or span <= 0:
        return float("nan"), float("nan")
    vecs = np.stack([tc / sxx, np.full(n, 1.0 / math.sqrt(n)), tc / math.sqrt(sxx)])
    acc = np.zeros(3)
    dither = 2.0 * white / lsb ** 2  # two independent readings' noise blurs their distance (count^2)
    own = 1.0 / 12.0 + white / lsb ** 2  # a reading's own error: rounding (uniform phase) plus its noise
    step = np.diff(t)
    if np.ptp(step) <= 1e-9 * max(float(step.mean()), 1e-300):
        # evenly spaced readings: C depends on the lag alone (Toeplitz), v'Cv = sum_k c_k r_k(v)
        lag = np.arange(n) * float(step.mean())
        c = sawtooth_cov(omega / lsb * lag, np.sqrt((band * lag / span) ** 2 + dither))
        c[0] = own
        for k, v in enumerate(vecs):
            r = np.correlate(v, v, mode="full")[n - 1:]
            acc[k] = c[0] * r[0] + 2.0 * float(c[1:] @ r[1:])
    else:
        for s in range(0, n, ROW_CHUNK):
            dt = t[s:s + ROW_CHUNK, None] - t[None, :]
            C = sawtooth_cov(omega / lsb * dt, np.sqrt((band * dt / span) ** 2 + dither))
            i = np.arange(C.shape[0])
            C[i, s + i] = own
            acc += np.einsum("kn,nm,km->k", vecs[:, s:s + ROW_CHUNK], C, vecs)
    slope_var = acc[0] * lsb ** 2
    # E[e' (I - H) e] = tr C - tr(H C), H the projection on [1, t]
    resid_var = max(n * own - acc[1] - acc[2], 0.0) / (n - 2) * lsb ** 2
    return slope_var, resid_var


def slope_se_at(t: np.ndarray, omega: float, s2: float, counts_per_rev: float) -> float:
    """Standard error (rad/s) of a least-squares slope of angles read in whole counts at times t
    (s), for a wheel turning at omega (rad/s) whose line fit left a residual scatter s2 (rad^2 per
    reading): rounding's error at that speed and window, plus the scatter rounding does not
    explain (s2 less what rounding leaves at that speed) taken as white angle noise before the
    rounding. `encoder_slope_fit` evaluates it at the fitted slope; a fit that weights by it
    evaluates it again at the model's prediction (`omnibench.analysis.fitting`), since at the
    step's own slope it follows that slope's own error (see `speed_se_at_prediction`)."""
    if not math.isfinite(omega) or not math.isfinite(s2):
        return float("nan")
    v, r = quantised_slope(t, float(omega), counts_per_rev)
    white = max(float(s2) - r, 0.0)  # scatter that rounding does not explain
    if white > 0:
        v, _ = quantised_slope(t, float(omega), counts_per_rev, white=white)
    return math.sqrt(v) if math.isfinite(v) else float("nan")


def line_fit(t: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares slope of each column of phi (n, k) against t and the residual scatter it
    leaves per reading (sum of squares / (n - 2)); NaN with fewer than 3 readings."""
    t = np.asarray(t, dtype=float)
    phi = np.asarray(phi, dtype=float)
    if phi.ndim == 1:
        phi = phi[:, None]
    n = len(t)
    if n < 3:
        return np.full(phi.shape[1], np.nan), np.full(phi.shape[1], np.nan)
    tc = t - t.mean()
    sxx = float(np.sum(tc * tc))
    slope = (tc @ (phi - phi.mean(axis=0))) / sxx
    res = phi - phi.mean(axis=0) - np.outer(tc, slope)
    return slope, np.sum(res * res, axis=0) / (n - 2)


def encoder_slope_fit(t: np.ndarray, phi: np.ndarray, counts_per_rev: float) -> tuple[np.ndarray, np.ndarray]:
    """Straight-line fit of wheel angles (rad) read in whole counts against time (s): slope
    (rad/s) and its standard error per column of phi (n, k). The error is rounding's at that
    slope and window (see the module docstring), with the residual scatter rounding does not
    explain taken as white angle noise before the rounding (`slope_se_at`)."""
    slope, s2 = line_fit(t, phi)
    t = np.asarray(t, dtype=float)
    se = np.array([slope_se_at(t, float(w), float(v), counts_per_rev) for w, v in zip(slope, s2)])
    return slope, se
