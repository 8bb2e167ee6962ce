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
