"""Command-timing effects (omnibench.effects.timing): a latency is an exact time shift of each
wheel's duty schedule, closes the energy balance, vanishes at zero size, and the simulated
board (step by step) and the batch simulator (fit, predict) apply it the same way."""

from __future__ import annotations

import numpy as np
import pytest

from omnibench.effects.timing import PACKET_9600, delay_schedules, lag_schedules, slots, wheel_delays
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


def test_a_board_advancing_every_step_queues_only_changed_commands(omnibot):
    """A realtime board advances the Simulator about every millisecond with its duties unchanged:
    the same trajectory as simulate_batch, and only the commands that changed the duties are
    queued (each queued command's arrivals run the steps around them one at a time)."""
    scen = Scenario(mode="upside_down", command_delays=(0.00417, 0.00833, 0.0125, 0.0167))
    sim = Simulator(omnibot, scen)
    phi, longest = [], 0
    t_c = T_CMD + [1.0]
    for k in range(len(T_CMD)):
        for _ in range(round((t_c[k + 1] - t_c[k]) / 0.001)):
            phi.append(sim.advance(np.array(U_CMD[k]), 0.001).phi.copy())
            longest = max(longest, len(sim._history))
    ref = simulate_batch(omnibot, scen, T_CMD, U_CMD, 1.0).frame(0)
    want = ref[[f"phi{j}" for j in range(1, 5)]].to_numpy()[1:]
    np.testing.assert_allclose(np.array(phi), want[: len(phi)], atol=1e-9)
    assert longest <= 2  # the command each wheel still holds and the one on its way


def test_sub_step_latency_moves_the_trajectory_continuously(omnibot):
    """Latencies between two physics steps give trajectories between theirs, without jumps (a
    fit can differentiate them): the step a change falls in carries the average duty."""
    taus = np.linspace(0.010, 0.011, 11)
    scen = [Scenario(mode="upside_down", effects={"command_latency": {"tau": t}}) for t in taus]
    res = simulate_batch(omnibot, scen, T_CMD, U_CMD, 0.4, record_every=1)
    steps = np.diff(res.signal("phi1")[:, 350])  # 50 ms after the reversal at 0.3 s
    assert np.all(steps > 0)  # a later reversal: more angle still gained forward
    assert steps.max() < 3 * steps.mean()  # no jump at a step boundary


def test_actuator_lag_gives_the_first_order_step_response_exactly():
    """A duty step 0 -> 1 at 0.1 s through tau_a: each physics step carries the exact average of
    1 - exp(-(t - 0.1) / tau_a) over it; zero lag leaves the schedule as it is."""
    tau, dt = 0.03, 1e-3
    t, U = lag_schedules(np.array([0.0, 0.1]), np.array([[[0, 0, 0, 0], [1, 1, 1, 1]]], float),
                         np.array([[tau, 0.0, tau, 0.0]]), dt, 0.3)
    k = np.arange(len(t))
    lo, hi = np.maximum(k * dt - 0.1, 0), np.maximum((k + 1) * dt - 0.1, 0)
    exact = (hi - lo - tau * (np.exp(-lo / tau) - np.exp(-hi / tau))) / dt  # mean of 1 - exp(-s/tau)
    np.testing.assert_allclose(U[0, :, 0], exact, atol=1e-12)
    np.testing.assert_allclose(U[0, :, 1], (k * dt >= 0.1 - 1e-12).astype(float))
    assert U[0, 100 + int(tau / dt), 2] == pytest.approx(1 - np.exp(-1), abs=0.02)  # 63 % after tau_a


def test_the_lag_recursion_is_scipys_first_order_filter_bit_for_bit():
    """The lag's recursion (model/timing.py, compiled, without importing scipy.signal) gives the
    numbers of scipy.signal.lfilter([0, 1 - a], [1, -a], x) exactly, for several time constants
    and duty histories with steps, ramps, sign changes and long runs."""
    from scipy.signal import lfilter

    from omnibench.model.timing import _lag_filter, lag_coefficients

    rng = np.random.default_rng(4)
    x = np.concatenate([np.zeros(5), np.ones(300), rng.uniform(-1, 1, 2000), np.linspace(-0.7, 0.9, 30000)])
    for tau in (0.0005, 0.004, 0.03, 0.5):
        a = float(lag_coefficients(np.array([tau]), 1e-3)[0][0])
        got = _lag_filter()(x, a)
        want = lfilter([0.0, 1.0 - a], [1.0, -a], x)
        assert got[0] == 0.0
        assert np.array_equal(got, want), (tau, np.max(np.abs(got - want)))


def test_simulated_board_applies_actuator_lag_like_the_batch_simulator(omnibot):
    scen = Scenario(mode="upside_down", effects={"actuator_lag": {"tau_a": 0.04},
                                                 "command_latency": {"tau": 0.0125}})
    sim = Simulator(omnibot, scen)
    phi = []
    t_c = T_CMD + [1.0]
    for k in range(len(T_CMD)):
        for _ in range(round((t_c[k + 1] - t_c[k]) / 0.02)):
            phi.append(sim.advance(np.array(U_CMD[k]), 0.02).phi.copy())
    ref = simulate_batch(omnibot, scen, T_CMD, U_CMD, 1.0).frame(0)
    np.testing.assert_allclose(np.array(phi), ref[[f"phi{j}" for j in range(1, 5)]].to_numpy()[20::20], atol=1e-9)
    base = simulate_batch(omnibot, Scenario(mode="upside_down", effects={"command_latency": {"tau": 0.0125}}),
                          T_CMD, U_CMD, 1.0).frame(0)
    assert np.abs(ref["phi1"] - base["phi1"]).max() > 1e-2  # the lag does change the run
    assert ref["phi_dot1"].iloc[290] == pytest.approx(base["phi_dot1"].iloc[290], rel=3e-3)  # same steady speed
