"""The shifted deadband's start values from a sweep's voltage balance (effects/driver.py)."""

from __future__ import annotations

import numpy as np

from omnibench.effects.driver import deadband_start


def _sweep(u_0=0.04, R_a=1.85, k_e=1.6, V=24.7, b=0.5, a=0.01):
    u = np.repeat([-0.8, -0.45, -0.2, -0.06, -0.02, 0.02, 0.06, 0.2, 0.45, 0.8], 4)
    u_eff = np.sign(u) * np.maximum(np.abs(u) - u_0, 0.0)
    # steady state of k_t i = b + a omega, V u_eff = k_e omega + R_a i (k_t = k_e); stalled below breakaway
    omega = np.sign(u) * np.maximum((V * np.abs(u_eff) * k_e - R_a * b) / (k_e ** 2 + R_a * a), 0.0)
    i = (V * u_eff - k_e * omega) / R_a
    return u, omega, i, np.full(len(u), 0.002), np.full(len(u), V)


def test_the_voltage_balance_gives_u_0_R_a_and_k_e():
    got = deadband_start(*_sweep())
    assert got is not None
    assert abs(got["u_0"] - 0.04) < 1e-9 and abs(got["R_a"] - 1.85) < 1e-9 and abs(got["k_e"] - 1.6) < 1e-9


def test_no_start_for_the_cut_form_or_too_few_steady_states():
    u, omega, i, se, v = _sweep()
    assert deadband_start(u, omega, i, se, v, cut=1.0) is None
    assert deadband_start(u[:5], omega[:5], i[:5], se[:5], v[:5]) is None
    assert deadband_start(u, omega, np.full(len(u), np.nan), se, v) is None


def _loaded_sweep(u_0=0.04, R_a=1.85, k_e=1.6, V=24.7, a=0.01, b=0.5, c=0.01, kt=0.94):
    """Steady states upside down with two wheel sets: kt i = (1 + c F)(a omega + b sign omega),
    V (u - u_0 sign u) = k_e omega + R_a i; a wheel below breakaway stalls with its current."""
    u = np.tile(np.repeat([-0.8, -0.45, -0.2, -0.1, -0.06, 0.06, 0.1, 0.2, 0.45, 0.8], 2), 2)
    F = np.repeat([8.8, 18.6], len(u) // 2)
    u_eff = np.sign(u) * np.maximum(np.abs(u) - u_0, 0.0)
    g = 1.0 + c * F
    # moving: kt (V u_eff - k_e w) / R_a = g (a w + b): w = (kt V u_eff / R_a - g b) / (kt k_e / R_a + g a)
    w = np.sign(u) * np.maximum((kt * V * np.abs(u_eff) / R_a - g * b) / (kt * k_e / R_a + g * a), 0.0)
    i = (V * u_eff - k_e * w) / R_a
    return u, w, i, np.full(len(u), 0.002), np.full(len(u), V), F


def test_the_torque_balance_gives_a_b_and_c_with_the_loads_and_torque_constant():
    u, w, i, se, v, F = _loaded_sweep()
    assert np.sum(w == 0.0) >= 4 and np.sum(w != 0.0) >= 12  # stalled steady states are left out, not fitted
    got = deadband_start(u, w, i, se, v, F_N=F, torque_constant=0.94, omega_se=se)
    assert got is not None
    assert abs(got["u_0"] - 0.04) < 1e-9 and abs(got["R_a"] - 1.85) < 1e-9
    assert abs(got["a"] - 0.01) < 1e-9 and abs(got["b"] - 0.5) < 1e-9 and abs(got["c"] - 0.01) < 1e-9
    # without the loads or the torque constant only the voltage balance
    assert set(deadband_start(u, w, i, se, v)) == {"u_0", "R_a", "k_e"}
    # one wheel set cannot separate b from c b
    one = F == F[0]
    assert set(deadband_start(u[one], w[one], i[one], se[one], v[one], F_N=F[one], torque_constant=0.94)) \
        == {"u_0", "R_a", "k_e"}
