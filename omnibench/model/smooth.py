"""Regularised sign used for every Coulomb-type term.

sign_eps(x) = x / sqrt(x^2 + eps^2): odd, smooth, |.| < 1, equals sign(x) to within
0.5 % once |x| > 10 eps and 5e-5 once |x| > 100 eps. The width eps is a documented robot
setting (`sign_width_phi` in rad/s for wheel speeds, `sign_width_sigma` in m/s for roller
slip). It keeps the integrator stable at zero speed: the kernel sub-steps when b/eps is stiff. Upside
down the kernel passes an exact width (kernel.EXACT_SIGN_WIDTH) and decides sticking itself.
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, inline="always")
def sign_eps(x: float, eps: float) -> float:
    """Smooth sign of x with width eps (same units as x)."""
    return x / math.sqrt(x * x + eps * eps)
