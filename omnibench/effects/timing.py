"""Command-timing effects: when a logged duty really reaches each motor.

  command_latency          every wheel's duty acts tau s after its time stamp
  serial_command_latency   wheel j acts tau + tau_packet * slot_j s after it, slot_j = the
                           wheel's place (0..3) in the order the firmware sends the commands
  per_wheel_latency        wheel j acts tau_j s after it (the order read off the data)
  actuator_lag             the duty each motor sees follows the command through a first-order
                           lag of time constant tau_a (driver ramping / output filter)

A latency is a pure time shift of each wheel's zero-order-hold duty schedule, so it is not a
kernel hook: `delay_schedule` rewrites the schedule before the kernel sees it, in
`simulate_batch` (fit, predict, diagnosis, simulated campaigns) and in the step-by-step
`Simulator` (the simulated board, `sim://?effects.command_latency.tau=0.02`). Before a
wheel's first delayed command its duty is 0 (the run starts at rest). Energy: a shifted
schedule is still a schedule, so the power balance closes term by term; the terms book no
power of their own (E_<term> = 0).

The 2019 Arduino sketches send four 4-byte Sabertooth packets at 9600 baud one motor after
another (4 x 10 bits / 9600 = 4.17 ms each): `serial_command_latency` with the run's recorded
send order (`Scenario.command_order`) is that pattern.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from omnibench.model.terms import Param, Term, register

#: one 4-byte packet at 9600 baud, 8N1 (10 bits per byte), s
PACKET_9600 = 4 * 10 / 9600.0
MAX_LATENCY = 0.2  # s, physical range of a latency parameter

TIMING_TERMS = ("command_latency", "serial_command_latency", "per_wheel_latency", "actuator_lag")
MAX_LAG = 0.5  # s, physical range of an actuator time constant

command_latency = register(Term(
    name="command_latency",
    title="Command latency (every wheel)",
    doc="u_j(t) = u_cmd,j(t - tau): the duty logged at a time stamp reaches the motors tau s "
        "later (firmware loop, serial link to the driver, driver update). A pure time shift of "
        "the schedule: steady states are unchanged, every change of duty arrives late.",
    params=(Param("tau", "s", 0.0, "latency of every wheel's command", 0.0, MAX_LATENCY),),
    reveals="step_response (residual concentrated just after each change of duty)",
))

serial_command_latency = register(Term(
    name="serial_command_latency",
    title="Serialised motor commands (one packet per wheel)",
    doc="u_j(t) = u_cmd,j(t - tau - tau_packet slot_j): the firmware sends one packet per motor, "
        "one after another; slot_j is wheel j's place in the send order the run records "
        "(2019 square-wave sketch FL, FR, BL, BR; RC sketch FL, FR, BR, BL; default FL, FR, RL, RR). "
        "At 9600 baud a 4-byte packet takes 4.17 ms.",
    params=(Param("tau", "s", 0.0, "latency of the first wheel in the send order", 0.0, MAX_LATENCY),
            Param("tau_packet", "s", 0.0, "extra latency per place in the send order (one packet)",
                  0.0, 0.05)),
    reveals="step_response (residual after each change of duty, growing along the send order)",
))

per_wheel_latency = register(Term(
    name="per_wheel_latency",
    title="Command latency per wheel",
    doc="u_j(t) = u_cmd,j(t - tau_j): each wheel's command arrives with its own latency "
        "(the order in which a firmware serves the motors, read off the data).",
    params=tuple(Param(f"tau_{j}", "s", 0.0, f"latency of wheel {j}'s command", 0.0, MAX_LATENCY)
                 for j in range(1, 5)),
    reveals="step_response (residual after each change of duty, different per wheel)",
))


actuator_lag = register(Term(
    name="actuator_lag",
    title="Actuator lag (first-order duty filter)",
    doc="tau_a du_eff,j/dt = u_j - u_eff,j, u_eff = 0 at the start: the duty the motor sees "
        "follows the command with time constant tau_a (a motor driver that ramps or filters its "
        "output, e.g. a Sabertooth's ramping). Steady states are unchanged; unlike a latency the "
        "change starts at once but arrives gradually. A rewrite of the schedule like the "
        "latencies (after them): it books no power of its own (E_actuator_lag = 0).",
    params=(Param("tau_a", "s", 0.0, "time constant of the duty the motors see", 0.0, MAX_LAG),),
    reveals="step_response (residual just after each change of duty, decaying over tau_a)",
))


def slots(order: Sequence[int] | None) -> np.ndarray:
    """Place (0..3) of each wheel FL, FR, RL, RR in a send order given as wheel numbers 1..4."""
    order = tuple(order) if order is not None else (1, 2, 3, 4)
    if sorted(order) != [1, 2, 3, 4]:
        raise ValueError(f"command order must list the wheels 1..4 once each, not {order}")
    out = np.zeros(4)
    for place, wheel in enumerate(order):
        out[wheel - 1] = place
    return out


def wheel_delays(terms: Mapping[str, Mapping[str, float]], order: Sequence[int] | None = None) -> np.ndarray:
    """Latency of each wheel's command (4,), s, from the enabled timing terms ({term: params});
    the terms add."""
    d = np.zeros(4)
    if "command_latency" in terms:
        d += float(terms["command_latency"].get("tau", 0.0))
    if "serial_command_latency" in terms:
        p = terms["serial_command_latency"]
        d += float(p.get("tau", 0.0)) + float(p.get("tau_packet", 0.0)) * slots(order)
    if "per_wheel_latency" in terms:
        p = terms["per_wheel_latency"]
        d += np.array([float(p.get(f"tau_{j}", 0.0)) for j in range(1, 5)])
    return d


def wheel_lags(terms: Mapping[str, Mapping[str, float]]) -> np.ndarray:
    """Actuator time constant of each wheel (4,), s (0: no lag)."""
    return np.full(4, float(terms["actuator_lag"].get("tau_a", 0.0)) if "actuator_lag" in terms else 0.0)


def lag_coefficients(tau: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Per physics step dt of a first-order lag with time constants tau (0: none): the decay
    a = exp(-dt/tau) and the weight c = tau/dt (1 - a) of the start value in the step average."""
    tau = np.asarray(tau, dtype=float)
    safe = np.where(tau > 0, tau, 1.0)
    a = np.where(tau > 0, np.exp(-dt / safe), 0.0)
    return a, np.where(tau > 0, safe / dt * (1.0 - a), 0.0)


def lag_schedules(t_cmd: np.ndarray, U: np.ndarray, lags: np.ndarray, dt: float,
                  t_end: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold schedules (t_cmd (K,), U (B, K, 4)) through a first-order lag per wheel
    (lags (B, 4), s; 0 = none) -> (t (N,), U' (B, N, 4)) on the physics grid k dt up to t_end:
    each step's exact average of the lagged duty, the command held constant over the step at
    its own average (exact for a schedule on the grid, as `delay_schedules(..., dt)` gives)."""
    from scipy.signal import lfilter

    U = np.asarray(U, dtype=float)
    B = U.shape[0]
    n = int(math.ceil(t_end / dt - 1e-9)) + 1
    grid = np.arange(n + 1) * dt
    ubar = np.diff(_integral(np.asarray(t_cmd, dtype=float), U, np.zeros((B, 4)), grid), axis=2) / dt  # (B, 4, n)
    out = ubar.copy()
    lags = np.asarray(lags, dtype=float).reshape(B, 4)
    a, c = lag_coefficients(lags, dt)
    for b, j in zip(*np.nonzero(lags > 0)):
        y = lfilter([0.0, 1.0 - a[b, j]], [1.0, -a[b, j]], ubar[b, j])  # value at each step's start, 0 at t = 0
        out[b, j] = ubar[b, j] + (y - ubar[b, j]) * c[b, j]
    return grid[:-1], np.ascontiguousarray(out.transpose(0, 2, 1))


def delay_schedules(t_cmd: np.ndarray, U: np.ndarray, delays: np.ndarray,
                    dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold schedules (t_cmd (K,), U (B, K, 4)) with wheel j of trajectory b delayed
    by delays[b, j] s -> (t (K',), U' (B, K', 4)) on one common time base; 0 before a wheel's
    first delayed command (and before t_cmd[0] as always).

    With `dt` (the physics step) a delayed change that falls inside a step gives that step the
    time average of the duty over it: the kernel holds one duty per step, and the average makes
    the trajectory a continuous function of the latency (a fit can differentiate it) and exact
    for the energy the driver delivers over the step."""
    t_cmd = np.asarray(t_cmd, dtype=float)
    U = np.asarray(U, dtype=float)
    B = U.shape[0]
    delays = np.asarray(delays, dtype=float).reshape(B, 4)
    shifted = t_cmd[None, None, :] + delays[:, :, None]  # (B, 4, K)
    if dt is None:
        times = np.unique(shifted.ravel())
        idx = np.searchsorted(t_cmd, times[None, None, :] - delays[:, :, None] + 1e-12, side="right") - 1
        gathered = np.take_along_axis(U.transpose(0, 2, 1), np.maximum(idx, 0), axis=2)  # (B, 4, K')
        return times, np.ascontiguousarray(np.where(idx >= 0, gathered, 0.0).transpose(0, 2, 1))
    k = np.floor(shifted.ravel() / dt + 1e-9)
    times = np.unique(np.concatenate([k * dt, (k + 1) * dt]))
    lo = _integral(t_cmd, U, delays, times)
    hi = _integral(t_cmd, U, delays, times + dt)
    return times, np.ascontiguousarray(((hi - lo) / dt).transpose(0, 2, 1))


def _integral(t_cmd: np.ndarray, U: np.ndarray, delays: np.ndarray, at: np.ndarray) -> np.ndarray:
    """int_0^t u_j(s - d_j) ds of each delayed zero-order-hold schedule at times `at`: (B, 4, len(at))."""
    Uw = U.transpose(0, 2, 1)  # (B, 4, K)
    widths = np.diff(t_cmd)
    cum = np.concatenate([np.zeros(Uw.shape[:2] + (1,)), np.cumsum(Uw[:, :, :-1] * widths, axis=2)], axis=2)
    rel = at[None, None, :] - delays[:, :, None]  # time in the undelayed schedule
    m = np.searchsorted(t_cmd, rel, side="right") - 1
    mc = np.maximum(m, 0)
    val = np.take_along_axis(cum, mc, axis=2) + np.take_along_axis(Uw, mc, axis=2) * (rel - t_cmd[mc])
    return np.where(m >= 0, val, 0.0)


def step_average(history: Sequence[tuple[float, np.ndarray]], delays: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """Average over [t0, t1] of each wheel's delayed duty, from commands issued at the times
    in `history` ((time, duties (4,)), increasing); 0 before the first. For the step-by-step
    simulator: the same duty per physics step as `delay_schedules(..., dt)`."""
    t = np.array([h[0] for h in history], dtype=float)
    U = np.array([h[1] for h in history], dtype=float)[None]
    d = np.asarray(delays, dtype=float)[None]
    ends = _integral(t, U, d, np.array([t0, t1]))[0]
    return (ends[:, 1] - ends[:, 0]) / (t1 - t0)


def library_effects() -> dict:
    """The timing candidates as diagnosis sees them (omnibench.effects.library.Effect)."""
    from omnibench.effects.library import Effect

    order = {"per_wheel_latency": "log the command's arrival at each driver (or swap the send order in "
                                  "the firmware): a serial pattern moves with the order, a wheel's own "
                                  "latency does not"}
    return {e.name: e for e in (
        Effect("command_latency", fit=("tau",), example={"tau": 0.02}, start={"tau": 0.005},
               procedures=("step_response",), variable="time since duty change",
               separates={"serial_command_latency": "compare wheels: a serial link makes the latency grow "
                          "along the send order"}),
        Effect("serial_command_latency", fit=("tau", "tau_packet"),
               example={"tau": 0.01, "tau_packet": PACKET_9600}, start={"tau": 0.005, "tau_packet": 0.002},
               procedures=("step_response",), variable="time since duty change", separates=order,
               nests=("command_latency",)),
        Effect("actuator_lag", fit=("tau_a",), example={"tau_a": 0.03}, start={"tau_a": 0.005},
               procedures=("step_response",), variable="time since duty change",
               separates={"command_latency": "look at the first sample after a change: a latency moves "
                          "nothing until it has passed, a lag starts at once and arrives gradually; "
                          "log faster than tau_a to see the shape"}),
        Effect("per_wheel_latency", fit=("tau_1", "tau_2", "tau_3", "tau_4"),
               example={"tau_1": 0.015, "tau_2": 0.004, "tau_3": 0.010, "tau_4": 0.002},
               start={f"tau_{j}": 0.005 for j in range(1, 5)},
               procedures=("step_response",), variable="time since duty change",
               separates={"serial_command_latency": order["per_wheel_latency"]},
               nests=("command_latency", "serial_command_latency")),
    )}
