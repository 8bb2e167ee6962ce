"""The candidate-effect library: each effect does what its physics says, closes the energy
balance, and vanishes exactly at zero size (issue 6, part 1).

The closed forms below are written out here from docs/effects.md, independently of the hooks.
Every batch shares one compiled kernel, so the file runs in a few seconds after the compile.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from omnibench.effects import EFFECTS
from omnibench.model import Scenario, simulate, simulate_batch
from omnibench.model.context import GRAVITY
from omnibench.model.geometry import inverse_kinematics
from omnibench.model.terms import get_term

T_CMD = [0.0, 1.0, 2.0, 3.0, 4.0]
U_CMD = [
    [0.6, 0.6, 0.6, 0.6],
    [0.5, -0.5, -0.5, 0.5],
    [-0.4, 0.4, -0.4, 0.4],
    [0.3, 0.1, -0.2, 0.5],
    [0.0, 0.0, 0.0, 0.0],
]
MODES = ("ground", "upside_down")


def _zero_size(name: str) -> dict[str, dict[str, float]]:
    """The effect with its fitted size parameters set to zero (its other parameters realistic)."""
    eff = EFFECTS[name]
    return {name: eff.params({k: 0.0 for k in eff.example})}


def test_library_effects_are_registered_with_units_and_docs():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "effects.md").read_text()
    assert len(EFFECTS) >= 11
    for name, eff in EFFECTS.items():
        term = get_term(name)
        assert not term.core and term.doc and term.reveals
        assert set(eff.fit) <= set(term.param_names)
        for p in term.params:
            assert p.unit and p.doc and p.lower <= p.default <= p.upper
        for k, v in eff.example.items():
            spec = {p.name: p for p in term.params}[k]
            assert spec.lower <= v <= spec.upper
        assert f"## {name}" in doc, f"docs/effects.md has no section for {name}"


@pytest.mark.parametrize("mode", MODES)
def test_zero_size_gives_the_base_model_exactly(omnibot, mode):
    names = list(EFFECTS)
    scen = [Scenario(mode=mode)] + [Scenario(mode=mode, effects=_zero_size(n)) for n in names]
    res = simulate_batch(omnibot, scen, T_CMD, U_CMD, 5.0, record_every=100)
    # every recorded signal except the per-term energy and state columns (those differ in layout only)
    cols = [k for k, c in enumerate(res.columns) if not (c.startswith("E_") and c[2:] in EFFECTS) and "." not in c]
    base = res.array[0][:, cols]
    assert np.abs(base).max() > 0.1 and res.signal("E_batt")[0, -1] > 50.0
    for k, name in enumerate(names, start=1):
        assert np.array_equal(res.array[k][:, cols], base), f"{name} at zero size changed the model"
        assert np.all(res.signal(f"E_{name}")[k] == 0.0)


@pytest.mark.parametrize("mode", MODES)
def test_energy_balance_closes_with_each_effect_at_realistic_size(omnibot, mode):
    """E_batt = E_copper + E_conversion + E_quiescent + sum E_term + delta KE, to 0.1 %."""
    names = list(EFFECTS)
    scen = [Scenario(mode=mode, payload=2.0 if mode == "ground" else 0.0, effects=EFFECTS[n].world()) for n in names]
    res = simulate_batch(omnibot, scen, T_CMD, U_CMD, 5.0, record_every=100)
    base = simulate_batch(omnibot, Scenario(mode=mode, payload=2.0 if mode == "ground" else 0.0), T_CMD, U_CMD, 5.0,
                          record_every=100).frame(0)
    changed = 0
    for k, name in enumerate(names):
        df = res.frame(k)
        end = df.iloc[-1]
        dissipated = sum(end[c] for c in df.columns if c.startswith("E_") and c != "E_batt")
        assert end["E_batt"] > 50.0
        assert dissipated + end["KE"] - df["KE"].iloc[0] == pytest.approx(end["E_batt"], rel=1e-3), name
        changed += not np.allclose(df[["x", "phi1", "E_batt"]], base[["x", "phi1", "E_batt"]], rtol=1e-6, atol=1e-9)
    # each effect that can act in this mode changed the run (com_offset and floor_slope act only on the ground)
    assert changed >= len(names) - (2 if mode == "upside_down" else 0)


# --- upside-down steady states: torque balance solved here, compared with the simulation ---

from omnibench.model.kernel import EXACT_SIGN_WIDTH  # noqa: E402


def _steady(robot, u_eff: float, F_N: float, extra) -> float:
    """Root of eta k_t (u V - k_e w)/R_a - (1 + c F_N)(a w + b sign w) + extra(w) = 0, rad/s."""
    g = robot.eta * robot.k_t / robot.R_a
    eps = EXACT_SIGN_WIDTH  # upside down the dry terms' sign is exact (stick-slip)

    def balance(w: float) -> float:
        return g * (u_eff * robot.V_batt - robot.k_e * w) - (1 + robot.c * F_N) * (robot.a * w + robot.b * w / math.hypot(w, eps)) + extra(w)

    return brentq(balance, -40.0, 40.0, xtol=1e-12)


def _sgn(w: float, eps: float) -> float:
    return w / math.hypot(w, eps)


UPSIDE_CASES = {
    # name: (effect values, extra torque on the axle as a function of (w, wheel index, F_N))
    "stribeck_friction": ({"b_s": 0.25, "w_s": 1.0, "c_s": 0.01},
                          lambda w, j, F: -(1 + 0.01 * F) * 0.25 * math.exp(-w * w) * _sgn(w, EXACT_SIGN_WIDTH)),
    "asymmetric_coulomb": ({"db": 0.06}, lambda w, j, F: -(1 + 0.01 * F) * 0.06 * abs(_sgn(w, EXACT_SIGN_WIDTH))),
    "per_wheel_friction": ({"db_1": 0.0, "db_2": 0.08, "db_3": -0.06, "db_4": 0.05,
                            "da_1": 0.002, "da_2": 0.0, "da_3": -0.003, "da_4": 0.001},
                           lambda w, j, F: -(0.0, 0.08, -0.06, 0.05)[j] * _sgn(w, EXACT_SIGN_WIDTH) - (0.002, 0.0, -0.003, 0.001)[j] * w),
    "quadratic_drag": ({"d_q": 1.5e-3}, lambda w, j, F: -1.5e-3 * abs(w) * w),
}


@pytest.mark.parametrize("name", list(UPSIDE_CASES))
def test_axle_friction_effects_match_the_torque_balance_upside_down(omnibot, name):
    params, extra = UPSIDE_CASES[name]
    duties = [0.12, -0.2, 0.45, -0.8]
    masses = (0.9, 1.9)
    scen = [Scenario(mode="upside_down", wheel_mass=(m,) * 4, effects={name: params}) for m in masses]
    res = simulate_batch(omnibot, scen, [0.0], [duties], 0.6, record_every=100)
    moved = []
    for k, m in enumerate(masses):
        F = m * GRAVITY
        for j, u in enumerate(duties):
            got = res.signal(f"phi_dot{j + 1}_free")[k, -1]
            want = _steady(omnibot, u, F, lambda w: extra(w, j, F))
            assert got == pytest.approx(want, rel=1e-4, abs=1e-4)
            moved.append(abs(got - _steady(omnibot, u, F, lambda w: 0.0)))
    assert max(moved) > 0.05, "the effect must move some steady speed"


def test_stribeck_grows_with_the_wheel_load_but_deadband_does_not(omnibot):
    """The experiment that separates the two: swap in a heavier wheel set."""
    u = 0.08
    worlds = {"stribeck_friction": {"b_s": 0.25, "w_s": 1.0, "c_s": 0.05}, "driver_deadband": {"u_0": 0.01, "w_u": 0.002}}
    loss = {}
    for name, params in worlds.items():
        scen = [Scenario(mode="upside_down", wheel_mass=(m,) * 4, effects=e) for m in (0.9, 1.9) for e in ({}, {name: params})]
        res = simulate_batch(omnibot, scen, [0.0], [[u] * 4], 0.6, record_every=100)
        w = res.signal("phi_dot1_free")[:, -1]
        loss[name] = [(w[0] - w[1]), (w[2] - w[3])]
        assert min(loss[name]) > 0.01
    # Stribeck: loss rises with load (1 + c_s F_N); deadband: the lost voltage is the same
    assert loss["stribeck_friction"][1] > 1.05 * loss["stribeck_friction"][0]
    g_v = omnibot.eta * omnibot.k_t * 0.01 * omnibot.V_batt / omnibot.R_a  # torque the deadband removes
    assert g_v > 0


def test_driver_deadband_gives_no_motion_below_u0_and_shifts_the_duty_above(omnibot):
    u_0 = 0.05
    duties = [0.03, -0.045, 0.2, -0.6]
    sc = Scenario(mode="upside_down", effects={"driver_deadband": {"u_0": u_0, "w_u": 0.002}})
    res = simulate_batch(omnibot, sc, [0.0], [duties], 0.6, record_every=100)
    F = omnibot.wheel_mass[0] * GRAVITY
    for j, u in enumerate(duties):
        got = res.signal(f"phi_dot{j + 1}_free")[0, -1]
        u_eff = res.signal(f"u{j + 1}_eff")[0, -1]
        if abs(u) < u_0:
            assert abs(got) < 1e-3 and abs(u_eff) < 1e-3
        else:
            assert u_eff == pytest.approx(u - math.copysign(u_0, u), abs=1e-5)
            assert got == pytest.approx(_steady(omnibot, u - math.copysign(u_0, u), F, lambda w: 0.0), rel=1e-3)


def test_cogging_ripple_has_the_linear_response_amplitude(omnibot):
    """Speed ripple at n_c w: amplitude A_c / |I_w j Omega + d| with d the linearised damping."""
    A, n = 0.05, 10.0
    u = 0.35
    sc = Scenario(mode="upside_down", effects={"cogging_torque": {"A_c": A, "n_c": n, "phase": 0.0}})
    df = simulate(omnibot, sc, [0.0], [[u] * 4], 1.0)
    w = df["phi_dot1"].to_numpy()[500:]
    w_mean = w.mean()
    F = omnibot.wheel_mass[0] * GRAVITY
    assert w_mean == pytest.approx(_steady(omnibot, u, F, lambda x: 0.0), rel=2e-3)  # averages out
    d = omnibot.eta * omnibot.k_t * omnibot.k_e / omnibot.R_a + (1 + omnibot.c * F) * omnibot.a
    Omega = n * w_mean
    amp = A / math.hypot(omnibot.I_w * Omega, d)
    assert 0.5 * (w.max() - w.min()) == pytest.approx(amp, rel=0.05)


def test_strong_cogging_holds_a_slowly_driven_wheel(omnibot):
    u = 0.11  # about 1 rad/s without cogging; the ripple (2 N m) exceeds the motor's torque at rest (1.4 N m)
    scen = [Scenario(mode="upside_down"), Scenario(mode="upside_down", effects={"cogging_torque": {"A_c": 2.0, "n_c": 10.0, "phase": 0.3}})]
    res = simulate_batch(omnibot, scen, [0.0], [[u] * 4], 3.0, record_every=100)
    w = res.signal("phi_dot1_free")[:, -1]
    assert w[0] > 0.5 and abs(w[1]) < 1e-3


def test_com_offset_normal_forces_obey_statics(omnibot):
    dx, dy = 0.03, -0.02
    sc = Scenario(payload=2.0, effects={"com_offset": {"dx": dx, "dy": dy}})
    df = simulate(omnibot, sc, [0.0], [[0.3, 0.3, 0.3, 0.3]], 0.05, record_every=10)
    FN = df[["FN1", "FN2", "FN3", "FN4"]].to_numpy()[-1]
    W = (omnibot.m + 2.0) * GRAVITY
    s = np.array([1, 1, -1, -1]) * omnibot.L
    d = np.array([1, -1, 1, -1]) * omnibot.l
    assert FN.sum() == pytest.approx(W, rel=1e-12)
    assert (FN * s).sum() == pytest.approx(W * dx, rel=1e-9)  # moment balance about the y axis
    assert (FN * d).sum() == pytest.approx(W * dy, rel=1e-9)
    assert np.allclose(FN, W / 4 * (1 + dx * s / omnibot.L**2 + dy * d / omnibot.l**2))
    # upside down the wheels carry only their own weight
    up = simulate(omnibot, Scenario(mode="upside_down", effects=sc.effects), [0.0], [[0.3] * 4], 0.02, record_every=10)
    assert np.allclose(up[["FN1", "FN2", "FN3", "FN4"]].iloc[-1], omnibot.wheel_mass[0] * GRAVITY)


def test_com_offset_sideways_makes_a_straight_run_curve(omnibot):
    scen = [Scenario(), Scenario(effects={"com_offset": {"dx": 0.0, "dy": 0.03}})]
    res = simulate_batch(omnibot, scen, [0.0, 1.5], [[0.5] * 4, [0.0] * 4], 2.5, record_every=100)
    psi = res.signal("psi")[:, -1]
    # small: the rollers barely slip, so the heavier side's extra rolling resistance turns the
    # robot by a fraction of a milliradian in 2.5 s (a creeping roller model made it 8 mrad)
    assert abs(psi[0]) < 1e-9 and abs(psi[1]) > 1e-4


def test_battery_resistance_sags_the_voltage_with_current(omnibot):
    R_b = 0.25
    sc = Scenario(mode="upside_down", effects={"battery_resistance": {"R_b": R_b}})
    df = simulate(omnibot, sc, [0.0, 0.3], [[0.8] * 4, [-0.5] * 4], 0.6, record_every=5)
    V, I = df["V_batt"].to_numpy(), df["I_batt"].to_numpy()
    assert np.allclose(V, omnibot.V_batt - R_b * I, atol=1e-9)
    assert I.max() > 10.0  # start-up current of four motors: the sag is volts, not millivolts


def test_quiescent_current_adds_I_q_V_to_the_battery_energy(omnibot):
    I_q = 0.3
    scen = [Scenario(), Scenario(effects={"quiescent_current": {"I_q": I_q}})]
    res = simulate_batch(omnibot, scen, T_CMD, U_CMD, 5.0, record_every=100)
    E = res.signal("E_batt")[:, -1]
    assert E[1] - E[0] == pytest.approx(I_q * omnibot.V_batt * 5.0, rel=1e-9)
    assert np.allclose(res.signal("x")[0], res.signal("x")[1])  # no mechanical effect


def test_winding_heating_follows_the_first_order_thermal_model(omnibot):
    theta, tau, alpha = 20.0, 0.5, 0.00393
    sc = Scenario(mode="upside_down", effects={"winding_heating": {"theta": theta, "tau_th": tau, "alpha_cu": alpha}})
    df = simulate(omnibot, sc, [0.0], [[0.6] * 4], 5.0)
    dT = df["winding_heating.x0"].to_numpy()
    i = df["i1"].to_numpy()
    t = df["t"].to_numpy()
    # steady: dT = theta i^2 (1 + alpha dT)  ->  dT = theta i^2 / (1 - alpha theta i^2)
    want = theta * i[-1] ** 2 / (1 - alpha * theta * i[-1] ** 2)
    assert dT[-1] == pytest.approx(want, rel=1e-3)
    # the whole history: the first-order ODE driven by the recorded current (trapezoid, 1 ms)
    ref = np.zeros_like(dT)
    for k in range(1, len(t)):
        h = t[k] - t[k - 1]
        f0 = (theta * i[k - 1] ** 2 * (1 + alpha * ref[k - 1]) - ref[k - 1]) / tau
        pred = ref[k - 1] + h * f0
        f1 = (theta * i[k] ** 2 * (1 + alpha * pred) - pred) / tau
        ref[k] = ref[k - 1] + 0.5 * h * (f0 + f1)
    assert np.allclose(dT, ref, rtol=2e-2, atol=0.05 * want)
    assert want > 5.0  # kelvin: the test has teeth
    # a warm winding passes less current for the same duty: the wheel slows down
    base = simulate(omnibot, Scenario(mode="upside_down"), [0.0], [[0.6] * 4], 5.0, record_every=10)
    assert df["phi_dot1"].iloc[-1] < base["phi_dot1"].iloc[-1] - 0.01


def test_floor_slope_accelerates_a_robot_without_dry_friction_as_m_g_sin_theta(omnibot):
    theta = 0.02
    robot = omnibot.replace(b=0.0, C_r=0.0, b_r=0.0, a=0.0)
    sc = Scenario(effects={"floor_slope": {"theta_s": theta, "psi_s": 0.0}})
    df = simulate(robot, sc, [0.0], [[0.0] * 4], 0.5)
    F = robot.m * GRAVITY * math.sin(theta)
    R = inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha)
    m_eff = robot.m + robot.I_w * (R[:, 0] ** 2).sum()
    # gravity against the short-circuited motors' back-EMF braking: v = v_T (1 - exp(-t/T))
    d = robot.eta * robot.k_t * robot.k_e / robot.R_a
    D = d * (R[:, 0] ** 2).sum()
    v_term, T = F / D, m_eff / D
    t = df["t"].to_numpy()
    assert np.allclose(df["v1"], v_term * (1 - np.exp(-t / T)), rtol=1e-3, atol=1e-6 * v_term)
    assert (df["v1"].iloc[1] / t[1]) == pytest.approx(F / m_eff, rel=0.03)  # initial acceleration m g sin(theta) / m_eff
    assert np.abs(df["v2"]).max() < 1e-9


def test_floor_slope_pulls_along_the_world_direction_whatever_the_heading(omnibot):
    robot = omnibot.replace(b=0.0, C_r=0.0, b_r=0.0, a=0.0)
    sc = Scenario(effects={"floor_slope": {"theta_s": 0.02, "psi_s": math.pi / 2}})
    df = simulate(robot, sc, [0.0], [[0.0] * 4], 0.5, record_every=10)
    assert df["y"].iloc[-1] > 1e-3 and abs(df["x"].iloc[-1]) < 1e-9 * max(1.0, df["y"].iloc[-1])


def test_realistic_slope_is_held_by_gearbox_friction_but_changes_runs(omnibot):
    sc = Scenario(effects={"floor_slope": {"theta_s": 0.0175, "psi_s": 0.0}})
    rest = simulate(omnibot, sc, [0.0], [[0.0] * 4], 1.0, record_every=100)
    assert abs(rest["v1"].iloc[-1]) < 0.01  # creep only, within the sign regularisation
    scen = [Scenario(), sc]
    fwd = simulate_batch(omnibot, scen, [0.0, 1.5], [[0.4] * 4, [0.0] * 4], 2.5, record_every=100)
    bwd = simulate_batch(omnibot, scen, [0.0, 1.5], [[-0.4] * 4, [0.0] * 4], 2.5, record_every=100)
    x_f, x_b = fwd.signal("x")[:, -1], bwd.signal("x")[:, -1]
    assert x_f[0] == pytest.approx(-x_b[0], rel=1e-9)
    # downhill further, uphill shorter, by the speed the slope force buys against the motors'
    # back-EMF damping (nearly velocity sources: millimetres) ...
    assert x_f[1] > x_f[0] + 0.004 and -x_b[1] < -x_b[0] - 0.004
    # ... and the motors work harder uphill: the current tells more than the tape
    i_f, i_b = fwd.signal("i1")[:, 10], bwd.signal("i1")[:, 10]
    F = omnibot.m * GRAVITY * math.sin(0.0175)
    di = F * omnibot.r / 4 / (omnibot.eta * omnibot.k_t)
    assert i_f[1] - i_f[0] == pytest.approx(-di, rel=0.15) and i_b[1] - i_b[0] == pytest.approx(-di, rel=0.15)
