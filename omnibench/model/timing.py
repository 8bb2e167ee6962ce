"""Command timing inside the model: when a logged duty reaches each motor.

The schedule arithmetic the simulator needs (issue 35: the model does not import the effect
library): a wheel's latency from the timing terms and the run's firmware send order, a latency
as an exact time shift of the zero-order-hold duty schedule, and a first-order actuator lag.
The terms themselves (their documentation, parameters and diagnosis metadata) are registered
in omnibench/effects/timing.py.

Firmware timing versus the robot's own effects (issue 36): the latencies (command_latency,
serial_command_latency, per_wheel_latency) are properties of the firmware that recorded a run,
the order and rate at which it sends the driver packets; actuator_lag (a driver that ramps) is
the robot's. `FIRMWARE_TERMS` / `ROBOT_TIMING_TERMS` say which is which (model files keep them
apart: analysis/model_file.py). Latencies are expressed in the send order: per_wheel_latency's
tau_k is the latency of the k-th packet a loop sends, so a model fitted on one sketch's runs
predicts another sketch's runs with that sketch's order (`Scenario.command_order`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

#: one 4-byte packet at 9600 baud, 8N1 (10 bits per byte), s
PACKET_9600 = 4 * 10 / 9600.0
MAX_LATENCY = 0.2  # s, physical range of a latency parameter
MAX_LAG = 0.5  # s, physical range of an actuator time constant

TIMING_TERMS = ("command_latency", "serial_command_latency", "per_wheel_latency", "actuator_lag")
#: timing that belongs to the firmware recording a run (send order, loop timing)
FIRMWARE_TERMS = ("command_latency", "serial_command_latency", "per_wheel_latency")
#: timing that belongs to the robot (its motor drivers), whatever the firmware
ROBOT_TIMING_TERMS = ("actuator_lag",)


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
    """Latency of each wheel's command (4,), s, from the enabled timing terms ({term: params}) and
    the run's send order (wheels 1..4; None: FL, FR, RL, RR); the terms add. The latencies are
    firmware timing, so they follow the send order: per_wheel_latency's tau_k belongs to the
    wheel sent k-th (for the default order, wheel k), serial_command_latency's packets likewise."""
    d = np.zeros(4)
    if "command_latency" in terms:
        d += float(terms["command_latency"].get("tau", 0.0))
    if "serial_command_latency" in terms:
        p = terms["serial_command_latency"]
        d += float(p.get("tau", 0.0)) + float(p.get("tau_packet", 0.0)) * slots(order)
    if "per_wheel_latency" in terms:  # tau_k: the k-th packet of the run's send order
        p = terms["per_wheel_latency"]
        taus = np.array([float(p.get(f"tau_{k}", 0.0)) for k in range(1, 5)])
        d += taus[slots(order).astype(int)]
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
    U = np.asarray(U, dtype=float)
    B = U.shape[0]
    n = int(math.ceil(t_end / dt - 1e-9)) + 1
    grid = np.arange(n + 1) * dt
    ubar = np.diff(schedule_integral(np.asarray(t_cmd, dtype=float), U, np.zeros((B, 4)), grid),
                   axis=2) / dt  # (B, 4, n)
    out = ubar.copy()
    lags = np.asarray(lags, dtype=float).reshape(B, 4)
    a, c = lag_coefficients(lags, dt)
    start = _lag_filter()
    for b, j in zip(*np.nonzero(lags > 0)):
        y = start(ubar[b, j], float(a[b, j]))  # value at each step's start, 0 at t = 0
        out[b, j] = ubar[b, j] + (y - ubar[b, j]) * c[b, j]
    return grid[:-1], np.ascontiguousarray(out.transpose(0, 2, 1))


def _lag_starts(x: np.ndarray, a: float) -> np.ndarray:
    """The lagged value at each step's start, 0 at the first: y[k] = (1 - a) x[k-1] + a y[k-1].
    The arithmetic of scipy.signal.lfilter([0, 1 - a], [1, -a], x) (direct form II transposed),
    step for step, so the numbers are the same bit for bit (tests/effects/test_timing.py); not
    scipy's own: importing scipy.signal costs ~1 s of every process that simulates a lag (each
    diagnose screens actuator_lag), for a one-line recursion."""
    b1 = 1.0 - a
    a1 = -a
    y = np.empty_like(x)
    z = 0.0
    for k in range(x.shape[0]):
        yk = z + 0.0 * x[k]
        y[k] = yk
        z = x[k] * b1 - yk * a1
    return y


_LAG_FILTER = None


def _lag_filter():
    """`_lag_starts` compiled by numba (cached on disk; numba is imported only when a lag is
    simulated: this module is also read by the robot file's loader)."""
    global _LAG_FILTER
    if _LAG_FILTER is None:
        from numba import njit

        _LAG_FILTER = njit(cache=True)(_lag_starts)
    return _LAG_FILTER


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
    lo = schedule_integral(t_cmd, U, delays, times)
    hi = schedule_integral(t_cmd, U, delays, times + dt)
    return times, np.ascontiguousarray(((hi - lo) / dt).transpose(0, 2, 1))


def schedule_integral(t_cmd: np.ndarray, U: np.ndarray, delays: np.ndarray, at: np.ndarray) -> np.ndarray:
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
    ends = schedule_integral(t, U, d, np.array([t0, t1]))[0]
    return (ends[:, 1] - ends[:, 0]) / (t1 - t0)
