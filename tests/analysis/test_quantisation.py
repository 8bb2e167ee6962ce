"""The stated error of a speed read from encoder counts against Monte Carlo over the mounting phase."""

from __future__ import annotations

import math

import numpy as np
import pytest

from omnibench.analysis.observations import slope_fit
from omnibench.analysis.quantisation import encoder_slope_fit, quantised_slope

CPR = 980
LSB = 2 * math.pi / CPR
RATE = 100.0


def _readings(t, omega, phase, noise=0.0, rng=None):
    """Angles (rad) read in whole counts of a wheel turning at omega, mounting phase in counts."""
    x = omega * t + (rng.normal(0.0, noise, t.size) if noise else 0.0)
    return np.floor(x / LSB + phase) * LSB


@pytest.mark.parametrize("omega, window", [(0.3, 1.5), (2.8, 3.0), (1.0, 0.3)])
def test_the_rounding_variance_of_a_slope_is_the_monte_carlo_one_over_the_phase(omega, window):
    """With no speed band, aᵀCa is the slope's error variance over a uniform phase (exact)."""
    t = np.arange(int(window * RATE)) / RATE
    phases = (np.arange(2000) + 0.5) / 2000
    errs = np.array([slope_fit(t, _readings(t, omega, o))[0][0] - omega for o in phases])
    var, _ = quantised_slope(t, omega, CPR, band=0.0)
    assert math.sqrt(var) == pytest.approx(errs.std(), rel=0.03)


@pytest.mark.parametrize("window, noise", [(0.3, 0.0), (1.5, 0.0), (3.0, 0.0), (1.5, 0.3), (3.0, 1.0)])
@pytest.mark.parametrize("speeds", [(0.2, 0.5), (2.0, 5.0)])
def test_stated_speed_errors_are_honest_over_speeds_and_phases(window, noise, speeds):
    """Over uniform speeds (slow and fast) and phases the error over the stated SE has RMS about
    1, with and without white angle noise (in counts) before the rounding. The textbook SE of the
    same slope (rounding taken as independent) gives 0.35 for slow wheels over 1.5 s and 0.74 for
    fast ones: wrong, and by a different factor at each speed."""
    rng = np.random.default_rng(3)
    t = np.arange(int(window * RATE)) / RATE
    z, z_textbook = [], []
    for omega in rng.uniform(*speeds, 40):
        for o in rng.random(6):
            phi = _readings(t, omega, o, noise * LSB, rng)
            w, se = encoder_slope_fit(t, phi, CPR)
            _, se_tb = slope_fit(t, phi, floor=LSB / math.sqrt(12))
            z.append((w[0] - omega) / se[0])
            z_textbook.append((w[0] - omega) / se_tb[0])
    rms = math.sqrt(float(np.mean(np.square(z))))
    assert 0.8 < rms < 1.25, rms
    if noise == 0.0 and window == 1.5 and speeds[0] < 1.0:
        assert math.sqrt(float(np.mean(np.square(z_textbook)))) < 0.5


def test_slow_wheels_are_not_trusted_more_than_their_rounding_allows():
    """Two wheel speeds of a benchmark lateral design: at 0.258 rad/s over 1.5 s the rounding
    error is 0.56 x the textbook figure, at 2.8 rad/s over 3 s 0.18 x: one noise scale per
    group cannot be right for both."""
    slow = np.arange(150) / RATE
    fast = np.arange(300) / RATE
    floor = LSB / math.sqrt(12) / math.sqrt(float(np.sum((slow - slow.mean()) ** 2)))
    floor_fast = LSB / math.sqrt(12) / math.sqrt(float(np.sum((fast - fast.mean()) ** 2)))
    r_slow = math.sqrt(quantised_slope(slow, 0.258, CPR, band=0.0)[0]) / floor
    r_fast = math.sqrt(quantised_slope(fast, 2.8, CPR, band=0.0)[0]) / floor_fast
    assert r_slow > 2.5 * r_fast, (r_slow, r_fast)


def test_evenly_and_unevenly_spaced_readings_give_the_same_error():
    """The Toeplitz shortcut for evenly spaced readings agrees with the full covariance."""
    t = np.arange(300) / RATE
    jittered = t + np.r_[np.zeros(299), 1e-7]
    for omega in (0.3, 2.8):
        even = quantised_slope(t, omega, CPR, white=1e-6)
        uneven = quantised_slope(jittered, omega, CPR, white=1e-6)
        assert even == pytest.approx(uneven, rel=1e-4)


def test_noise_well_above_a_count_gives_the_textbook_error():
    """Limit: white noise of 3 counts dithers the rounding away; the error is the textbook one."""
    rng = np.random.default_rng(5)
    t = np.arange(150) / RATE
    phi = _readings(t, 1.3, 0.4, 3 * LSB, rng)
    _, se = encoder_slope_fit(t, phi, CPR)
    _, se_tb = slope_fit(t, phi)
    assert se[0] == pytest.approx(se_tb[0], rel=0.05)


def test_the_supply_at_rest_averages_the_adc_dither_and_drops_glitches():
    """A battery read through the firmware's 10-bit ADC and 6:1 divider (a 29.3 mV code, each
    reading at its code's centre) with half a code of conversion noise: the median is one code's
    centre (24.7 V sits 0.09 code above a code's bottom, so the median reads 12 mV high); the supply
    taken is within a millivolt, and readings of 0.5 V (glitches) do not move it."""
    import pandas as pd

    from omnibench.analysis.observations import supply_at_rest

    code = 5.0 / 1024 * 6.0
    rng = np.random.default_rng(4)
    v = (np.floor((24.7 + rng.normal(0.0, code / 2, 4000)) / code) + 0.5) * code
    v[::500] = 0.5
    samples = pd.DataFrame({"V_batt": v, **{f"u{j}": 0.0 for j in range(1, 5)}})
    assert abs(float(np.median(v)) - 24.7) > 0.005  # what a median of the codes gives
    assert supply_at_rest(samples) == pytest.approx(24.7, abs=0.001)
