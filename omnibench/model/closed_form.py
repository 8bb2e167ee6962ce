"""Closed forms of the model that procedures and fits check against."""

from __future__ import annotations

import math

from omnibench.model.robot import Robot


def upside_down_steady_speed(robot: Robot, u: float, F_N: float) -> float:
    """Steady wheel speed (rad/s) on blocks at duty u with axle load F_N (N), paper III.i:
    eta k_t (u V_batt - k_e w)/R_a = (1 + c F_N)(a w + b sign w). Zero below breakaway."""
    g = robot.eta * robot.k_t / robot.R_a
    load = 1.0 + robot.c * F_N
    drive = g * u * robot.V_batt
    if abs(drive) <= load * robot.b:
        return 0.0
    return (drive - load * robot.b * math.copysign(1.0, u)) / (g * robot.k_e + load * robot.a)
