"""The paper's eq. (8), once, in plain numpy with the paper's symbols: the robot on the ground.

The reference the numba kernel is tested against (tests/model/test_physics.py integrates it with
scipy and compares trajectories with `simulate`). It is written in the paper's world frame, with
H(ψ) and K(ψ, ψ̇) as printed; the kernel integrates the same dynamics in the body frame, where
the mass matrix is constant (docs/robot-file.md, "The model these numbers feed"). Slow and
readable on purpose: nothing else in the package calls it.

The paper ("Mecanum wheels model sophistication", §II.iv, eq. 8; the terms from §I.ii and
§II.i-iii):

    H q̈_r + K q̇_r = R_ψ Rᵀ (Γ + τ_r) + F_rr                                        (8)

    H = M_r + R_ψ Rᵀ M_w R R_ψᵀ            M_r = diag(m, m, I_z),  M_w = I_w 𝟙₄
    K = R_ψ Rᵀ M_w R Ṙ_ψᵀ

with q_r = (x, y, ψ) the pose in the world frame (m, m, rad), and, per wheel i:

    φ̇ = R R_ψᵀ q̇_r                          wheel speeds (rad/s); R the inverse kinematics
    σ = S R_ψᵀ q̇_r                          roller slip speeds (m/s); S the slip matrix
    i = (u V_batt − k_e φ̇) / R_a            motor current (A), u the duty in [−1, 1]
    Γ = η k_t i − (1 + c F_N)(a φ̇ + b sign φ̇)          wheel torque (N m): motor − transmission friction
    τ_r = −F_N C_r r sign φ̇                               rolling resistance (N m)
    τ' = −(1 + c_r F_N)(a_r σ + b_r sign σ)               roller-axis friction (N)
    F_rr = R_ψ Sᵀ τ'                                        its generalised force (N, N, N m)
    F_N = (m + payload) g / 4                              normal force per wheel (N)

The paper reuses a, b, c for the rollers; they have their own coefficients here (a_r, b_r, c_r),
as in the robot file. sign() is the model's smooth sign (omnibench/model/smooth.py): tanh(x/ε)
for wheel speeds (ε = sign_width_phi), x/√(x² + ε²) for roller slip (ε = sign_width_sigma).
"""

from __future__ import annotations

import numpy as np

from omnibench.model.context import GRAVITY
from omnibench.model.geometry import inverse_kinematics, rotation, slip_matrix
from omnibench.model.robot import Robot


def rotation_rate(psi: float, psi_dot: float) -> np.ndarray:
    """Ṙ_ψ: the time derivative of the rotation R_ψ at heading ψ (rad) turning at ψ̇ (rad/s)."""
    return psi_dot * np.array([[-np.sin(psi), -np.cos(psi), 0.0],
                               [np.cos(psi), -np.sin(psi), 0.0],
                               [0.0, 0.0, 0.0]])


def eq8_accelerations(robot: Robot, u: np.ndarray, q_r: np.ndarray, q_r_dot: np.ndarray, *,
                      payload: float = 0.0, roller: bool = True) -> np.ndarray:
    """q̈_r = H⁻¹ (F_a − K q̇_r): the pose accelerations (m/s², m/s², rad/s²) of eq. (8) for the
    duties `u` (FL, FR, RL, RR), the pose q_r = (x, y, ψ) and its rate q̇_r (world frame).

    payload: kg on the robot (it loads the wheels and the body); roller=False leaves out the
    roller-axis friction F_rr (the paper's base model, eq. 5, with a_r = b_r = c_r = 0)."""
    R = inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha)
    S = slip_matrix(robot.L, robot.l, robot.alpha)
    m = robot.m + payload
    M_r = np.diag([m, m, robot.I_z])
    M_w = robot.I_w * np.eye(4)
    F_N = np.full(4, m * GRAVITY / 4)
    psi = q_r[2]
    R_psi = rotation(psi)
    H = M_r + R_psi @ R.T @ M_w @ R @ R_psi.T
    K = R_psi @ R.T @ M_w @ R @ rotation_rate(psi, q_r_dot[2]).T

    phi_dot = R @ R_psi.T @ q_r_dot
    sigma = S @ R_psi.T @ q_r_dot
    sign_phi = np.tanh(phi_dot / robot.sign_width_phi)
    sign_sigma = sigma / np.sqrt(sigma**2 + robot.sign_width_sigma**2)

    i = (u * robot.V_batt - robot.k_e * phi_dot) / robot.R_a
    Gamma = robot.eta * robot.k_t * i - (1 + robot.c * F_N) * (robot.a * phi_dot + robot.b * sign_phi)
    tau_r = -F_N * robot.C_r * robot.r * sign_phi
    tau_prime = -(1 + robot.c_r * F_N) * (robot.a_r * sigma + robot.b_r * sign_sigma)
    F_rr = R_psi @ S.T @ tau_prime if roller else np.zeros(3)

    F_a = R_psi @ R.T @ (Gamma + tau_r) + F_rr
    q_r_ddot: np.ndarray = np.linalg.solve(H, F_a - K @ q_r_dot)
    return q_r_ddot
