"""Predictor's prediction cache: a parameter set asked for again is not simulated again, and
the numbers are bit for bit those of a new simulation (issue 34)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def obs(truth):
    from omnibench.analysis.simcampaign import simulated_observations

    return simulated_observations(truth, seed=3, procedures=("sweep", "forward"))


def test_cached_predictions_equal_fresh_ones(robot, obs):
    from omnibench.analysis.predictor import Predictor

    r1, r2 = robot, robot.replace(b=0.45, C_r=0.03)
    pred = Predictor(obs)
    first = pred.predict([r1, r2])
    n = pred.simulated
    assert n > 0
    again = pred.predict([r2, r1, r2])
    assert pred.simulated == n  # nothing simulated: all three from the cache
    np.testing.assert_array_equal(again, first[[1, 0, 1]])
    fresh = Predictor(obs).predict([r2, r1])
    np.testing.assert_array_equal(fresh, first[[1, 0]])
    # another sub-step count is another simulation
    pred.predict([r1], substeps=pred.substeps([r1]) + 1)
    assert pred.simulated > n


def test_skipped_blocks_copy_robot_zero_from_the_cache(robot, obs):
    """same_as_first (fitting's Jacobian): blocks known not to depend on a parameter copy robot
    0's numbers, also when robot 0 comes from the cache; such rows are not cached."""
    from omnibench.analysis.predictor import Predictor

    pred = Predictor(obs)
    base = robot.replace(a_r=2.5)
    shifted = base.replace(a_r=2.6)  # the roller terms do not act upside down nor going straight
    full = Predictor(obs).predict([base, shifted])
    skip = {k: {1} for k in pred.groups}
    pred.predict([base])
    n = pred.simulated
    out = pred.predict([base, shifted], same_as_first=skip)
    assert pred.simulated == n  # every block of `shifted` copied, robot 0 from the cache
    np.testing.assert_array_equal(out, full)
    out = pred.predict([shifted])  # not cached from the copied row: simulated now
    assert pred.simulated > n
    np.testing.assert_array_equal(out[0], full[1])


def test_model_fitted_to_these_runs_is_not_fitted_again(robot, truth, tmp_path):
    """diagnose starts from a model file `omnibench fit` wrote for the same runs (its [fit] table
    carries digests of the observations and of the fitted robot); any change means a refit."""
    from omnibench.analysis.fitting import fit, refit_needed
    from omnibench.analysis.model_file import load_model, write_model
    from omnibench.analysis.simcampaign import simulated_observations

    obs = simulated_observations(truth, seed=5, procedures=("sweep",))
    res = fit(robot, obs, procedures=["sweep"])
    path = write_model(tmp_path / "model.toml", res)
    model, info = load_model(path)
    assert info["fitted"] == res.fitted
    assert not refit_needed(model, obs, ["sweep"], info)
    assert refit_needed(model.replace(m=model.m + 0.1), obs, ["sweep"], info)  # an edited model
    other = simulated_observations(truth, seed=6, procedures=("sweep",))
    assert refit_needed(model, other, ["sweep"], info)  # other runs
    assert refit_needed(model, obs, ["sweep", "forward"], info)  # other procedures
    assert refit_needed(robot, obs, ["sweep"], {})  # a plain robot file


def test_a_row_with_copied_blocks_is_cached_for_the_groups_it_simulated(robot, obs):
    """The cache is per group: a Jacobian row whose sweep block was copied (same_as_first) is
    found again for the forward runs it simulated; only its sweep block is simulated later."""
    from omnibench.analysis.predictor import Predictor

    pred = Predictor(obs)
    base = robot.replace(a_r=2.5)
    shifted = base.replace(C_r=0.03)  # rolling resistance does not act upside down
    full = Predictor(obs).predict([base, shifted])
    pred.predict([base, shifted], same_as_first={("sweep",): {1}})
    n = pred.simulated
    out = pred.predict([shifted])
    assert pred.simulated == n + 1  # the sweep group only: the forward block came from the cache
    np.testing.assert_array_equal(out[0], full[1])


def test_repeated_runs_are_simulated_once_with_the_same_numbers(robot, obs, monkeypatch):
    """Trajectories with the same duties, world and supply (a campaign repeats a forward run at
    one duty) are one simulation: the predictions equal those of simulating every one."""
    from omnibench.analysis import predictor as predictor_module
    from omnibench.analysis.predictor import Predictor, _Group

    g = Predictor(obs).groups[("forward",)]
    first, inverse = g.distinct()
    assert len(first) < len(g.scen)  # the simulated campaign repeats its forward duties
    _, U, _, _ = g.built()
    for b, k in enumerate(inverse):
        np.testing.assert_array_equal(U[b], U[first[k]])
        assert g.scen[b] == g.scen[first[k]]
    sizes: list[int] = []
    real = predictor_module.simulate_batch

    def counting(robots, *args, **kw):
        sizes.append(len(robots))
        return real(robots, *args, **kw)

    monkeypatch.setattr(predictor_module, "simulate_batch", counting)
    robots = [robot, robot.replace(C_r=0.03)]
    deduplicated = Predictor(obs).predict(robots)
    assert sizes == [2 * 32, 2 * len(first)]
    monkeypatch.setattr(_Group, "distinct", lambda self: (list(range(len(self.scen))),
                                                          np.arange(len(self.scen))))
    every = Predictor(obs).predict(robots)
    np.testing.assert_array_equal(deduplicated, every)


def test_several_parameter_sets_equal_each_set_alone(robot, obs):
    """A call with several parameter sets simulates them trajectory-major (one trajectory under
    several sets in a lane group): each set's predictions are bit for bit those of that set
    alone, with and without declared effects (a trajectory's numbers do not depend on its lane)."""
    from omnibench.analysis.predictor import Predictor

    with_effects = robot.replace(effects={"stribeck_friction": {"b_s": 0.05, "w_s": 1.0},
                                          "battery_resistance": {"R_b": 0.1}})
    for base in (robot, with_effects):
        robots = [base.replace(a=base.a * s, C_r=0.02 * s) for s in (0.9, 1.0, 1.05, 1.1, 1.2)]
        together = Predictor(obs).predict(robots, substeps=8)
        for k, r in enumerate(robots):
            np.testing.assert_array_equal(together[k], Predictor(obs).predict([r], substeps=8)[0])
