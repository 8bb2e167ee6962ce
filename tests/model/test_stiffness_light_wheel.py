"""Upside down, the integrator's sub-steps follow the wheel's viscous decay rate for every inertia
a fit may try (I_w down to its bound, 1e-6 kg m^2): the stiffness probe must not stick the wheel.

A probe step that takes the probed speed to zero (dry friction over a light wheel) was read as a
rate of 1 / H_PROBE: 400 000 sub-steps per physics step, one simulation of the 2019 square
waves for hours, where a fit of the wheel inertia's trial step asked for I_w = 3.5e-6."""

from __future__ import annotations

import pytest

from omnibench.model.robot import default_robot
from omnibench.model.scenario import Scenario
from omnibench.model.simulator import GRAVITY, decay_rates_of, stable_substeps


def _viscous_rate(robot) -> float:
    """d(omega')/d(omega) of a free wheel upside down at zero duty: transmission viscous term
    (scaled by the wheel's own weight) and back-EMF damping, over the inertia (1/s)."""
    F_N = max(robot.wheel_mass) * GRAVITY
    return ((1.0 + robot.c * F_N) * robot.a + robot.eta * robot.k_t * robot.k_e / robot.R_a) / robot.I_w


@pytest.mark.parametrize("b", [0.38, 1.0])
@pytest.mark.parametrize("I_w", [2.66e-3, 1e-4, 5e-6, 3.5e-6, 1e-6])
def test_upside_down_rate_is_the_viscous_one_for_light_wheels(I_w, b):
    robot = default_robot().replace(a=0.032, b=b, I_w=I_w)
    lam = float(decay_rates_of([(robot, Scenario(mode="upside_down"))])[0])
    assert lam == pytest.approx(_viscous_rate(robot), rel=1e-3)


def test_substeps_at_the_inertia_bound_stay_a_few_hundred():
    robot = default_robot().replace(a=0.032, b=0.38, I_w=1e-6)  # I_w's lower bound in a fit
    lam = float(decay_rates_of([(robot, Scenario(mode="upside_down"))])[0])
    n = stable_substeps(lam, 1e-3)
    # the rate 8.5e5 /s over RK4's limit 2.5 at 1 ms: 342 sub-steps (400 001 when the probe stuck)
    assert n == stable_substeps(_viscous_rate(robot), 1e-3)
    assert n < 400
