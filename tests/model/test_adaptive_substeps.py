"""Adaptive sub-steps on the ground (kernel.ADAPT_LIMITS, simulate_batch(adaptive=True), issue 34):
the same trajectories as the fixed sub-step count to well within measurement noise, batch
independence kept, nothing changed upside down."""

from __future__ import annotations

import numpy as np
import pytest

from omnibench.model.robot import default_robot
from omnibench.model.scenario import Scenario
from omnibench.model.simulator import simulate_batch

T = np.array([0.0, 1.5, 2.0, 3.0])
CASES = {
    "forward": np.array([[0.5] * 4, [0.0] * 4, [0.0] * 4, [0.0] * 4]),
    "lateral": np.array([[0.5, -0.5, -0.5, 0.5], [0.0] * 4, [0.0] * 4, [0.0] * 4]),
    "diagonal": np.array([[0.5, 0.0, 0.0, 0.5], [0.0] * 4, [0.0] * 4, [0.0] * 4]),
    "reversals": np.array([[0.5] * 4, [-0.5] * 4, [-0.5, 0.5, 0.5, -0.5], [0.3, 0.1, -0.2, 0.0]]),
}
SIGNALS = ("x", "y", "psi", "v1", "v2", "psi_dot", "phi1", "phi2", "phi3", "phi4", "E_batt", "i1", "i2")
# Measurement noise of what the fits use (docs/robot-file.md, analysis/quantisation.py): tape
# ~1 mm, encoder speeds ~1e-2 rad/s, currents ~1e-2 A, energies ~0.1 J. The bounds below are
# 100x or more below it.
BOUND = {"x": 1e-5, "y": 1e-5, "psi": 1e-5, "v1": 1e-4, "v2": 1e-4, "psi_dot": 1e-4, "phi1": 1e-4,
         "phi2": 1e-4, "phi3": 1e-4, "phi4": 1e-4, "E_batt": 1e-3, "i1": 1e-3, "i2": 1e-3}


def _diff(a, b):
    return {c: float(np.max(np.abs(a.signal(c) - b.signal(c)))) for c in SIGNALS}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("effects", [{}, {"stribeck_friction": {}, "driver_deadband": {"u_0": 0.04}}])
def test_adaptive_matches_fixed_substeps_far_within_noise(case, effects):
    robot = default_robot()
    for payload in (0.0, 4.0):
        sc = Scenario(mode="ground", payload=payload, effects=effects)
        fixed = simulate_batch(robot, sc, T, CASES[case], 4.0, record_every=5)
        adapt = simulate_batch(robot, sc, T, CASES[case], 4.0, record_every=5, adaptive=True)
        # against a finer fixed step: the adaptive step's own error is larger than the fixed
        # count's where speeds reverse (y 1.4e-6 m against 1.0e-7 m) but as far within the noise
        fine = simulate_batch(robot, sc, T, CASES[case], 4.0, record_every=5, substeps=40)
        d, e_fixed, e_adapt = _diff(fixed, adapt), _diff(fixed, fine), _diff(adapt, fine)
        for c in SIGNALS:
            assert d[c] <= BOUND[c], (case, payload, c, d[c])
            assert e_adapt[c] <= e_fixed[c] + BOUND[c], (case, payload, c, e_adapt[c], e_fixed[c])


def test_adaptive_trajectory_does_not_depend_on_its_batch():
    robot = default_robot()
    sc = Scenario(mode="ground")
    robots = [robot, robot.replace(b=0.3), robot.replace(a_r=1.0), robot.replace(C_r=0.05), robot.replace(b_r=2.0)]
    U = CASES["reversals"]
    batch = simulate_batch(robots, sc, T, U, 4.0, record_every=5, adaptive=True, substeps=9)
    for k in (0, 1, 4):
        one = simulate_batch(robots[k], sc, T, U, 4.0, record_every=5, adaptive=True, substeps=9)
        np.testing.assert_allclose(batch.array[k], one.array[0], rtol=1e-11, atol=1e-12)


def test_adaptive_changes_nothing_upside_down():
    robot = default_robot()
    sc = Scenario(mode="upside_down")
    U = CASES["reversals"]
    a = simulate_batch(robot, sc, T, U, 4.0, record_every=5)
    b = simulate_batch(robot, sc, T, U, 4.0, record_every=5, adaptive=True)
    np.testing.assert_array_equal(a.array, b.array)
