"""The one least-squares engine (analysis/least_squares.py) that fit, diagnose and the planner share."""

from __future__ import annotations

import numpy as np
import pytest

from omnibench.analysis import least_squares
from omnibench.analysis.diagnosis import engine
from omnibench.analysis.predictor import PHYSICS_DT, Predictor
from omnibench.analysis.simcampaign import simulated_observations
from omnibench.model import default_robot


def test_a_latency_is_differenced_over_one_physics_step_in_the_fit_as_in_diagnose():
    """One step rule: a relative step of each scale, a latency exactly one physics step (its
    prediction jumps where a reversal's crossing moves to the next step), whatever the
    relative step (the fit's 1e-5, diagnose's 1e-4)."""
    robot = default_robot()
    robot = robot.replace(effects={"command_latency": {"tau": 0.02}})
    params = least_squares.Parameters(robot, ["a", "command_latency.tau"])
    tau_scale = least_squares.param_scale(robot, "command_latency.tau")
    for step in (least_squares.FD_STEP, engine.FD_STEP):
        steps = params.steps(step)
        assert steps[0] == step
        assert steps[1] * tau_scale == pytest.approx(PHYSICS_DT, rel=1e-12)


def test_the_fits_jacobian_is_the_engines_differences_and_a_new_sigma_is_not_served_from_the_cache():
    """WeightedResiduals.jacobian is -(forward differences)/sigma of the used entries, bit for
    bit; setting sigma (a reweighted pass) forgets the cached Jacobian: doubling sigma halves it."""
    robot = default_robot()
    obs = simulated_observations(robot.replace(a=0.02), procedures=["sweep"], seed=5)
    pred = Predictor(obs, ["sweep"])
    used = np.isfinite(pred.measured) & np.isfinite(pred.sigma) & (pred.sigma > 0)
    wr = least_squares.weighted_residuals(robot, pred, ["a", "b"], used, pred.sigma)
    x = wr.params.x_of(robot)
    J = wr.jacobian(x)
    F = least_squares.Problem(pred, used, pred.sigma).stencil(wr.params, x, wr.steps)
    D = least_squares.Problem.differences(F, wr.steps)
    assert np.array_equal(J, -D.T[used] / pred.sigma[used][:, None])
    assert np.all(np.linalg.norm(J, axis=0) > 0)
    wr.sigma = 2.0 * pred.sigma
    assert np.array_equal(wr.jacobian(x), J / 2.0)
    assert np.array_equal(wr.prediction_at(x), F[0])
