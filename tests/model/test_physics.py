"""The model against closed forms, the paper's world-frame equations, limits, symmetry and
energy conservation (issue 2's done-means)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from omnibench.model import Scenario, simulate, simulate_batch
from omnibench.model.context import GRAVITY
from omnibench.model.geometry import inverse_kinematics, slip_matrix
from omnibench.model.reference import eq8_accelerations
from omnibench.model.terms import all_terms

# a duty schedule that accelerates, strafes, turns and brakes (t in s, duties FL FR RL RR)
T_CMD = [0.0, 1.5, 3.0, 4.5, 6.0, 8.0]
U_CMD = [
    [0.6, 0.6, 0.6, 0.6],
    [0.5, -0.5, -0.5, 0.5],
    [0.2, 0.7, 0.2, 0.7],
    [-0.4, 0.4, -0.4, 0.4],
    [0.3, 0.1, -0.2, 0.5],
    [0.0, 0.0, 0.0, 0.0],
]


def steady_speed_closed_form(robot, u: float, F_N: float) -> float:
    """Upside-down steady state of docs/robot-file.md, the model, written out here independently of the package."""
    g = robot.eta * robot.k_t / robot.R_a
    load = 1.0 + robot.c * F_N
    s = math.copysign(1.0, u)
    return (g * u * robot.V_batt - load * robot.b * s) / (g * robot.k_e + load * robot.a)


def test_package_closed_form_agrees(omnibot):
    from omnibench.model.closed_form import upside_down_steady_speed

    for u in (0.9, -0.3):
        assert upside_down_steady_speed(omnibot, u, 8.0) == pytest.approx(steady_speed_closed_form(omnibot, u, 8.0))
    assert upside_down_steady_speed(omnibot, 0.01, 8.0) == 0.0  # below breakaway


@pytest.mark.parametrize("wheel_mass", [0.5, 1.2, 2.5])
def test_upside_down_steady_speed_matches_closed_form(omnibot, wheel_mass):
    robot = omnibot.replace(c=0.03)
    duties = [0.8, -0.8, 0.35, -0.35]
    scenario = Scenario(mode="upside_down", wheel_mass=(wheel_mass,) * 4)
    df = simulate(robot, scenario, [0.0], [duties], 1.0, record_every=10)
    F_N = wheel_mass * GRAVITY
    for j, u in enumerate(duties, start=1):
        expected = steady_speed_closed_form(robot, u, F_N)
        assert df[f"phi_dot{j}"].iloc[-1] == pytest.approx(expected, rel=1e-4)
        # the signs are right: a positive duty turns the wheel forward
        assert math.copysign(1, df[f"phi_dot{j}"].iloc[-1]) == math.copysign(1, u)


def test_heavier_wheels_turn_slower_upside_down(omnibot):
    robot = omnibot.replace(c=0.05)
    speeds = [
        simulate(robot, Scenario(mode="upside_down", wheel_mass=(m,) * 4), [0.0], [[0.5] * 4], 1.0,
                 record_every=100)["phi_dot1"].iloc[-1]
        for m in (0.5, 1.0, 2.0)
    ]
    assert speeds[0] > speeds[1] > speeds[2]


def test_below_breakaway_the_wheel_sticks(omnibot):
    """Below the breakaway duty an upside-down wheel does not move at all (stick-slip; the
    regularised wheel sign would creep at eps * artanh(tau / B)), and it does not oscillate."""
    robot = omnibot.replace(a=0.0)
    F_N = robot.wheel_mass[0] * GRAVITY
    B = (1 + robot.c * F_N) * robot.b
    g = robot.eta * robot.k_t / robot.R_a
    u = 0.5 * B / (g * robot.V_batt)  # motor stall torque is half the breakaway torque
    df = simulate(robot, Scenario(mode="upside_down"), [0.0], [[u] * 4], 2.0, record_every=10)
    assert (df["phi_dot1"] == 0.0).all() and (df["phi1"] == 0.0).all()
    assert df["i1"].iloc[-1] == pytest.approx(u * robot.V_batt / robot.R_a, rel=1e-9)  # stalled motor


def test_forward_motion_has_no_roller_slip(omnibot):
    df = simulate(omnibot, Scenario(), [0.0, 2.0], [[0.7] * 4, [-0.3] * 4], 4.0)
    S = slip_matrix(omnibot.L, omnibot.l, omnibot.alpha)
    sigma = df[["v1", "v2", "psi_dot"]].to_numpy() @ S.T
    assert np.abs(sigma).max() < 1e-12
    assert df["E_roller_friction"].abs().max() < 1e-12
    assert np.abs(df[["y", "psi"]].to_numpy()).max() < 1e-12
    assert df["x"].iloc[-1] > 0.5  # it did move


def test_a_slow_wheel_on_the_ground_gets_all_of_coulombs_friction(omnibot):
    """Driving straight at 0.26 rad/s (26 x sign_width_phi, the slowest wheels of a 60 deg
    lateral run) the steady speed is Coulomb's closed form: per wheel
    g (u V - k_e w) = (1 + c F)(a w + b) + F C_r r, g = eta k_t / R_a. The algebraic sign
    x / sqrt(x^2 + eps^2) is 7e-4 short of Coulomb there and misses it by 2e-3 of the speed."""
    w = 0.26
    F = omnibot.m * GRAVITY / 4.0
    g = omnibot.eta * omnibot.k_t / omnibot.R_a
    load = 1.0 + omnibot.c * F
    u = (g * omnibot.k_e * w + load * (omnibot.a * w + omnibot.b) + F * omnibot.C_r * omnibot.r) / (g * omnibot.V_batt)
    df = simulate(omnibot, Scenario(), [0.0], [[u] * 4], 20.0, record_every=100)
    speeds = df[[f"phi_dot{j}" for j in range(1, 5)]].iloc[-1].to_numpy()
    assert abs(df["phi_dot1"].iloc[-1] - df["phi_dot1"].iloc[-11]) < 1e-9  # settled
    assert speeds == pytest.approx([w] * 4, rel=2e-5)


def test_inverse_kinematics_is_the_usual_mecanum_pattern(omnibot):
    R = inverse_kinematics(omnibot.L, omnibot.l, omnibot.r, omnibot.alpha)
    k = omnibot.L + omnibot.l
    expected = np.array([[1, -1, -k], [1, 1, k], [1, 1, -k], [1, -1, k]]) / omnibot.r
    assert np.allclose(R, expected)
    assert np.allclose(slip_matrix(omnibot.L, omnibot.l, omnibot.alpha)[:, 0], 0.0)


def _paper_eq8(robot, scenario, t_cmd, u_cmd, t_end, roller=True):
    """Independent reference: the paper's eq. (8) in the WORLD frame with H and K as printed
    (omnibench.model.reference), integrated by scipy. Returns a function t -> (x, y, psi)."""
    t_cmd = np.asarray(t_cmd)

    def rhs(t, y):
        u = np.asarray(u_cmd[np.searchsorted(t_cmd, t, side="right") - 1], dtype=float)
        qdd = eq8_accelerations(robot, u, y[:3], y[3:], payload=scenario.payload, roller=roller)
        return np.concatenate([y[3:], qdd])

    sol = solve_ivp(rhs, (0, t_end), np.zeros(6), method="LSODA", rtol=1e-10, atol=1e-12,
                    dense_output=True, max_step=0.01, first_step=1e-5)
    assert sol.success
    return lambda t: sol.sol(t)[:3]


def test_full_model_matches_the_papers_world_frame_equation(omnibot):
    """The kernel integrates eq. (8) in the body frame; the paper writes it in the world frame
    with H(psi) and K(psi, psi_dot). Both must give the same trajectory."""
    df = simulate(omnibot, Scenario(payload=3.0), T_CMD, U_CMD, 9.0, record_every=100)
    ref = _paper_eq8(omnibot, Scenario(payload=3.0), T_CMD, U_CMD, 9.0)
    for _, row in df.iloc[::10].iterrows():
        assert np.allclose(row[["x", "y", "psi"]].to_numpy(float), ref(row["t"]), atol=2e-5)


def test_zero_new_coefficients_give_the_base_model(omnibot):
    """c = c_r = C_r = a_r = b_r = 0 is Moreno's base model (paper eq. 5): only a, b friction."""
    base = omnibot.replace(c=0.0, c_r=0.0, C_r=0.0, a_r=0.0, b_r=0.0)
    df = simulate(base, Scenario(), T_CMD, U_CMD, 9.0, record_every=100)
    ref = _paper_eq8(base, Scenario(), T_CMD, U_CMD, 9.0, roller=False)
    for _, row in df.iloc[::10].iterrows():
        assert np.allclose(row[["x", "y", "psi"]].to_numpy(float), ref(row["t"]), atol=2e-5)
    assert df["E_roller_friction"].abs().max() == 0.0
    assert df["E_rolling_resistance"].abs().max() == 0.0
    # and the new terms do matter when present: the full model ends somewhere else
    full = simulate(omnibot, Scenario(), T_CMD, U_CMD, 9.0, record_every=100)
    assert np.hypot(full["x"].iloc[-1] - df["x"].iloc[-1], full["y"].iloc[-1] - df["y"].iloc[-1]) > 0.005


def test_mirrored_commands_give_mirrored_trajectories(omnibot):
    """Mirror about the body x axis: swap left and right wheels (their rollers mirror too), so x
    stays and y, psi change sign. Mirror about the y axis: swap front and rear wheels and reverse
    their spin, so y stays and x, psi change sign. (Negating every duty is NOT a symmetry: the
    centripetal terms are even in velocity.)"""
    U = np.array(U_CMD)
    left_right = U[:, [1, 0, 3, 2]]
    front_rear = -U[:, [2, 3, 0, 1]]
    res = simulate_batch(omnibot, Scenario(), T_CMD, np.stack([U, left_right, front_rear]), 9.0, record_every=50)
    a, b, c = (res.frame(k) for k in range(3))
    for mirror, same, flipped in ((b, "x", ("y", "psi")), (c, "y", ("x", "psi"))):
        assert np.allclose(mirror[same], a[same], atol=1e-9)
        for col in flipped:
            assert np.allclose(mirror[col], -a[col], atol=1e-9)
        assert np.allclose(mirror["E_batt"], a["E_batt"], rtol=1e-9)
    assert np.abs(a["y"]).max() > 0.1 and np.abs(a["psi"]).max() > 0.1  # the test has teeth


def _every_term_active():
    """World effects: every registered non-core term at its documented default size."""
    return {t.name: t.defaults() for t in all_terms() if not t.core}


@pytest.mark.parametrize("mode", ["ground", "upside_down"])
def test_energy_balance_closes_with_every_effect_active(omnibot, mode):
    """Battery energy = copper loss + gear/conversion loss + quiescent draw + energy dissipated
    by every term + change of kinetic energy, to 0.1 % over 10 s."""
    robot = omnibot.replace(I_0=0.15)
    scenario = Scenario(mode=mode, payload=2.0 if mode == "ground" else 0.0, effects=_every_term_active())
    df = simulate(robot, scenario, T_CMD, U_CMD, 10.0, record_every=100)
    end = df.iloc[-1]
    dissipated = sum(end[c] for c in df.columns if c.startswith("E_") and c not in ("E_batt",))
    balance = dissipated + end["KE"] - df["KE"].iloc[0]
    assert end["E_batt"] > 100.0
    assert balance == pytest.approx(end["E_batt"], rel=1e-3)
    # every paper term that can act in this mode did dissipate energy
    assert end["E_transmission_friction"] > 0
    if mode == "ground":
        assert end["E_roller_friction"] > 0 and end["E_rolling_resistance"] > 0


def test_quiescent_current_draws_its_energy(omnibot):
    df = simulate(omnibot.replace(I_0=0.15), Scenario(), [0.0], [[0.0] * 4], 10.0, record_every=1000)
    assert df["E_quiescent"].iloc[-1] == pytest.approx(0.15 * 10.0 * omnibot.V_batt, rel=1e-9)
    assert df["E_batt"].iloc[-1] == pytest.approx(df["E_quiescent"].iloc[-1], rel=1e-9)


def test_batch_of_parameter_sets_equals_separate_runs(omnibot):
    robots = [omnibot.replace(a=a, b_r=b) for a, b in [(0.0, 0.5), (0.02, 1.0), (0.05, 2.0)]]
    res = simulate_batch(robots, Scenario(), T_CMD, U_CMD, 5.0, record_every=50)
    for k, robot in enumerate(robots):
        single = simulate(robot, Scenario(), T_CMD, U_CMD, 5.0, record_every=50)
        assert np.allclose(res.frame(k)[["x", "y", "psi", "E_batt"]], single[["x", "y", "psi", "E_batt"]], rtol=1e-12, atol=1e-12)
    finals = res.signal("x")[:, -1]
    assert len(set(np.round(finals, 6))) == 3  # different friction, different outcome
