"""Mecanum geometry: inverse kinematics R (phi_dot = R v) and roller slip S (sigma = S v).

Wheel order 1 FL, 2 FR, 3 RL, 4 RR at body positions (s_i, d_i) with s = (L, L, -L, -L),
d = (l, -l, l, -l) (docs/robot-file.md, the model).
"""

from __future__ import annotations

import numpy as np


def wheel_positions(L: float, l: float) -> tuple[np.ndarray, np.ndarray]:
    """(s, d): longitudinal and lateral positions of the four wheels, m."""
    return np.array([L, L, -L, -L]), np.array([l, -l, l, -l])


def inverse_kinematics(L: float, l: float, r: float, alpha) -> np.ndarray:
    """The paper's R (4x3): row i = (1/r)[1, -cot(alpha_i), -(d_i + s_i cot(alpha_i))]."""
    s, d = wheel_positions(L, l)
    cot = 1.0 / np.tan(np.asarray(alpha, dtype=float))
    return np.column_stack([np.ones(4), -cot, -(d + s * cot)]) / r


def slip_matrix(L: float, l: float, alpha) -> np.ndarray:
    """The paper's S (4x3): row i = [0, 1/sin(alpha_i), s_i/sin(alpha_i)]; sigma in m/s."""
    s, _ = wheel_positions(L, l)
    inv_sin = 1.0 / np.sin(np.asarray(alpha, dtype=float))
    return np.column_stack([np.zeros(4), inv_sin, s * inv_sin])


def rotation(psi: float) -> np.ndarray:
    """R_psi: body frame to world frame rotation about z (3x3)."""
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
