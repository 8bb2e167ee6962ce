"""IV energy trajectories: named open-loop trajectories with the battery current logged."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from omnibench.procedures.plan import (
    MAX_MASS_KG,
    Plan,
    ProcedureFile,
    Step,
    World,
    body_velocity_duties,
    operator_settings,
    telemetry_settings,
    top_keys,
)

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

TRAJECTORY_KINDS = ("square", "circle", "figure_eight", "spin", "segments")


def trajectory_segments(pf: ProcedureFile, tr: dict[str, Any]) -> list[tuple[float, np.ndarray]]:
    """Body-velocity segments [(duration s, (v1, v2, psi_dot))] of one named trajectory.

    square: four sides driven without turning (forward, left, back, right), side/speed each.
    circle: forward at `speed` while turning at speed/radius: one lap.
    figure_eight: one lap turning left, one turning right.
    spin: turn in place at `yaw_rate` for `duration`.
    segments: explicit list of {v1, v2, psi_dot, duration}.
    """
    kind = tr.get("kind")
    sec = "trajectories"
    if kind not in TRAJECTORY_KINDS:
        pf.fail(sec, "kind", f"expected one of {', '.join(TRAJECTORY_KINDS)}, got {kind!r}")
    allowed = {"square": ["side", "speed"], "circle": ["radius", "speed"],
               "figure_eight": ["radius", "speed"], "spin": ["yaw_rate", "duration"],
               "segments": ["segments"]}[kind]
    pf.check_keys(sec, tr, ["name", "kind", *allowed])
    if kind == "square":
        side = pf.quantity(sec, tr, "side", "m", None, lo=0, lo_open=True)
        v = pf.quantity(sec, tr, "speed", "m/s", None, lo=0, lo_open=True)
        T = side / v
        return [(T, np.array(d)) for d in ([v, 0, 0], [0, v, 0], [-v, 0, 0], [0, -v, 0])]
    if kind in ("circle", "figure_eight"):
        radius = pf.quantity(sec, tr, "radius", "m", None, lo=0, lo_open=True)
        v = pf.quantity(sec, tr, "speed", "m/s", None, lo=0, lo_open=True)
        T = 2 * math.pi * radius / v
        laps = [1.0] if kind == "circle" else [1.0, -1.0]
        return [(T, np.array([v, 0.0, s * v / radius])) for s in laps]
    if kind == "spin":
        w = pf.quantity(sec, tr, "yaw_rate", "rad/s", None)
        T = pf.quantity(sec, tr, "duration", "s", None, lo=0, lo_open=True)
        return [(T, np.array([0.0, 0.0, w]))]
    segs = tr.get("segments")
    if not isinstance(segs, list) or not segs:
        pf.fail(sec, "segments", "expected a list of {v1, v2, psi_dot, duration}")
    out = []
    for s in segs:
        if not isinstance(s, dict):
            pf.fail(sec, "segments", "each segment must be a table {v1, v2, psi_dot, duration}")
        pf.check_keys(sec, s, ["v1", "v2", "psi_dot", "duration"])
        out.append((pf.quantity(sec, s, "duration", "s", None, lo=0, lo_open=True),
                    np.array([pf.quantity(sec, s, "v1", "m/s", 0.0), pf.quantity(sec, s, "v2", "m/s", 0.0),
                              pf.quantity(sec, s, "psi_dot", "rad/s", 0.0)])))
    return out


def expand(pf: ProcedureFile, robot: Robot) -> Plan:
    """IV: named open-loop trajectories on the ground, duties from the body velocities through
    the inverse kinematics; the battery current is logged for the energy balance."""
    top_keys(pf, ["trajectories", "run", "ammeter"])
    run_t = pf.table("run", required=False)
    pf.check_keys("run", run_t, ["repetitions", "settle", "payload"])
    reps = pf.integer("run", run_t, "repetitions", 1, lo=1)
    settle = pf.quantity("run", run_t, "settle", "s", 1.0, lo=0)
    payload = pf.quantity("run", run_t, "payload", "kg", 0.0, lo=0, hi=MAX_MASS_KG)
    am = pf.table("ammeter", required=False)
    pf.check_keys("ammeter", am, ["source", "required"])
    source = am.get("source", "board")
    if source not in ("board",):
        pf.fail("ammeter", "source", "only 'board' (the board's battery current sensor) is supported")
    required = pf.boolean("ammeter", am, "required", False)
    trs = pf.data.get("trajectories")
    if not isinstance(trs, list) or not trs:
        pf.fail(None, "trajectories", "expected [[trajectories]] tables with name and kind")
    world = World("ground", "standard", None, payload)
    names = set()
    expanded = []
    for tr in trs:
        if not isinstance(tr, dict):
            pf.fail(None, "trajectories", "each trajectory must be a table")
        name = tr.get("name")
        if not isinstance(name, str) or not name or name in names:
            pf.fail("trajectories", "name", f"each trajectory needs a unique name, got {name!r}")
        names.add(name)
        expanded.append((name, str(tr.get("kind")), trajectory_segments(pf, tr)))
    steps: list[Step] = []
    for rep in range(reps):
        for name, kind, segs in expanded:
            schedule = []
            t0 = 0.0
            for T, v in segs:
                u = tuple(float(x) for x in body_velocity_duties(robot, v))
                schedule.append((t0, u))
                t0 += T
            steps.append(Step(
                index=len(steps), kind="trajectory",
                label=f"{name} ({kind}, {t0:.1f} s, repetition {rep + 1})", world=world,
                params={"trajectory": name, "trajectory_kind": kind, "duration": t0,
                        "repetition": rep + 1, "payload": payload, "n_segments": len(segs),
                        "segments": [[T, *v.tolist()] for T, v in segs]},
                schedule=schedule, duration=t0, settle=settle, place=True, measure=None,
            ))
    return Plan("energy_trajectories", pf.path, pf.text, steps,
                {**telemetry_settings(pf), "ammeter_required": required, "operator": operator_settings(pf)})
