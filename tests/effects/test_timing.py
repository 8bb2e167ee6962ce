"""Command-timing effects (omnibench.effects.timing): a latency is an exact time shift of each
wheel's duty schedule, closes the energy balance, vanishes at zero size, and the simulated
board (step by step) and the batch simulator (fit, predict) apply it the same way."""

from __future__ import annotations

import numpy as np
import pytest

from omnibench.effects.timing import PACKET_9600, delay_schedules, slots, wheel_delays
from omnibench.model import Scenario, Simulator, simulate_batch

T_CMD = [0.0, 0.3, 0.6]
U_CMD = [[0.5, 0.5, 0.5, 0.5], [-0.4, 0.3, -0.2, 0.6], [0.0, 0.0, 0.0, 0.0]]


def test_packet_time_and_send_order_slots():
    assert PACKET_9600 == pytest.approx(4.1667e-3, rel=1e-4)
    assert list(slots((1, 2, 4, 3))) == [0, 1, 3, 2]  # ardu.ino.ino: FL, FR, BR, BL
    d = wheel_delays({"serial_command_latency": {"tau": 0.01, "tau_packet": PACKET_9600},
                      "per_wheel_latency": {"tau_1": 0.0, "tau_2": 0.001, "tau_3": 0.0, "tau_4": 0.0}},
                     (1, 2, 4, 3))
    np.testing.assert_allclose(d, [0.01, 0.01 + PACKET_9600 + 0.001, 0.01 + 3 * PACKET_9600, 0.01 + 2 * PACKET_9600])
    with pytest.raises(ValueError):
        slots((1, 1, 2, 3))


def test_delay_schedules_shift_each_wheel_and_start_at_rest():
    t, U = delay_schedules(np.array([0.0, 1.0]), np.array([[[1, 2, 3, 4], [5, 6, 7, 8]]], float),
                           np.array([[0.0, 0.5, 0.0, 1.5]]))
    np.testing.assert_allclose(t, [0.0, 0.5, 1.0, 1.5, 2.5])
    np.testing.assert_allclose(U[0], [[1, 0, 3, 0], [1, 2, 3, 0], [5, 2, 7, 0], [5, 6, 7, 4], [5, 6, 7, 8]])


@pytest.mark.parametrize("mode", ("upside_down", "ground"))
def test_latency_equals_the_shifted_schedule_and_closes_the_energy_balance(omnibot, mode):
    """Closed form: the model with latency d_j = the base model fed the schedule shifted by d_j."""
    eff = {"serial_command_latency": {"tau": 0.014, "tau_packet": 0.004}}
    scen_lat = Scenario(mode=mode, effects=eff, command_order=(4, 1, 2, 3))  # RR first
    d = 0.014 + 0.004 * np.array([1, 2, 3, 0])
    t_s, U_s = delay_schedules(np.array(T_CMD), np.array(U_CMD)[None], d[None])
    a = simulate_batch(omnibot, scen_lat, T_CMD, U_CMD, 1.0).frame(0)
    b = simulate_batch(omnibot, Scenario(mode=mode), t_s, U_s, 1.0).frame(0)
    for c in ("phi1", "phi4", "i2", "E_batt", "x"):
        np.testing.assert_allclose(a[c], b[c], rtol=0, atol=1e-9)
    base = simulate_batch(omnibot, Scenario(mode=mode), T_CMD, U_CMD, 1.0).frame(0)
    assert np.abs(a["phi1"] - base["phi1"]).max() > 1e-3  # it does change the run
    # energy: E_batt = copper + conversion + quiescent + terms + kinetic, the term books nothing
    assert np.all(a["E_serial_command_latency"] == 0.0)
    zero = Scenario(mode=mode, effects={"command_latency": {"tau": 0.0}, "per_wheel_latency": {}})
    z = simulate_batch(omnibot, zero, T_CMD, U_CMD, 1.0).frame(0)
    assert np.array_equal(z["phi1"].to_numpy(), base["phi1"].to_numpy())  # zero size: the base model


def test_simulated_board_applies_latency_like_the_batch_simulator(omnibot):
    """The step-by-step Simulator (sim://) queues the commands: same trajectory as simulate_batch."""
    scen = Scenario(mode="upside_down", effects={"per_wheel_latency": {"tau_1": 0.0, "tau_2": 0.0042,
                                                                       "tau_3": 0.0125, "tau_4": 0.0333}})
    sim = Simulator(omnibot, scen)
    phi = []
    t_c = T_CMD + [1.0]
    for k in range(len(T_CMD)):
        n = round((t_c[k + 1] - t_c[k]) / 0.02)
        for _ in range(n):  # the board steps in 20 ms telemetry periods
            phi.append(sim.advance(np.array(U_CMD[k]), 0.02).phi.copy())
    ref = simulate_batch(omnibot, scen, T_CMD, U_CMD, 1.0).frame(0)
    got = np.array(phi)
    want = ref[[f"phi{j}" for j in range(1, 5)]].to_numpy()[20::20]
    np.testing.assert_allclose(got, want, atol=1e-9)


def test_sub_step_latency_moves_the_trajectory_continuously(omnibot):
    """Latencies between two physics steps give trajectories between theirs, without jumps (a
    fit can differentiate them): the step a change falls in carries the average duty."""
    taus = np.linspace(0.010, 0.011, 11)
    scen = [Scenario(mode="upside_down", effects={"command_latency": {"tau": t}}) for t in taus]
    res = simulate_batch(omnibot, scen, T_CMD, U_CMD, 0.4, record_every=1)
    steps = np.diff(res.signal("phi1")[:, 350])  # 50 ms after the reversal at 0.3 s
    assert np.all(steps > 0)  # a later reversal: more angle still gained forward
    assert steps.max() < 3 * steps.mean()  # no jump at a step boundary
