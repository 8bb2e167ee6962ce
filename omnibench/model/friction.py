"""The paper's own terms: transmission friction, roller-axis friction, rolling resistance.

Equations (docs/robot-file.md, the model, paper eq. 8):
  transmission  tau_fric_i = (1 + c F_Ni)(a phi_dot_i + b sign(phi_dot_i))      (opposes the wheel)
  roller axis   tau'_i     = -(1 + c_r F_Ni)(a_r sigma_i + b_r sign(sigma_i))   (along the roller)
  rolling       tau_r_i    = -F_Ni C_r r sign(phi_dot_i)                         (on the ground only)
"""

from __future__ import annotations

from numba import njit

from omnibench.model.context import CTX_MODE, CTX_R, CTX_SIGN_PHI, CTX_SIGN_SIGMA, MODE_GROUND
from omnibench.model.smooth import slip_sign, wheel_sign
from omnibench.model.terms import Param, Term, register


@njit(cache=True)
def transmission_friction_torque(out, phi, phi_dot, FN, i_motor, xs, ctx, p):
    """-(1 + c F_N)(a phi_dot + b sign(phi_dot)) on each axle, N m."""
    a, b, c = p[0], p[1], p[2]
    eps = ctx[CTX_SIGN_PHI]
    for j in range(4):
        out[j] = -(1.0 + c * FN[j]) * (a * phi_dot[j] + b * wheel_sign(phi_dot[j], eps))


@njit(cache=True)
def roller_friction_force(out, sigma, FN, ctx, p):
    """-(1 + c_r F_N)(a_r sigma + b_r sign(sigma)) along each contact roller, N."""
    a_r, b_r, c_r = p[0], p[1], p[2]
    eps = ctx[CTX_SIGN_SIGMA]
    for j in range(4):
        out[j] = -(1.0 + c_r * FN[j]) * (a_r * sigma[j] + b_r * slip_sign(sigma[j], eps))


@njit(cache=True)
def rolling_resistance_torque(out, phi, phi_dot, FN, i_motor, xs, ctx, p):
    """-F_N C_r r sign(phi_dot) on each axle when the wheel rolls on the floor, N m."""
    # a factor, not an early return: branch-free code vectorises over the kernel's lanes
    on_floor = 1.0 if ctx[CTX_MODE] == MODE_GROUND else 0.0
    C_r = p[0] * on_floor
    r = ctx[CTX_R]
    eps = ctx[CTX_SIGN_PHI]
    for j in range(4):
        out[j] = -FN[j] * C_r * r * wheel_sign(phi_dot[j], eps)


transmission_friction = register(
    Term(
        name="transmission_friction",
        title="Motor and transmission friction (load dependent)",
        doc="tau_fric = (1 + c F_N)(a phi_dot + b sign(phi_dot)): gearbox and motor losses; "
        "c scales them with the axle load (paper II.i).",
        params=(
            Param("a", "N*m*s/rad", 0.01, "viscous transmission friction", 0.0, 1.0),
            Param("b", "N*m", 0.5, "Coulomb transmission friction", 0.0, 10.0),
            Param("c", "1/N", 0.01, "load dependence of transmission friction", 0.0, 0.2),
        ),
        hooks={"wheel_torque": transmission_friction_torque},
        core=True,
        reveals="upside_down_sweep",
    )
)

roller_friction = register(
    Term(
        name="roller_friction",
        title="Friction in the rollers' axes",
        doc="tau' = -(1 + c_r F_N)(a_r sigma + b_r sign(sigma)) along the roller in contact, "
        "with slip speed sigma = S v (paper II.ii). Zero in pure forward motion.",
        params=(
            Param("a_r", "N*s/m", 2.0, "viscous roller-axis friction", 0.0, 200.0),
            Param("b_r", "N", 1.0, "Coulomb roller-axis friction", 0.0, 100.0),
            Param("c_r", "1/N", 0.01, "load dependence of roller friction", 0.0, 0.2),
        ),
        hooks={"roller_force": roller_friction_force},
        core=True,
        reveals="lateral_runs",
    )
)

rolling_resistance = register(
    Term(
        name="rolling_resistance",
        title="Rolling resistance of the wheel",
        doc="tau_r = -F_N C_r r sign(phi_dot): hysteresis of wheel and floor (paper II.iii); "
        "absent upside down.",
        params=(Param("C_r", "1", 0.02, "rolling resistance coefficient", 0.0, 0.5),),
        hooks={"wheel_torque": rolling_resistance_torque},
        core=True,
        reveals="forward_runs",
    )
)

CORE_PARAMS = ("a", "b", "c", "a_r", "b_r", "c_r", "C_r")
