"""III.iii lateral runs: driving with lateral speed for each payload; the operator measures the
displacement."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from omnibench.procedures.plan import (
    MAX_MASS_KG,
    Plan,
    ProcedureFile,
    Step,
    World,
    body_velocity_duties,
    no_slip_settings,
    operator_settings,
    runs_settings,
    telemetry_settings,
    top_keys,
)

if TYPE_CHECKING:
    from omnibench.model.robot import Robot


def expand(pf: ProcedureFile, robot: Robot) -> Plan:
    """III.iii: on the ground with lateral speed (rollers turn, sigma != 0), for each payload;
    the operator places each weight and measures the displacement (forward, left)."""
    top_keys(pf, ["runs", "directions", "payloads", "no_slip"])
    t = pf.table("runs")
    pf.check_keys("runs", t, ["duration", "repetitions", "settle", "both_ways"])
    c = runs_settings(pf, "runs", t)
    both = pf.boolean("runs", t, "both_ways", True)
    dirs_raw = pf.data.get("directions")
    if not isinstance(dirs_raw, list) or not dirs_raw:
        pf.fail(None, "directions", "expected [[directions]] tables with heading and speed")
    directions = []
    for d in dirs_raw:
        if not isinstance(d, dict):
            pf.fail(None, "directions", "each direction must be a table {heading, speed}")
        pf.check_keys("directions", d, ["heading", "speed"])
        heading = pf.quantity("directions", d, "heading", "rad", None, lo=-2 * math.pi, hi=2 * math.pi)
        speed = pf.quantity("directions", d, "speed", "m/s", None, lo=0, lo_open=True)
        directions.append((heading, speed))
    if "payloads" not in pf.data:
        payloads = [0.0]
    else:
        payloads = pf.quantity_list(None, pf.data, "payloads", "kg", lo=0, hi=MAX_MASS_KG)
    steps: list[Step] = []
    for payload in payloads:
        world = World("ground", "standard", None, payload)
        for rep in range(c["repetitions"]):
            for heading, speed in directions:
                for way in ((1.0, -1.0) if both else (1.0,)):
                    h = heading if way > 0 else heading + math.pi
                    v = np.array([speed * math.cos(h), speed * math.sin(h), 0.0])
                    u = tuple(float(x) for x in body_velocity_duties(robot, v))
                    steps.append(Step(
                        index=len(steps), kind="timed",
                        label=(f"heading {math.degrees(h):+.0f} deg at {speed:g} m/s, payload "
                               f"{payload:g} kg (repetition {rep + 1})"),
                        world=world,
                        params={"heading": h, "speed": speed, "v1": v[0], "v2": v[1], "psi_dot": 0.0,
                                "payload": payload, "duration": c["duration"], "repetition": rep + 1,
                                **{f"u{j + 1}": u[j] for j in range(4)}},
                        schedule=[(0.0, u)], duration=c["duration"], settle=c["settle"],
                        place=True, measure="displacement",
                    ))
    return Plan("lateral_runs", pf.path, pf.text, steps,
                {**telemetry_settings(pf), "no_slip": no_slip_settings(pf), "operator": operator_settings(pf)})
