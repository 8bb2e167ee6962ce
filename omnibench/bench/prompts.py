"""What a person at the robot is told and how they answer.

Every prompt before a step says what will move next, which way and how far (`describe_motion`);
anything that leads to motion needs an explicit "yes" (`ask_yes`: no default, so a stray Enter
never confirms), and keystrokes typed before the prompt appeared are dropped
(`flush_typeahead`).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

WHEELS = ("FL", "FR", "RL", "RR")
YES = ("yes", "y")
NO = ("no", "n", "stop", "quit")


def flush_typeahead() -> None:
    """Drop input typed before the prompt (only on a terminal; a pipe or file is left alone)."""
    try:
        if sys.stdin is not None and sys.stdin.isatty():
            import termios

            termios.tcflush(sys.stdin.fileno(), termios.TCIFLUSH)
    except (OSError, ValueError):  # closed or not a real terminal
        pass


def read_answer(prompt: str) -> str:
    import click

    flush_typeahead()
    return click.prompt(prompt, default="", show_default=False, err=True).strip()


def ask_yes(question: str, read: Callable[[str], str] = read_answer) -> None:
    """Ask until the person types yes (returns) or no (click.Abort: the run stops, resumable).

    An empty answer is never taken as either: it asks again."""
    import click

    while True:
        text = read(f"{question} Type yes when done, or no to stop").lower()
        if text in YES:
            return
        if text in NO:
            raise click.exceptions.Abort()
        click.echo("  please type yes or no", err=True)


def _direction(v1: float, v2: float) -> str:
    """'forward', 'left', 'backward and right' ... of a planar displacement (robot frame)."""
    parts = []
    if abs(v1) >= 0.25 * math.hypot(v1, v2):
        parts.append("forward" if v1 > 0 else "backward")
    if abs(v2) >= 0.25 * math.hypot(v1, v2):
        parts.append("left" if v2 > 0 else "right")
    return " and ".join(parts) or "nowhere"


def _wheels(u: tuple[float, ...]) -> str:
    if len(set(u)) == 1:
        return f"all four wheels at duty {u[0]:+.2f} ({'forward' if u[0] > 0 else 'backward'})"
    return ", ".join(f"{w} {x:+.2f}" for w, x in zip(WHEELS, u))


def free_path(step: Any, robot: Robot) -> tuple[float, float, float]:
    """Upper-bound path of a ground step with no load and no slip: (farthest distance from the
    start m, net forward m, net left m). Wheel speed u V_batt / k_e is the no-load speed, so the
    real robot stays within this distance."""
    from omnibench.model.geometry import inverse_kinematics

    R = np.linalg.pinv(inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha))
    x = y = psi = far = 0.0
    ends = [t for t, _ in step.schedule[1:]] + [step.duration]
    for (t0, u), t1 in zip(step.schedule, ends):
        v = R @ (np.asarray(u) * robot.V_batt / robot.k_e)
        n = max(int((t1 - t0) / 0.02), 1)
        dt = (t1 - t0) / n
        for _ in range(n):
            x += (math.cos(psi) * v[0] - math.sin(psi) * v[1]) * dt
            y += (math.sin(psi) * v[0] + math.cos(psi) * v[1]) * dt
            psi += v[2] * dt
            far = max(far, math.hypot(x, y))
    return far, x, y


def describe_motion(step: Any, robot: Robot) -> str:
    """One line: what moves in `step`, which way and how far (or for how long in the air)."""
    u0 = step.schedule[0][1]
    if step.world.mode == "upside_down":
        return (f"Next: the wheels spin in the air (robot upside down), {_wheels(u0)}, "
                f"for at most {step.duration:.0f} s")
    far, x, y = free_path(step, robot)
    if step.kind == "trajectory" and far < 0.05:
        return (f"Next: the robot turns in place ({step.params.get('trajectory', 'a trajectory')!r}) for "
                f"{step.duration:.1f} s: keep the space around it clear")
    if step.kind == "trajectory":
        return (f"Next: the robot drives {step.params.get('trajectory', 'a trajectory')!r} "
                f"({step.params.get('trajectory_kind', '')}) for {step.duration:.1f} s and may go up to "
                f"{far:.1f} m from the start mark: keep that space clear")
    return (f"Next: the robot drives {_direction(x, y)} ({_wheels(u0)}) for {step.duration:.1f} s: "
            f"up to {far:.2f} m")
