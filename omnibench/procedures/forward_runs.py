"""III.ii forward/backward runs: all four wheels at one duty for a fixed time; the operator measures
the distance."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from omnibench.procedures.plan import (
    DIRECTIONS,
    Plan,
    ProcedureFile,
    Step,
    World,
    duty_levels,
    no_slip_settings,
    operator_settings,
    runs_settings,
    telemetry_settings,
    top_keys,
)

if TYPE_CHECKING:
    from omnibench.model.robot import Robot


def expand(pf: ProcedureFile, robot: Robot) -> Plan:
    """III.ii: on the ground, all four wheels at the same duty for a fixed time, forward and
    backward; the operator measures the distance travelled; the encoders' rolling distance
    r * mean(delta phi) is compared with it (the no-slip check: sigma = 0 when driving straight)."""
    top_keys(pf, ["runs", "no_slip"])
    t = pf.table("runs")
    pf.check_keys("runs", t, ["duties", "voltages", "directions", "duration", "repetitions", "settle"])
    levels, given_as = duty_levels(pf, "runs", t, robot)
    directions = pf.choices("runs", t, "directions", list(DIRECTIONS), ["forward", "backward"])
    c = runs_settings(pf, "runs", t)
    world = World("ground", "standard", None, 0.0)
    steps: list[Step] = []
    for rep in range(c["repetitions"]):
        for u in levels:
            for dname in directions:
                duty = DIRECTIONS[dname] * u
                steps.append(Step(
                    index=len(steps), kind="timed",
                    label=f"{dname} at duty {duty:+.3f} for {c['duration']:g} s (repetition {rep + 1})",
                    world=world,
                    params={"direction": int(DIRECTIONS[dname]), "duty": duty, "voltage": duty * robot.V_batt,
                            "duration": c["duration"], "repetition": rep + 1, "payload": 0.0,
                            "heading": 0.0 if duty > 0 else math.pi,
                            **{f"u{j + 1}": duty for j in range(4)}},
                    schedule=[(0.0, (duty, duty, duty, duty))],
                    duration=c["duration"], settle=c["settle"], place=True, measure="distance",
                ))
    return Plan("forward_runs", pf.path, pf.text, steps,
                {**telemetry_settings(pf), "no_slip": no_slip_settings(pf), "operator": operator_settings(pf),
                 "levels_given_as": given_as})
