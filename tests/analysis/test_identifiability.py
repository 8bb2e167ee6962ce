"""The fit says what a data set cannot separate (docs/fit.md, "Identifiability verdicts"), instead of printing a number for each."""

from __future__ import annotations

import math

import pytest

from omnibench.analysis.fitting import fit
from omnibench.analysis.observations import Observations
from omnibench.analysis.simcampaign import simulated_observations
from omnibench.errors import UserError


@pytest.fixture(scope="module")
def sweep_no_current(truth):
    return simulated_observations(truth, seed=5, procedures=["sweep"], current=False)


@pytest.fixture(scope="module")
def one_load_no_current(sweep_no_current):
    obs = sweep_no_current
    first = obs.sweep[obs.sweep["wheel_mass"] == obs.sweep["wheel_mass"].min()]
    return obs.select(steps={(r, int(s)) for r, s in zip(first["run"], first["step"])})


def test_without_current_a_and_back_emf_are_not_separable(robot, one_load_no_current):
    obs = one_load_no_current
    assert not obs.has_current and obs.sweep["wheel_mass"].nunique() == 1
    res = fit(robot, obs, ["a", "b", "k_e"])
    # a and k_e: one combination only; k_e (the motor constant) is held, a is reported conditional on it
    assert res.identifiable["k_e"].status == "not identifiable"
    assert math.isnan(res.se["k_e"]) and res.values["k_e"] == robot.k_e
    assert res.identifiable["a"].status == "conditional"
    assert "k_e" in res.identifiable["a"].reason
    assert res.rank == 2 and res.condition_number > 1e5
    assert "k_e" in res.fixed


def test_default_fit_without_current_flags_a_as_conditional_on_back_emf(robot, one_load_no_current):
    res = fit(robot, one_load_no_current)
    assert set(res.free) == {"a", "b", "c"}
    assert res.identifiable["a"].status == "conditional"
    assert "back-EMF" in res.identifiable["a"].reason
    assert any(c["fixed"] == "k_e" and "a" in c["with"] for c in res.confounded)
    # a single wheel load: c cannot be told from a scaling of a and b
    assert res.identifiable["c"].status == "not identifiable"
    assert math.isnan(res.se["c"])


def test_with_current_a_and_k_e_separate(robot, truth):
    obs = simulated_observations(truth, seed=6, procedures=["sweep"])
    first = obs.sweep[obs.sweep["wheel_mass"] == obs.sweep["wheel_mass"].min()]
    one = obs.select(steps={(r, int(s)) for r, s in zip(first["run"], first["step"])})
    res = fit(robot, one, ["a", "b", "k_e", "R_a"])
    F = float(one.sweep["F_N"].iloc[0])
    for p in ("a", "b", "k_e", "R_a"):
        assert res.identifiable[p].status == "identified", (p, res.identifiable[p])
        # c is held at the robot file's value, so a and b come out as the load-scaled friction
        k = (1 + truth.c * F) / (1 + robot.c * F) if p in ("a", "b") else 1.0
        assert abs(res.values[p] - k * getattr(truth, p)) < 3 * res.se[p], p
    assert res.rank == 4 and res.condition_number < 1e3
    assert not res.confounded


def test_parameter_without_information_is_not_identifiable(robot, sweep_no_current):
    res = fit(robot, sweep_no_current, ["a", "b", "C_r"])  # upside down: no rolling contact
    assert res.identifiable["C_r"].status == "not identifiable"
    assert "no information" in res.identifiable["C_r"].reason
    assert res.identifiable["b"].ok


def test_bad_parameter_names_are_one_line_errors(robot, sweep_no_current):
    with pytest.raises(UserError, match="cannot fit 'zeta'"):
        fit(robot, sweep_no_current, ["a", "zeta"])
    with pytest.raises(UserError, match="declares no effect"):
        fit(robot, sweep_no_current, ["stribeck_friction.b_s"])
    with pytest.raises(UserError, match="no observations"):
        fit(robot, Observations(), ["a"])


def test_declared_effect_parameters_are_fitted_through_the_simulator(robot):
    """Generic over terms: a world with Stribeck friction, the robot declaring it."""
    truth = robot.replace(a=0.02, b=0.45, c=0.015, effects={"stribeck_friction": {"b_s": 0.2, "w_s": 1.0, "c_s": 0.01}})
    obs = simulated_observations(truth, seed=4, procedures=["sweep"])
    start = robot.replace(effects={"stribeck_friction": {"b_s": 0.1, "w_s": 1.5, "c_s": 0.01}})
    res = fit(start, obs, ["a", "b", "c", "stribeck_friction.b_s", "stribeck_friction.w_s"])
    assert res.values["stribeck_friction.b_s"] == pytest.approx(0.2, abs=3 * res.se["stribeck_friction.b_s"])
    assert res.values["stribeck_friction.w_s"] == pytest.approx(1.0, abs=3 * res.se["stribeck_friction.w_s"])
    assert res.robot.effects["stribeck_friction"]["b_s"] == res.values["stribeck_friction.b_s"]
    for p in ("a", "b", "c"):
        assert abs(res.values[p] - getattr(truth, p)) < 3 * res.se[p]


def test_effect_redundant_with_a_paper_term_is_held_not_the_paper_term(robot, real_runs):
    """b plus four per-wheel Coulomb offsets: only four combinations are seen on four wheels."""
    declared = robot.replace(effects={"per_wheel_friction": {f"db_{j}": 0.0 for j in range(1, 5)}})
    obs = Observations.from_runs([real_runs["results_jacked"]], declared)
    names = ["a", "b"] + [f"per_wheel_friction.db_{j}" for j in range(1, 5)]
    res = fit(declared, obs, names)
    held = [p for p in names if res.identifiable[p].status == "not identifiable"]
    assert len(held) == 1 and held[0].startswith("per_wheel_friction.")
    assert res.rank == 5 and res.identifiable["b"].ok and math.isfinite(res.se["b"])
    # the wheels' Coulomb levels come out as b + db_j: 1 and 2 above 3 and 4 (as the per-wheel fits say)
    level = {j: res.values["b"] + (0.0 if f"per_wheel_friction.db_{j}" in held else res.values[f"per_wheel_friction.db_{j}"])
             for j in range(1, 5)}
    assert min(level[1], level[2]) > max(level[3], level[4])
