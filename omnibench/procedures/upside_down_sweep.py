"""III.i upside-down sweep: the robot on its back, each wheel set, direction and duty held until
the wheel speeds are steady."""

from __future__ import annotations

from typing import TYPE_CHECKING

from omnibench.procedures.plan import (
    DIRECTIONS,
    MAX_MASS_KG,
    Plan,
    ProcedureFile,
    Step,
    World,
    duty_levels,
    telemetry_settings,
    top_keys,
)

if TYPE_CHECKING:
    from omnibench.model.robot import Robot


def expand(pf: ProcedureFile, robot: Robot) -> Plan:
    """III.i: robot upside down; for each wheel set, each direction, each level: hold the duty
    on all four wheels until every wheel speed is steady (see `steady_state`), record it."""
    top_keys(pf, ["sweep", "wheel_sets", "steady_state", "rest"])
    sw = pf.table("sweep")
    pf.check_keys("sweep", sw, ["duties", "voltages", "directions", "order"])
    levels, given_as = duty_levels(pf, "sweep", sw, robot)
    directions = pf.choices("sweep", sw, "directions", list(DIRECTIONS), ["forward", "backward"])
    order = sw.get("order", "ascending")
    if order not in ("ascending", "descending", "as_given"):
        pf.fail("sweep", "order", f"expected ascending, descending or as_given, got {order!r}")
    if order == "ascending":
        levels = sorted(levels)
    elif order == "descending":
        levels = sorted(levels, reverse=True)
    sets_raw = pf.data.get("wheel_sets", [{"name": "standard"}])
    if not isinstance(sets_raw, list) or not sets_raw:
        pf.fail(None, "wheel_sets", "expected one or more [[wheel_sets]] tables")
    wheel_sets = []
    for ws in sets_raw:
        if not isinstance(ws, dict):
            pf.fail(None, "wheel_sets", "each [[wheel_sets]] must be a table")
        pf.check_keys("wheel_sets", ws, ["name", "wheel_mass"])
        name = ws.get("name")
        if not isinstance(name, str) or not name:
            pf.fail("wheel_sets", "name", "each wheel set needs a name")
        raw = ws.get("wheel_mass")
        if raw is None:
            masses = tuple(robot.wheel_mass)
        elif isinstance(raw, list):
            if len(raw) != 4:
                pf.fail("wheel_sets", "wheel_mass", "give one mass or four (FL, FR, RL, RR)")
            masses = tuple(pf.convert("wheel_sets", "wheel_mass", v, "kg", lo=0, lo_open=True, hi=MAX_MASS_KG) for v in raw)
        else:
            m = pf.convert("wheel_sets", "wheel_mass", raw, "kg", lo=0, lo_open=True, hi=MAX_MASS_KG)
            masses = (m, m, m, m)
        wheel_sets.append((name, masses))
    ss = pf.table("steady_state", required=False)
    pf.check_keys("steady_state", ss, ["window", "confidence", "noise_factor", "relative_tolerance",
                                       "min_hold", "max_hold", "average"])
    steady = {
        "window": pf.quantity("steady_state", ss, "window", "s", 0.3, lo=0.02, lo_open=True),
        "confidence": pf.quantity("steady_state", ss, "confidence", "1", 0.95, lo=0.5, hi=0.9999),
        "noise_factor": pf.quantity("steady_state", ss, "noise_factor", "1", 2.0, lo=0, lo_open=True),
        "relative_tolerance": pf.quantity("steady_state", ss, "relative_tolerance", "1", 0.01, lo=0),
        "min_hold": pf.quantity("steady_state", ss, "min_hold", "s", 0.2, lo=0),
        "max_hold": pf.quantity("steady_state", ss, "max_hold", "s", 5.0, lo=0, lo_open=True, hi=3600),
        "average": pf.quantity("steady_state", ss, "average", "s", 0.3, lo=0.02, lo_open=True),
    }
    if steady["max_hold"] < steady["min_hold"] + max(steady["window"], steady["average"]):
        pf.fail("steady_state", "max_hold", "must be at least min_hold + window (and min_hold + average)")
    rest_t = pf.table("rest", required=False)
    pf.check_keys("rest", rest_t, ["between_levels", "between_directions"])
    rest_levels = pf.quantity("rest", rest_t, "between_levels", "s", 0.0, lo=0)
    rest_dirs = pf.quantity("rest", rest_t, "between_directions", "s", 0.5, lo=0)
    steps: list[Step] = []
    for set_name, masses in wheel_sets:
        world = World("upside_down", set_name, masses, 0.0)
        for dname in directions:
            sgn = DIRECTIONS[dname]
            for n, u in enumerate(levels):
                duty = sgn * u
                steps.append(Step(
                    index=len(steps), kind="hold",
                    label=f"{set_name} {dname} duty {duty:+.3f} ({duty * robot.V_batt:+.2f} V)",
                    world=world,
                    params={"wheel_set": set_name, "direction": int(sgn), "duty": duty,
                            "voltage": duty * robot.V_batt,
                            **{f"u{j + 1}": duty for j in range(4)},
                            **{f"wheel_mass{j + 1}": masses[j] for j in range(4)}},
                    schedule=[(0.0, (duty, duty, duty, duty))],
                    duration=steady["max_hold"],
                    settle=rest_dirs if n == 0 else rest_levels,
                ))
    return Plan("upside_down_sweep", pf.path, pf.text, steps,
                {**telemetry_settings(pf), "steady_state": steady, "levels_given_as": given_as})
