"""Effects of the surroundings (`body_force` hook, on the ground only).

  floor_slope   F_body = m g sin(theta_s) (cos(psi_s - psi), sin(psi_s - psi), 0)

The floor rises toward the world direction psi_s + pi: gravity pulls the robot (mass m plus
payload) downhill along psi_s with m g sin(theta_s). The force is turned into the body frame
with the heading psi; the centre of mass is over the geometric centre, so there is no moment.
(The normal forces change by cos(theta_s), under 0.1 % for slopes below 2.5 deg: neglected.)
"""

from __future__ import annotations

import math

from numba import njit

from omnibench.model.context import CTX_G, CTX_MASS, CTX_PSI
from omnibench.model.terms import Param, Term, register


@njit(cache=True)
def floor_slope_force(out, q, v, ctx, p):
    """Downhill component of gravity in the body frame, N."""
    theta_s, psi_s = p[0], p[1]
    if theta_s == 0.0:
        return
    F = ctx[CTX_MASS] * ctx[CTX_G] * math.sin(theta_s)
    rel = psi_s - ctx[CTX_PSI]
    out[0] = F * math.cos(rel)
    out[1] = F * math.sin(rel)


floor_slope = register(
    Term(
        name="floor_slope",
        title="Floor slope",
        doc="F = m g sin(theta_s) along the downhill direction psi_s (world frame): a floor that "
        "is not level. Forward runs downhill go further than the same runs uphill.",
        params=(
            Param("theta_s", "rad", 0.0087, "slope angle (0.5 deg)", -0.2, 0.2),
            Param("psi_s", "rad", 0.0, "downhill direction in the world frame", -math.pi, math.pi),
        ),
        hooks={"body_force": floor_slope_force},
        reveals="forward_runs (forward and backward distances differ), lateral_runs",
    )
)
