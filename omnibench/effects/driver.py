"""Motor-driver effects (voltage domain, `duty` hook).

  driver_deadband   u_eff = ramp(u - u_0) - ramp(-u - u_0),  ramp(x) = (x + sqrt(x^2 + w_u^2)) / 2

A dead zone of half-width u_0 (fraction of the battery voltage): the H-bridge outputs nothing
for |u| < u_0 and u - u_0 sign(u) above it, rounded over a width w_u. It is independent of
the load: that is what tells it from Stribeck friction (torque domain, grows with F_N).
"""

from __future__ import annotations

import math

from numba import njit

from omnibench.model.terms import Param, Term, register


@njit(cache=True)
def deadband_duty(u, ctx, p):
    """Map commanded duty to the duty the driver really applies (dead zone of half-width u_0)."""
    u_0, w_u, cut = p[0], p[1], p[2]
    if u_0 == 0.0:
        return
    for j in range(4):
        x1 = u[j] - u_0
        x2 = -u[j] - u_0
        shifted = 0.5 * (x1 + math.sqrt(x1 * x1 + w_u * w_u)) - 0.5 * (x2 + math.sqrt(x2 * x2 + w_u * w_u))
        m = abs(u[j]) - u_0
        passed = u[j] * 0.5 * (1.0 + m / math.sqrt(m * m + w_u * w_u))  # smooth step at |u| = u_0
        u[j] = (1.0 - cut) * shifted + cut * passed


driver_deadband = register(
    Term(
        name="driver_deadband",
        title="Motor-driver deadband",
        doc="u_eff = u - u_0 sign(u) for |u| > u_0 (form 'shifted', cut = 0) or u (form 'cut', "
        "cut = 1), 0 below (smoothed over w_u): the driver's "
        "dead zone around zero command (Sabertooth packet-serial commands -127..127: u_0 of a few "
        "counts). Voltage domain, independent of wheel load; it moves the current-speed relation "
        "not at all, only the duty-speed relation.",
        params=(
            Param("u_0", "1", 0.03, "half-width of the dead zone, fraction of V_batt", 0.0, 0.5),
            Param("w_u", "1", 0.002, "rounding width of the dead zone edges", 1e-5, 0.05),
            Param("cut", "1", 0.0, "form: 0 shifted (u - u_0 sign u above u_0), 1 cut (u passes unchanged)",
                  0.0, 1.0),
        ),
        hooks={"duty": deadband_duty},
        reveals="upside_down_sweep (lowest duties: no motion; offset independent of the wheel set)",
    )
)


def deadband_start(u, omega, current, current_se, v_batt, cut: float = 0.0, F_N=None,
                   torque_constant: float | None = None, omega_se=None) -> dict[str, float] | None:
    """Start values of the shifted deadband's fit from a sweep's steady states: the armature's
    voltage balance V (u - u_0 sign u) = k_e omega + R_a i holds at every steady state whose
    current flows (a stalled wheel too), and is linear in k_e, R_a and u_0, so one least-squares
    solve over the measured duty, speed and current gives all three. Without it the candidate
    fit starts at the declared fit's R_a, which took up the dead zone's offset (3.5 ohm for
    1.85 on the README's deadband campaign), and creeps along the valley of u_0 with R_a and
    the Coulomb term.

    With the axle loads `F_N` and the motor's torque constant (`torque_constant` = eta k_t, N m/A)
    it also gives the transmission friction from the torque balance of the turning wheels
    upside down, eta k_t i = (1 + c F_N)(a omega + b sign omega), linear in a, b, c b and c a:
    the declared fit bent a, b and c too to make up for the missing dead zone (on the README's
    deadband campaign c 0.0049 for 0.01), and a start with the voltage terms right but those
    left fits the data worse than the declared model (deviance 2885 against 1326; 788 with them).

    Returns {"u_0", "R_a", "k_e"} and, when the torque balance is solvable and physical,
    {"a", "b", "c"}; or None: form 'cut' (u passes unchanged above u_0, no offset in the
    balance), fewer than six steady states with current, a degenerate solve, or values outside
    their physical ranges."""
    import numpy as np

    if cut != 0.0:
        return None
    u, omega, current = (np.asarray(x, dtype=float) for x in (u, omega, current))
    se, v = np.asarray(current_se, dtype=float), np.asarray(v_batt, dtype=float)
    ok = np.isfinite(u) & np.isfinite(omega) & np.isfinite(current) & np.isfinite(v) & (u != 0.0)
    if not ok.any():
        return None
    # inside the dead zone no current flows and the balance does not hold: steady states whose
    # current is clear of its noise (5 SE) and of 1 % of the largest
    floor = 0.01 * float(np.max(np.abs(current[ok])))
    ok &= np.abs(current) > np.maximum(np.where(np.isfinite(se), 5.0 * se, 0.0), floor)
    if ok.sum() < 6:
        return None
    A = np.column_stack([omega[ok], current[ok], v[ok] * np.sign(u[ok])])
    coef, _, rank, _ = np.linalg.lstsq(A, v[ok] * u[ok], rcond=None)
    k_e, R_a, u_0 = (float(c) for c in coef)
    if rank < 3 or not (0.0 < u_0 < 0.5 and R_a > 0.0 and k_e > 0.0):
        return None
    out = {"u_0": u_0, "R_a": R_a, "k_e": k_e}
    if F_N is not None and torque_constant is not None and torque_constant > 0.0:
        out.update(_torque_balance(omega, current, np.asarray(F_N, dtype=float), float(torque_constant),
                                   ok, None if omega_se is None else np.asarray(omega_se, dtype=float)))
    return out


def _torque_balance(omega, current, F_N, torque_constant, ok, omega_se) -> dict[str, float]:
    """{"a", "b", "c"} from eta k_t i = (1 + c F_N)(a omega + b sign omega) over the steady states
    `ok` whose wheel turns (speed clear of 5 SE and of 1 % of the largest: a stalled wheel's
    friction is below its breakaway and says nothing of b); {} when that leaves fewer than six,
    two loads, or a solve outside the physical ranges (b > 0, a >= 0, c >= 0)."""
    import numpy as np

    turning = ok & np.isfinite(F_N)
    if not turning.any():
        return {}
    floor = 0.01 * float(np.max(np.abs(omega[turning])))
    se = np.where(np.isfinite(omega_se), 5.0 * omega_se, 0.0) if omega_se is not None else 0.0
    turning &= np.abs(omega) > np.maximum(se, floor)
    if turning.sum() < 6 or np.ptp(F_N[turning]) <= 0.0:
        return {}
    w, f, s = omega[turning], F_N[turning], np.sign(omega[turning])
    A = np.column_stack([w, s, f * s, f * w])
    coef, _, rank, _ = np.linalg.lstsq(A, torque_constant * current[turning], rcond=None)
    a, b, cb = float(coef[0]), float(coef[1]), float(coef[2])
    if rank < 4 or not (b > 0.0 and a >= 0.0 and cb >= 0.0):
        return {}
    return {"a": a, "b": b, "c": cb / b}  # c from the Coulomb part: c a is the smaller column


def deadband_sweep_start(sweep, fixed, robot=None) -> dict[str, float] | None:
    """`deadband_start` on a sweep's observation table (its steady states; rows without a
    current SE count as noise-free) for the form held at `fixed` (Effect.sweep_start), with
    `robot`'s eta k_t for the torque balance and its V_batt where the sweep logged no supply (as
    the predictor simulates those steps), when given."""
    import numpy as np

    if not len(sweep) or not {"u", "omega", "current", "V_batt"} <= set(sweep.columns):
        return None
    if "steady" in sweep.columns:
        sweep = sweep[sweep["steady"].fillna(False).astype(bool)]
    se = sweep["current_se"] if "current_se" in sweep.columns else [float("nan")] * len(sweep)
    kt = float(robot.eta * robot.k_t) if robot is not None else None
    v = np.asarray(sweep["V_batt"], dtype=float)
    if robot is not None:
        v = np.where(np.isfinite(v), v, float(robot.V_batt))
    return deadband_start(sweep["u"], sweep["omega"], sweep["current"], se, v,
                          cut=float(fixed.get("cut", 0.0)),
                          F_N=sweep["F_N"] if "F_N" in sweep.columns else None, torque_constant=kt,
                          omega_se=sweep["omega_se"] if "omega_se" in sweep.columns else None)
