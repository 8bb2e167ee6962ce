"""Load-distribution effects (`normal_force` hook).

  com_offset   F_N,i = W/4 (1 + dx s_i / L^2 + dy d_i / l^2)      on the ground only

The centre of mass sits (dx, dy) from the geometric centre (body frame, m). With the four
contacts as equal springs on a rigid chassis, the load is linear in the wheel position; this
is the unique linear split with sum F_N = W and moments sum F_N s = W dx, sum F_N d = W dy
(the statics of a weight at (dx, dy) on the four contacts). Upside down the wheels carry only
their own weight, so the term does nothing there.
"""

from __future__ import annotations

from numba import njit

from omnibench.model.context import CTX_L, CTX_LW, CTX_MODE, CTX_W, MODE_GROUND
from omnibench.model.terms import Param, Term, register


@njit(cache=True)
def com_offset_normal_force(FN, ctx, p):
    """Shift load toward the side the centre of mass is on, keeping sum F_N = W, N."""
    dx, dy = p[0], p[1]
    if ctx[CTX_MODE] != MODE_GROUND or (dx == 0.0 and dy == 0.0):
        return
    L, l, W = ctx[CTX_L], ctx[CTX_LW], ctx[CTX_W]
    s1 = dx / (L * L)
    s2 = dy / (l * l)
    # wheel order FL, FR, RL, RR: s = (L, L, -L, -L), d = (l, -l, l, -l)
    FN[0] += 0.25 * W * (s1 * L + s2 * l)
    FN[1] += 0.25 * W * (s1 * L - s2 * l)
    FN[2] += 0.25 * W * (-s1 * L + s2 * l)
    FN[3] += 0.25 * W * (-s1 * L - s2 * l)


com_offset = register(
    Term(
        name="com_offset",
        title="Centre-of-mass offset (unequal load on the wheels)",
        doc="F_N,i = W/4 (1 + dx s_i/L^2 + dy d_i/l^2): battery or payload off-centre. Every "
        "load-dependent term ((1 + c F_N), (1 + c_r F_N), C_r F_N) then differs by wheel: a "
        "sideways offset dy makes straight runs curve, a fore-aft offset dx makes lateral runs turn.",
        params=(
            Param("dx", "m", 0.03, "centre of mass ahead of the geometric centre", -0.1, 0.1),
            Param("dy", "m", 0.0, "centre of mass left of the geometric centre", -0.1, 0.1),
        ),
        hooks={"normal_force": com_offset_normal_force},
        reveals="forward_runs (heading drift, dy), lateral_runs (heading drift, dx)",
    )
)
