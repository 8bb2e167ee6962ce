"""Stick-slip of the wheels upside down, against closed forms (kernel.EXACT_SIGN_WIDTH).

- breakaway: a duty just below eta k_t u V / R_a = b (1 + c F_N) leaves the wheel exactly at
  rest, just above it turns at the exact-sign closed form speed (no creep, no smoothing bias);
- a wheel slowed to a sub-breakaway drive stops dead and stays stopped;
- a drive that exceeds breakaway reverses the wheel through zero without sticking;
- the energy balance closes through stick and slip transitions (the kinetic energy a stop
  removes is booked as dissipated by the transmission friction).
"""

from __future__ import annotations

import numpy as np
import pytest

from omnibench.model import Scenario, default_robot, simulate
from omnibench.model.closed_form import upside_down_steady_speed
from omnibench.model.context import GRAVITY

UP = Scenario(mode="upside_down")


def breakaway_duty(robot, F_N):
    return robot.b * (1 + robot.c * F_N) * robot.R_a / (robot.eta * robot.k_t * robot.V_batt)


@pytest.mark.parametrize("method", ["rk4", "heun"])
def test_breakaway_duty_and_exact_sign_speed_just_above(method):
    robot = default_robot()
    FN = np.asarray(robot.wheel_mass) * GRAVITY
    u_b = breakaway_duty(robot, FN)
    # wheels 1, 2 just below breakaway (both directions), 3, 4 just above
    u = np.array([0.99 * u_b[0], -0.99 * u_b[1], 1.05 * u_b[2], -1.3 * u_b[3]])
    df = simulate(robot, UP, [0.0], [u], 1.0, method=method, record_every=10)
    assert (df["phi_dot1"] == 0.0).all() and (df["phi_dot2"] == 0.0).all()
    assert (df["phi1"] == 0.0).all()
    for j in (2, 3):
        expected = upside_down_steady_speed(robot, u[j], FN[j])
        assert abs(expected) > 0.01
        assert df[f"phi_dot{j + 1}"].iloc[-1] == pytest.approx(expected, rel=1e-6)


def test_wheel_stops_dead_under_a_sub_breakaway_drive_and_stays_stopped():
    robot = default_robot()
    u_b = breakaway_duty(robot, robot.wheel_mass[0] * GRAVITY)
    # the regularised sign would creep at eps u / u_b ~ 0.09 rad/s at 0.9 u_b
    df = simulate(robot, UP, [0.0, 0.5], [[0.4] * 4, [0.9 * u_b] * 4], 1.5, record_every=1)
    assert df.loc[df["t"] < 0.5, "phi_dot1"].iloc[-1] > 5.0
    late = df.loc[df["t"] > 0.8]
    assert (late["phi_dot1"] == 0.0).all()
    assert late["phi1"].max() - late["phi1"].min() == 0.0


def test_drive_above_breakaway_reverses_through_zero():
    robot = default_robot()
    FN = robot.wheel_mass[0] * GRAVITY
    df = simulate(robot, UP, [0.0, 0.5], [[0.3] * 4, [-0.3] * 4], 1.2, record_every=1)
    after = df.loc[df["t"] > 0.5, "phi_dot1"].to_numpy()
    # at most one step sits at exactly zero on the way through (a step can end on the probe)
    assert (after == 0.0).sum() <= 1
    assert after[-1] == pytest.approx(upside_down_steady_speed(robot, -0.3, FN), rel=1e-6)


@pytest.mark.parametrize("method", ["rk4", "heun"])
def test_energy_balance_through_stick_and_slip(method):
    robot = default_robot()
    u_b = breakaway_duty(robot, robot.wheel_mass[0] * GRAVITY)
    t_cmd = [0.0, 0.4, 0.8, 1.2, 1.6, 2.0]
    u_cmd = [[0.3, -0.2, 0.5, 0.1], [0.8 * u_b] * 4, [-0.3, 0.3, 0.0, -0.6], [0.0] * 4,
             [1.2 * u_b, -1.2 * u_b, 0.5 * u_b, 0.2], [-0.5 * u_b] * 4]
    df = simulate(robot, UP, t_cmd, u_cmd, 2.5, method=method, record_every=1)
    stuck = (df[["phi_dot1", "phi_dot2", "phi_dot3", "phi_dot4"]] == 0.0).to_numpy()
    assert stuck.any(axis=0).all() and (~stuck).any(axis=0).all()  # every wheel stuck and slipped
    end, start = df.iloc[-1], df.iloc[0]
    terms = [c for c in df.columns if c.startswith("E_") and c not in
             ("E_batt", "E_copper", "E_conversion", "E_quiescent")]
    accounted = (end["E_copper"] + end["E_conversion"] + end["E_quiescent"] + sum(end[t] for t in terms)
                 + end["KE"] - start["KE"])
    assert accounted == pytest.approx(end["E_batt"], rel=1e-3)
