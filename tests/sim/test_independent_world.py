"""The independent world generator (omnibench/worlds/independent.py) against closed forms and
against the model, and behind the simulated board's serial path (`sim://?plant=independent`).

It shares no numerical shortcut with the model (another integrator, exact stick-slip), so
where both implement the paper's equations they must agree to their integration errors, and
its own stick-slip must meet the closed forms (breakaway duty, exact-sign steady speed).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from omnibench.link.board import Board
from omnibench.model import Scenario, default_robot, simulate_batch
from omnibench.model.actuation import applied_duty
from omnibench.model.closed_form import upside_down_steady_speed
from omnibench.model.context import GRAVITY
from omnibench.worlds import independent

T_CMD = [0.0, 1.0, 2.0]
U_CMD = [[0.5, 0.5, 0.5, 0.5], [0.5, -0.5, 0.3, -0.3], [0.0, 0.0, 0.0, 0.0]]


def test_upside_down_breakaway_and_exact_sign_speed():
    robot = default_robot()
    FN = robot.wheel_mass[0] * GRAVITY
    u_b = robot.b * (1 + robot.c * FN) * robot.R_a / (robot.eta * robot.k_t * robot.V_batt)
    u = [0.98 * u_b, -1.1 * u_b, 0.3, -0.6]
    res = independent.simulate_batch(robot, Scenario(mode="upside_down"), [0.0], [u], 0.6, record_every=100)
    assert np.all(res.signal("phi1")[0] == 0.0) and res.signal("phi_dot1")[0, -1] == 0.0
    for j in (1, 2, 3):
        want = upside_down_steady_speed(robot, u[j], FN)
        assert res.signal(f"phi_dot{j + 1}")[0, -1] == pytest.approx(want, rel=1e-6)
    # stops dead when the drive falls below breakaway, and stays
    res = independent.simulate_batch(robot, Scenario(mode="upside_down"), [0.0, 0.3], [[0.4] * 4, [0.9 * u_b] * 4],
                                     0.8, record_every=1)
    late = res.signal("phi_dot1")[0, res.t > 0.5]
    assert np.all(late == 0.0)


@pytest.mark.parametrize("mode", ["ground", "upside_down"])
def test_agrees_with_the_model_where_both_implement_the_paper(mode):
    """Same equations, different numerics: pose within 2 mm / 2 mrad over 3 s, wheel angles
    within 0.02 rad, battery energy within 1 % (measured 0.5 % on the ground: first-order steps)."""
    robot = default_robot()
    a = independent.simulate_batch(robot, Scenario(mode=mode), T_CMD, U_CMD, 3.0, record_every=50)
    b = simulate_batch(robot, Scenario(mode=mode), T_CMD, U_CMD, 3.0, record_every=50)
    for s, tol in (("x", 2e-3), ("y", 2e-3), ("psi", 2e-3), ("phi1", 0.02), ("phi4", 0.02)):
        assert np.max(np.abs(a.signal(s)[0] - b.signal(s)[0])) < tol, s
    assert a.signal("E_batt")[0, -1] == pytest.approx(b.signal("E_batt")[0, -1], rel=1e-2)
    assert b.signal("E_batt")[0, -1] > 50.0


def test_effect_forms_differ_from_the_librarys():
    """A deadband that cuts leaves duties above u_0 untouched; the shifted one subtracts u_0."""
    robot = default_robot()
    FN = robot.wheel_mass[0] * GRAVITY
    scen = [Scenario(mode="upside_down", effects={"driver_deadband": {"u_0": 0.1, "cut": f}}) for f in (0.0, 1.0)]
    res = independent.simulate_batch(robot, scen, [0.0], [[0.3, 0.08, -0.3, 0.0]], 0.6, record_every=100)
    w = res.signal("phi_dot1")[:, -1]
    assert w[0] == pytest.approx(upside_down_steady_speed(robot, 0.2, FN), rel=1e-6)  # shifted
    assert w[1] == pytest.approx(upside_down_steady_speed(robot, 0.3, FN), rel=1e-6)  # cut
    assert np.all(res.signal("phi_dot2")[:, -1] == 0.0)  # below u_0: no drive in either form


def test_behind_the_serial_path_a_stuck_and_a_turning_wheel():
    """`sim://?plant=independent`: the board's telemetry carries the independent physics."""
    robot = default_robot()
    FN = robot.wheel_mass[0] * GRAVITY
    u_b = robot.b * (1 + robot.c * FN) * robot.R_a / (robot.eta * robot.k_t * robot.V_batt)
    with Board.open("sim://?plant=independent&mode=upside_down&seed=3&actuation=firmware") as b:
        b.configure(telemetry_hz=100)
        b.reset_encoders()
        b.set_duties([0.9 * u_b, 0.4, 0.0, 0.0])
        s = b.wait(1.0)
        b.stop()
    a0, a1 = s[len(s) // 2].wheel_angles(980), s[-1].wheel_angles(980)
    dt = s[-1].t - s[len(s) // 2].t
    assert a1[0] == a0[0]  # stuck: not one encoder count
    speed = (a1[1] - a0[1]) / dt
    # the board applies 0.4 as its drivers take it: the nearest packet-serial step, 51/127
    assert applied_duty(0.4) == pytest.approx(51 / 127)
    assert speed == pytest.approx(upside_down_steady_speed(robot, float(applied_duty(0.4)), FN),
                                  abs=2 * 2 * math.pi / 980 / dt)


def test_command_latency_is_a_pure_time_shift_per_wheel():
    """Serialised commands (tau + tau_packet x place in the send order): each wheel's speed is
    the undelayed run's, shifted by its own latency (to the half-step sampling of the hold)."""
    robot = default_robot()
    t_cmd, U = [0.0, 0.2], [[0.5] * 4, [-0.5] * 4]
    plain = independent.simulate_batch(robot, Scenario(mode="upside_down"), t_cmd, U, 0.4)
    lat = {"serial_command_latency": {"tau": 0.01, "tau_packet": 0.004}}
    late = independent.simulate_batch(robot, Scenario(mode="upside_down", effects=lat, command_order=(2, 1, 4, 3)),
                                      t_cmd, U, 0.4)
    for j, place in enumerate((1, 0, 3, 2)):
        d = int(round((0.01 + 0.004 * place) / 1e-3))
        want, got = plain.signal(f"phi_dot{j + 1}")[0], late.signal(f"phi_dot{j + 1}")[0]
        assert np.all(got[:d] == 0.0)
        assert np.max(np.abs(got[d:] - want[:len(want) - d])) < 0.05 * np.max(np.abs(want))
        assert np.max(np.abs(got[d + 3:] - want[:len(want) - d - 3])) > 0.1  # a wrong shift would not fit


def test_actuator_lag_is_the_exact_first_order_response():
    """actuator_lag in the independent world: after a duty step from 0 to 1 the seen duty is
    1 - exp(-t / tau_a), and its integral (what drives the motors) t - tau_a (1 - exp(-t / tau_a))."""
    robot = default_robot().replace(effects={"actuator_lag": {"tau_a": 0.028}})
    ph = independent.IndependentPhysics(robot, [Scenario(mode="upside_down")])
    u = np.ones((1, 4))
    integral, n = 0.0, 200
    for _ in range(n):
        integral += float(ph._actuator(u)[0, 0]) * ph.h
    t, tau = n * ph.h, 0.028
    assert ph.u_act[0, 0] == pytest.approx(1.0 - math.exp(-t / tau), rel=1e-12)
    assert integral == pytest.approx(t - tau * (1.0 - math.exp(-t / tau)), rel=1e-12)
    # off: the command passes unchanged
    plain = independent.IndependentPhysics(default_robot(), [Scenario(mode="upside_down")])
    assert not plain.lagged
