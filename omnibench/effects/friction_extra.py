"""Wheel-axle friction effects the paper's model lacks (torque domain, `wheel_torque` hook).

All torques are on the wheel axle (referred to the wheel shaft, like the paper's a, b), N m,
positive in the sense of positive wheel speed. `wheel_sign` is the model's regularised wheel sign
(width `sign_width_phi`, rad/s), so every Coulomb-type term is smooth at zero speed.

  stribeck_friction   tau = -(1 + c_s F_N) b_s exp(-|phi_dot / w_s|^shape) sign(phi_dot)   (ground: sign rounded over max(eps, w_s/2))
  asymmetric_coulomb  tau = -(1 + c_db F_N) db |sign(phi_dot)|   (Coulomb b + db forward, b - db backward)
  per_wheel_friction  tau_i = -(da_i phi_dot_i + db_i sign(phi_dot_i))   (one gearbox stiffer than the others)
  quadratic_drag      tau = -d_q |phi_dot| phi_dot     (lubricant churning, motor fan windage)
  cogging_torque      tau = -A_c sin(n_c phi + phase)  (conservative ripple: cogging, roller hand-over)

A term whose size parameter is exactly zero returns at once: its zero-size limit is the base
model bit for bit.
"""

from __future__ import annotations

import math

from numba import njit

from omnibench.model.context import CTX_MODE, CTX_SIGN_PHI
from omnibench.model.smooth import wheel_sign
from omnibench.model.terms import Param, Term, register


@njit(cache=True)
def stribeck_torque(out, phi, phi_dot, FN, i_motor, xs, ctx, p):
    """-(1 + c_s F_N) b_s exp(-|phi_dot/w_s|^shape) sign(phi_dot), N m."""
    b_s, w_s, c_s, shape = p[0], p[1], p[2], p[3]
    if b_s == 0.0:
        return
    # On the ground rounded over max(sign width, w_s / 2): keeps the term no stiffer at zero
    # speed than the paper's Coulomb friction (the hump peaks near w_s/2). Upside down the sign
    # is exact like every dry term there (the kernel's stick-slip decides at zero speed).
    eps = max(ctx[CTX_SIGN_PHI], 0.5 * w_s * (1.0 - ctx[CTX_MODE]))
    for j in range(4):
        x = abs(phi_dot[j]) / w_s
        out[j] = -(1.0 + c_s * FN[j]) * b_s * math.exp(-(x ** shape)) * wheel_sign(phi_dot[j], eps)


@njit(cache=True)
def asymmetric_coulomb_torque(out, phi, phi_dot, FN, i_motor, xs, ctx, p):
    """-(1 + c_db F_N) db |sign(phi_dot)|: Coulomb friction b + db turning forward, b - db
    turning backward, scaling with the axle load like b, N m."""
    db, c_db = p[0], p[1]
    if db == 0.0:
        return
    eps = ctx[CTX_SIGN_PHI]
    for j in range(4):
        out[j] = -(1.0 + c_db * FN[j]) * db * abs(wheel_sign(phi_dot[j], eps))


@njit(cache=True)
def per_wheel_friction_torque(out, phi, phi_dot, FN, i_motor, xs, ctx, p):
    """-(da_i phi_dot_i + db_i sign(phi_dot_i)): extra friction of each wheel's gearbox, N m."""
    eps = ctx[CTX_SIGN_PHI]
    for j in range(4):
        if p[j] != 0.0 or p[4 + j] != 0.0:
            out[j] = -p[4 + j] * phi_dot[j] - p[j] * wheel_sign(phi_dot[j], eps)


@njit(cache=True)
def quadratic_drag_torque(out, phi, phi_dot, FN, i_motor, xs, ctx, p):
    """-d_q |phi_dot| phi_dot on each axle, N m."""
    d_q = p[0]
    if d_q == 0.0:
        return
    for j in range(4):
        out[j] = -d_q * abs(phi_dot[j]) * phi_dot[j]


@njit(cache=True)
def cogging_torque_hook(out, phi, phi_dot, FN, i_motor, xs, ctx, p):
    """-A_c sin(n_c phi + phase): periodic, conservative torque on each axle, N m."""
    A_c, n_c, phase = p[0], p[1], p[2]
    if A_c == 0.0:
        return
    for j in range(4):
        out[j] = -A_c * math.sin(n_c * phi[j] + phase)


stribeck_friction = register(
    Term(
        name="stribeck_friction",
        title="Stribeck friction (static friction above Coulomb, decaying with speed)",
        doc="tau = -(1 + c_s F_N) b_s exp(-|phi_dot/w_s|^shape) sign(phi_dot): breakaway friction "
        "of the gear mesh and bearings exceeds the sliding (Coulomb) value and decays over the "
        "Stribeck speed w_s (shape 2: Gaussian decay, 1: exponential). Torque domain, so it grows "
        "with the axle load like the paper's b.",
        params=(
            Param("b_s", "N*m", 0.15, "extra breakaway (static minus Coulomb) torque", 0.0, 2.0),
            Param("w_s", "rad/s", 1.0, "Stribeck speed: width of the low-speed hump", 0.05, 20.0),
            Param("c_s", "1/N", 0.01, "load dependence of the breakaway torque (like c)", 0.0, 1.0),
            Param("shape", "1", 2.0, "decay exponent: 2 Gaussian, 1 exponential", 0.5, 4.0),
        ),
        hooks={"wheel_torque": stribeck_torque},
        reveals="upside_down_sweep (low duties, both wheel sets), step_response (start-up)",
    )
)

asymmetric_coulomb = register(
    Term(
        name="asymmetric_coulomb",
        title="Direction-asymmetric Coulomb friction",
        doc="tau = -(1 + c_db F_N) db |sign(phi_dot)|: the gearbox's dry friction is b + db turning "
        "forward and b - db turning backward (worm/helical gear thrust, brush timing, seal lip "
        "direction); dry friction, so it grows with the axle load like the paper's b.",
        params=(Param("db", "N*m", 0.05, "half the forward-minus-backward Coulomb torque", -1.0, 1.0),
                Param("c_db", "1/N", 0.01, "load dependence of the asymmetry (like c)", 0.0, 1.0)),
        hooks={"wheel_torque": asymmetric_coulomb_torque},
        reveals="upside_down_sweep in both directions (forward steady speeds lower than backward)",
    )
)

per_wheel_friction = register(
    Term(
        name="per_wheel_friction",
        title="Per-wheel friction differences",
        doc="tau_i = -(da_i phi_dot_i + db_i sign(phi_dot_i)): each wheel's gearbox has its own "
        "extra viscous and dry friction on top of the common a, b (assembly, wear, grease). Only "
        "differences between wheels are identifiable beside a and b: diagnosis fits da_2..da_4 and "
        "db_2..db_4 with wheel 1 as the reference.",
        params=(
            Param("db_1", "N*m", 0.0, "extra Coulomb torque of wheel 1 (front left)", -1.0, 1.0),
            Param("db_2", "N*m", 0.0, "extra Coulomb torque of wheel 2 (front right)", -1.0, 1.0),
            Param("db_3", "N*m", 0.0, "extra Coulomb torque of wheel 3 (rear left)", -1.0, 1.0),
            Param("db_4", "N*m", 0.0, "extra Coulomb torque of wheel 4 (rear right)", -1.0, 1.0),
            Param("da_1", "N*m*s/rad", 0.0, "extra viscous friction of wheel 1", -0.2, 0.2),
            Param("da_2", "N*m*s/rad", 0.0, "extra viscous friction of wheel 2", -0.2, 0.2),
            Param("da_3", "N*m*s/rad", 0.0, "extra viscous friction of wheel 3", -0.2, 0.2),
            Param("da_4", "N*m*s/rad", 0.0, "extra viscous friction of wheel 4", -0.2, 0.2),
        ),
        hooks={"wheel_torque": per_wheel_friction_torque},
        reveals="upside_down_sweep (residual differs by wheel, same sign at every duty)",
    )
)

quadratic_drag = register(
    Term(
        name="quadratic_drag",
        title="Quadratic (churning / windage) drag on the wheel axle",
        doc="tau = -d_q |phi_dot| phi_dot on each wheel axle: lubricant churning in the gearbox "
        "and the motor's fan windage grow with the square of speed. (Air drag on the body is "
        "~5 mN at 0.3 m/s, far below the rolling resistance, so the axle is where a quadratic "
        "loss is physically visible on this robot; it acts upside down and on the ground.)",
        params=(Param("d_q", "N*m*s^2/rad^2", 1e-3, "quadratic drag coefficient on the axle", 0.0, 0.1),),
        hooks={"wheel_torque": quadratic_drag_torque},
        reveals="upside_down_sweep (high duties: speed saturates below the linear prediction)",
    )
)

cogging_torque = register(
    Term(
        name="cogging_torque",
        title="Periodic axle torque (motor cogging reflected through the gearbox, roller hand-over)",
        doc="tau = -A_c sin(n_c phi + phase): a conservative torque ripple with n_c periods per "
        "wheel revolution (detent of the magnets seen through the gearbox, or the bump as the "
        "contact passes from one roller to the next). It averages to zero over a revolution "
        "but holds a slowly driven wheel in its valleys.",
        params=(
            Param("A_c", "N*m", 0.3, "ripple amplitude", 0.0, 5.0),
            Param("n_c", "1", 10.0, "periods per wheel revolution (e.g. number of rollers)", 1.0, 500.0),
            Param("phase", "rad", 0.0, "phase of the ripple at phi = 0", -math.pi, math.pi),
        ),
        hooks={"wheel_torque": cogging_torque_hook},
        reveals="upside_down_sweep at the lowest duties (wheel stalls in a valley), step_response (speed ripple)",
    )
)
