"""Black-box baselines (analysis/baseline.py) and the measured supply: closed forms, sticking,
parameter recovery, and a logged V_batt reaching the model."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from omnibench.analysis.baseline import Trace, fit_black_box, predict_trace, wheel_speeds


def _trace(duties, half=0.4, dt_log=0.02):
    t_end = half * len(duties)
    ts = np.round(np.arange(0.0, t_end, dt_log), 3)
    t_cmd = np.array([k * half for k in range(len(duties))])
    U = np.repeat(np.array(duties, dtype=float)[:, None], 4, axis=1)
    return Trace("r", ts, np.zeros((len(ts), 4)), t_cmd, U)


def test_first_order_step_matches_the_closed_form_and_a_weak_drive_sticks():
    tr = _trace([0.5, 0.5])
    K, T, c = 12.0, 0.05, 0.6
    w = wheel_speeds(tr, 0, K, T, c)
    tm = 0.5 * (tr.ts[1:] + tr.ts[:-1])
    closed = (K * 0.5 - c) * (1 - np.exp(-tm / T))  # mean over each interval ~ the midpoint value
    assert np.max(np.abs(w - closed)[tm > 0.1]) < 0.01
    assert np.all(wheel_speeds(tr, 0, K, T, c=6.5) == 0.0)  # |K u| = 6 <= c: the wheel sticks
    # a dead time delays the rise by exactly that much
    wd = wheel_speeds(tr, 0, K, T, c, d=0.04)
    assert np.allclose(wd[tm < 0.04 - 0.011], 0.0)
    late = tm > 0.2
    np.testing.assert_allclose(np.interp(tm[late] - 0.04, tm, w), wd[late], atol=0.02)


@pytest.mark.parametrize("dead_time", [False, True])
def test_fit_recovers_the_black_box_it_was_simulated_from(dead_time):
    truth = np.array([[12.0, 0.05, 0.5, 0.01], [11.0, 0.04, 0.3, 0.015],
                      [13.0, 0.06, 0.4, 0.02], [12.5, 0.03, 0.6, 0.025]])
    if not dead_time:
        truth = truth[:, :3]
    tr = _trace([0.6, -0.6, 0.3, -0.3, 0.8, 0.0])
    w = predict_trace(truth, tr)
    tr.phi = np.vstack([np.zeros(4), np.cumsum(w * np.diff(tr.ts)[:, None], axis=0)])
    bb = fit_black_box([tr], dead_time)
    np.testing.assert_allclose(bb.params, truth, rtol=0.02, atol=1e-3)
    assert bb.nrmse(tr) < 1e-3


def test_a_logged_supply_reaches_the_model(robot):
    """A sweep step whose run logged 20 V at rest is predicted at 20 V, not the robot file's."""
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.predictor import Predictor

    rows = [{"run": "r", "step": 0, "wheel": j, "u": 0.6, "direction": 1.0, "wheel_mass": 1.0, "F_N": 9.8,
             "omega": 10.0, "omega_se": 0.1, "current": math.nan, "current_se": math.nan, "n": 10,
             "steady": True, "time": 1.0, "V_batt": math.nan} for j in range(1, 5)]
    obs = Observations(sweep=pd.DataFrame(rows), runs={"r": {"procedure": "upside_down_sweep"}})
    nominal = Predictor(obs).predict([robot])[0]
    obs.runs["r"]["V_batt"] = 20.0
    logged = Predictor(obs).predict([robot])[0]
    same = Predictor(obs).predict([robot.replace(V_batt=20.0)])[0]
    np.testing.assert_allclose(logged, same, rtol=1e-12)
    assert np.all(logged < 0.9 * nominal)
