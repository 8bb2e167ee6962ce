"""A gain that differs between measurement days: each run's own supply voltage, re-estimated
where the run did not log it.

The 2019 logs carry no battery voltage, and their sessions disagree (the square-wave session
runs slower at the same duty than the sweep session). Pooling them under one nominal supply
makes the fit move a and b to split the difference, which then mispredicts every session.
`fit_with_run_supplies` fits the model's shared parameters and, for every other run with no
logged supply, its own V_batt (block by block: shared parameters with the supplies held, then
each run's supply with the model held; twice). A reference run (the one with the most steady
states, i.e. the sweep; it keeps the robot file's V_batt) fixes the scale, or friction a, b held
at values measured elsewhere (the sweep): otherwise the supplies are not separable from a and b
and are not fitted. A held-out run has no fitted
supply: it is predicted at the robot file's value.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from omnibench.analysis.observations import Observations

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

ITERATIONS = 2


@dataclass
class SupplyFit:
    """The shared fit (fitting.FitResult) and each run's re-estimated supply (V, SE)."""

    fit: Any
    supplies: dict[str, tuple[float, float]]
    reference: str | None


def reference_run(obs: Observations) -> str | None:
    """The run that fixes the supply scale: the sweep run with the most steady states."""
    if not len(obs.sweep):
        return None
    counts = obs.sweep.groupby("run").size()
    return str(counts.idxmax())


def _unlogged(obs: Observations) -> list[str]:
    return [r for r in obs.run_ids if not math.isfinite(float(obs.runs.get(r, {}).get("V_batt", float("nan"))))]


def fit_with_run_supplies(robot: Robot, obs: Observations, free: Sequence[str], procedures: Sequence[str], *,
                          max_nfev: int = 30) -> SupplyFit:
    """Shared parameters `free` and each unlogged run's supply (module docstring). `obs` is not
    changed: the supplies are applied to a copy of its run facts."""
    from omnibench.analysis.fitting import fit

    ref = reference_run(obs)
    work = replace(obs, runs=copy.deepcopy(obs.runs))
    shared = set(free) & {"a", "b", "c", "V_batt"}
    # the scale comes from the reference run, or from friction held at the sweep's values
    runs = [r for r in _unlogged(work) if r != ref] if (ref is not None or not shared) else []
    supplies: dict[str, tuple[float, float]] = {}
    res = fit(robot, work, list(free), procedures=procedures, max_nfev=max_nfev)
    for _ in range(ITERATIONS if runs else 0):
        for r in runs:
            one = work.select(runs=[r])
            one.runs[r] = {**one.runs[r], "V_batt": float("nan")}
            procs = [p for p in procedures if len(one.table(p))]
            start = res.robot.replace(V_batt=supplies.get(r, (robot.V_batt, 0.0))[0])
            rr = fit(start, one, ["V_batt"], procedures=procs, max_nfev=max_nfev)
            supplies[r] = (float(rr.values["V_batt"]), float(rr.se["V_batt"]))
            work.runs[r]["V_batt"] = supplies[r][0]
        res = fit(res.robot, work, list(free), procedures=procedures, max_nfev=max_nfev)
    return SupplyFit(res, supplies, ref)
