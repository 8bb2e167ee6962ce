"""Command-timing effects: when a logged duty really reaches each motor.

  command_latency          every wheel's duty acts tau s after its time stamp
  serial_command_latency   wheel j acts tau + tau_packet * slot_j s after it, slot_j = the
                           wheel's place (0..3) in the order the firmware sends the commands
  per_wheel_latency        the k-th packet of a loop acts tau_k s after it (a latency per place in
                           the send order, read off the data; for the default order FL, FR, RL, RR
                           tau_j is wheel j's)
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
send order (`Scenario.command_order`) is that pattern. Latencies are firmware timing and follow
the run's send order (omnibench/model/timing.py, where the schedule arithmetic lives).
"""

from __future__ import annotations

from omnibench.model.terms import Param, Term, register

# the schedule arithmetic lives in the model (issue 35); re-exported for the effect's users
from omnibench.model.timing import (  # noqa: F401
    FIRMWARE_TERMS,
    MAX_LAG,
    MAX_LATENCY,
    PACKET_9600,
    ROBOT_TIMING_TERMS,
    TIMING_TERMS,
    delay_schedules,
    lag_coefficients,
    lag_schedules,
    schedule_integral,
    slots,
    step_average,
    wheel_delays,
    wheel_lags,
)

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
    title="Command latency per wheel (per place in the send order)",
    doc="u_j(t) = u_cmd,j(t - tau_k), k = wheel j's place in the run's send order: each packet of a "
        "loop arrives with its own latency (the order and rate at which a firmware serves the motors, "
        "read off the data). Firmware timing: it follows the send order the run records, so with the "
        "default order FL, FR, RL, RR tau_j is wheel j's latency, and a run of the 2019 RC sketch "
        "(FL, FR, RR, RL) gives tau_3 to RR and tau_4 to RL.",
    params=tuple(Param(f"tau_{j}", "s", 0.0, f"latency of the {j}{'st' if j == 1 else 'nd' if j == 2 else 'rd' if j == 3 else 'th'} "
                       f"command in the send order (wheel {j} in the default order)", 0.0, MAX_LATENCY)
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


def library_effects() -> dict:
    """The timing candidates as diagnosis sees them (omnibench.effects.library.Effect)."""
    from omnibench.effects.library import Effect

    order = {"per_wheel_latency": "log the command's arrival at each driver: a serial link adds one packet "
                                  "time per place in the send order, per-packet latencies may step unevenly "
                                  "(both follow the send order: they are the firmware's timing)"}
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
