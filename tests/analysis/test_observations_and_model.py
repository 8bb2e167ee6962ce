"""Observations from run directories, the predictor against closed forms, model files."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import brentq

from omnibench.analysis.fitting import predict_observations
from omnibench.analysis.model_file import load_model, write_model
from omnibench.analysis.observations import Observations, slope_fit
from omnibench.analysis.simcampaign import simulated_observations
from omnibench.errors import UserError
from omnibench.model.smooth import wheel_sign


def test_slope_fit_of_an_exact_line_and_of_noise():
    t = np.linspace(0, 0.3, 31)
    phi = np.column_stack([2.0 * t + 1.0, -3.5 * t])
    w, se = slope_fit(t, phi, floor=0.0)
    np.testing.assert_allclose(w, [2.0, -3.5], atol=1e-12)
    assert np.all(se < 1e-10)
    # the floor: an angle read to +-lsb/sqrt(12) gives a slope error sigma / sqrt(sum (t - mean)^2)
    w, se = slope_fit(t, phi, floor=0.01)
    np.testing.assert_allclose(se, 0.01 / math.sqrt(np.sum((t - t.mean()) ** 2)))
    rng = np.random.default_rng(0)
    ws = [slope_fit(t, 2 * t + rng.normal(0, 0.01, t.size))[0][0] for _ in range(400)]
    assert np.std(ws) == pytest.approx(0.01 / math.sqrt(np.sum((t - t.mean()) ** 2)), rel=0.15)


from omnibench.model.kernel import EXACT_SIGN_WIDTH  # noqa: E402


def test_sweep_prediction_equals_the_closed_form_steady_state(truth):
    """Upside down: eta k_t (u V - k_e w)/R_a = (1 + c F)(a w + b sign(w)) at steady state (the
    wheels' dry friction is exact there: stick-slip)."""
    rows = []
    for k, (u, mass) in enumerate([(0.1, 0.9), (0.4, 0.9), (-0.7, 1.9), (0.9, 1.9)]):
        rows.append({"run": "cf", "step": k, "wheel": 1, "u": u, "direction": np.sign(u), "wheel_mass": mass,
                     "F_N": mass * 9.80665, "omega": 1.0, "omega_se": 0.01, "current": 0.0, "current_se": 0.01,
                     "n": 30, "steady": True})
    obs = Observations(sweep=pd.DataFrame(rows))
    pred = predict_observations(truth, obs)
    for k, r in enumerate(rows):
        F, u = r["F_N"], r["u"]

        def torque(w):
            i = (u * truth.V_batt - truth.k_e * w) / truth.R_a
            return truth.eta * truth.k_t * i - (1 + truth.c * F) * (truth.a * w + truth.b * wheel_sign(w, EXACT_SIGN_WIDTH))

        w = brentq(torque, -30, 30, xtol=1e-12)
        i = (u * truth.V_batt - truth.k_e * w) / truth.R_a
        got = pred[(pred["step"] == k)].set_index("signal")["predicted"]
        assert got["omega"] == pytest.approx(w, rel=1e-6)
        assert got["current"] == pytest.approx(i, rel=1e-6)


def _write_energy_run(tmp_path, truth):
    """An energy run directory written with the runs writer from a simulated trajectory."""
    from omnibench.model import Scenario, simulate
    from omnibench.runs import RunWriter

    t_cmd = [0.0, 1.0, 2.0]
    U = [[0.3, 0.3, 0.3, 0.3], [-0.3, 0.3, 0.3, -0.3], [0.0, 0.0, 0.0, 0.0]]
    sim = simulate(truth, Scenario(), t_cmd, U, 2.5)  # 1 ms records
    w = RunWriter.create(tmp_path, "energy_trajectories", counts_per_rev=truth.counts_per_rev)
    V, I, T = [], [], []
    with w:
        for n in range(0, len(sim), 10):  # 100 Hz telemetry
            row = sim.iloc[n]
            # a sample is read before the command it triggers acts (at t = 0: the robot at rest)
            before = sim.iloc[n - 1] if n else {"V_batt": truth.V_batt, "I_batt": truth.I_0}
            # like an omnibench board: each sample reports the duty that acted over the interval before it
            k = min(int(np.searchsorted(t_cmd, row["t"] - 1e-9, side="right")) - 1, 2)
            u = U[k] if k >= 0 else [0.0] * 4
            w.sample({"step": 0, "t": 10.0 + row["t"], "seq": n, **{f"u{j + 1}": u[j] for j in range(4)},
                      **{f"enc{j + 1}": int(math.floor(row[f"phi{j + 1}"] * truth.counts_per_rev / (2 * math.pi)))
                         for j in range(4)},
                      "V_batt": before["V_batt"], "I_batt": before["I_batt"]})
            V.append(before["V_batt"])
            I.append(before["I_batt"])
            T.append(row["t"])
        E = float(np.trapezoid(np.array(V) * np.array(I), np.array(T)))
        w.step_complete({"step": 0, "trajectory": "forward_then_left", "duration": 2.0, "payload": 0.0,
                         "t_start": 10.0, "t_end": 12.5, "energy": E, "has_current": True})
    return w.path, E


def test_energy_run_directory_round_trip_and_validation(tmp_path, truth, robot):
    from omnibench.analysis.validate import validate_energy

    path, E = _write_energy_run(tmp_path, truth)
    obs = Observations.from_runs([tmp_path], truth)
    assert len(obs.energy) == 1 and obs.energy["measured_J"].iloc[0] == pytest.approx(E)
    tr = obs.traces[(obs.energy["run"].iloc[0], 0)]
    assert tr["t"].iloc[0] == pytest.approx(0.0) and tr["phi1"].iloc[0] == 0.0
    val = validate_energy(truth, obs)
    assert abs(val.table["error_pct"].iloc[0]) < 0.5
    assert abs(validate_energy(robot.replace(b=0.9), obs).table["error_pct"].iloc[0]) > 5


def test_from_runs_errors_are_one_line(tmp_path):
    with pytest.raises(UserError, match="no such run directory"):
        Observations.from_runs([tmp_path / "nope"])
    with pytest.raises(UserError, match="no run directory here"):
        Observations.from_runs([tmp_path])


def test_model_file_round_trip(tmp_path, robot, truth):
    from omnibench.analysis.fitting import fit

    obs = simulated_observations(truth, seed=2, procedures=["sweep"])
    res = fit(robot, obs, ["a", "b", "c"])
    path = write_model(tmp_path / "model.toml", res, ["runs/x"])
    back, info = load_model(path)
    assert back.a == pytest.approx(res.values["a"]) and back.c == pytest.approx(res.values["c"])
    assert back.k_e == robot.k_e
    assert info["runs"] == ["runs/x"] and info["procedures"] == ["sweep"]
    assert info["parameters"]["b"]["se"] == pytest.approx(res.se["b"])
    assert info["parameters"]["b"]["ci95"][0] < back.b < info["parameters"]["b"]["ci95"][1]
    assert info["parameters"]["a"]["verdict"] == "identified"
    from omnibench.model import load_robot

    assert load_robot(path).b == back.b  # a model file works wherever a robot file does
    # a plain robot file is a model file without [fit]
    from omnibench.model.robot import DEFAULT_ROBOT_FILE

    r2, info2 = load_model(DEFAULT_ROBOT_FILE)
    assert info2 == {} and r2.a == robot.a
    bad = tmp_path / "bad.toml"
    bad.write_text("[fit\n")
    with pytest.raises(UserError, match="not valid TOML"):
        load_model(bad)
    with pytest.raises(UserError, match="not found"):
        load_model(tmp_path / "missing.toml")
