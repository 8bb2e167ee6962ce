"""Regularised signs used for every Coulomb-type term on the ground.

wheel_sign(x) = tanh(x / eps), for wheel speeds (eps = `sign_width_phi`, rad/s): odd, smooth,
slope 1/eps at zero, within 0.5 % of sign(x) once |x| > 3 eps and 4e-9 once |x| > 10 eps.
A wheel turns far outside eps but not always far enough for a slow tail: the algebraic form
below is still 7e-4 short at 26 eps (a wheel at 0.26 rad/s in a 60 deg lateral run), more dry
friction than a well-planned fit resolves on b (docs/design.md).

slip_sign(x) = x / sqrt(x^2 + eps^2), for roller slip (eps = `sign_width_sigma`, m/s): the same
slope at zero, within 0.5 % once |x| > 10 eps. Rollers slip far outside eps in any run that
moves sideways (5e-7 short at 1000 eps), and under small side forces they creep inside it,
where this form's creep is what the narrow width was set against (docs/robot-file.md).

Both keep the integrator stable at zero speed: the kernel sub-steps when b/eps is stiff. Upside
down the kernel passes an exact width (kernel.EXACT_SIGN_WIDTH) and decides sticking itself.
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, inline="always")
def wheel_sign(x: float, eps: float) -> float:
    """Smooth sign of a wheel speed x (rad/s) with width eps (rad/s): tanh(x / eps)."""
    return math.tanh(x / eps)


@njit(cache=True, inline="always")
def slip_sign(x: float, eps: float) -> float:
    """Smooth sign of a roller slip speed x (m/s) with width eps (m/s): x / sqrt(x^2 + eps^2)."""
    return x / math.sqrt(x * x + eps * eps)
