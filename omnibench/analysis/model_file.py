"""Model files: the robot file with the fitted values, plus a [fit] table saying how good they are.

A model file is a robot TOML (omnibench/model/omnibot.toml layout, SI numbers, from
`Robot.to_toml_dict`) followed by::

    [fit]
    date = "2026-11-21T12:00:00Z"
    tool = "omnibench 0.1.0"
    runs = ["runs/upside_down_sweep-...", ...]
    procedures = ["sweep", "forward", "lateral"]
    chi2 = 235.5
    dof = 399
    condition_number = 82.6
    [fit.parameters.a]
    value = 0.0199
    se = 2.9e-05
    ci95 = [0.01989, 0.02001]
    unit = "N m s/rad"
    verdict = "identified"        # identified | conditional | consistent with zero | model inadequate
                                  # | at bound | not identifiable (fitting.Verdict)
    reason = "..."

Effect parameters are written with their dotted name quoted ([fit.parameters."stribeck_friction.b_s"]).
`load_model(path)` returns (Robot, fit_info) and strips [fit] before the robot loader sees it,
so any robot file is also a valid model file (fit_info is then empty).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import tomli_w

from omnibench import __version__
from omnibench.errors import UserError
from omnibench.files import MARKER, read_toml, write_atomic
from omnibench.model.robot import Robot, robot_from_dict


def _finite(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(float(x)) else None


def fit_table(result: Any, runs: list[str] | None = None) -> dict[str, Any]:
    """The [fit] table of a FitResult (TOML has no NaN: unknown numbers are left out)."""
    params: dict[str, Any] = {}
    for row in result.summary_rows():
        entry: dict[str, Any] = {"unit": row["unit"], "verdict": row["verdict"], "reason": row["reason"],
                                 "identifiable": bool(row["identifiable"])}
        for key, val in (("value", row["value"]), ("se", row["se"])):
            v = _finite(val)
            if v is not None:
                entry[key] = v
        lo, hi = (_finite(x) for x in row["ci95"])
        if lo is not None and hi is not None:
            entry["ci95"] = [lo, hi]
        params[row["name"]] = entry
    out: dict[str, Any] = {
        "date": result.date, "tool": f"omnibench {__version__}", "runs": list(runs or result.runs_used),
        "procedures": list(result.procedures), "dof": int(result.dof), "parameters": params,
    }
    for key in ("chi2", "condition_number", "s2"):
        v = _finite(getattr(result, key))
        if v is not None:
            out[key] = v
    if result.notes:
        out["notes"] = list(result.notes)
    if getattr(result, "digest", ""):
        from omnibench.analysis.fitting import robot_digest

        # what the fit saw and wrote: diagnose on the same runs need not fit this model again
        out["fitted"] = list(result.fitted)
        out["digest"] = result.digest
        out["robot_digest"] = robot_digest(result.robot)
    return out


def write_model(path: str | Path, result: Any, runs: list[str] | None = None, *,
                per_wheel: dict[int, Any] | None = None) -> Path:
    """Write the fitted robot and its [fit] table to `path` (TOML). `per_wheel`: optional per-wheel
    sweep fits, stored as [fit.per_wheel.<n>] tables (information; the robot keeps one a, b, c)."""
    p = Path(path)
    data = result.robot.to_toml_dict()
    data["fit"] = fit_table(result, runs)
    if per_wheel:
        data["fit"]["per_wheel"] = {str(j): fit_table(r, runs)["parameters"] for j, r in per_wheel.items()}
    header = (f"{MARKER} {__version__}: a model file, the robot file with fitted coefficients (SI units)\n"
              "# and, in [fit], their standard errors, 95 % intervals, identifiability verdicts and the runs used.\n")
    return write_atomic(p, header + tomli_w.dumps(data), "model file")


def load_model(path: str | Path) -> tuple[Robot, dict[str, Any]]:
    """Read a model file (or a plain robot file): (Robot, the [fit] table or {})."""
    p = Path(path)
    data, text = read_toml(p, "model file")
    info = data.get("fit", {})
    if not isinstance(info, dict):
        raise UserError(f"{p}: [fit] must be a table")
    return robot_from_dict(data, path=str(p), text=text), info
