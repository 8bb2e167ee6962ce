"""The adaptive campaign: plan, run, fit, re-plan until every target SE is met or the budget
(robot minutes, operator actions) is spent.

Each round fits all data so far, plans the whole remaining design from that fit
(omnibench.analysis.design), and runs only its first block in one pose (up to the next flip):
the flip is where the operator is busy anyway, and re-planning there uses the newest data.
The first time a procedure runs, only a pilot (the best-ranked half of its steps, half the
repetitions) is run: its fit measures the noise the plan assumed (each observation group's
chi^2/dof), so the rest is planned with the noise the robot actually has.

`adaptive_loop` is independent of how steps are executed: `execute(files)` runs procedure
files and returns their Observations (the campaign runs them through the runner on a port;
benchmarks/design.py simulates them). Every decision is passed to `log` (the campaign writes
it into each run's events and the report).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from omnibench.analysis.design.files import diagnostic_floor, space_from_files, write_procedures
from omnibench.analysis.design.planner import Design, Unit, parse_targets, plan, target_se
from omnibench.analysis.design.space import REST, Costs, Limits, Space, sequence_actions, world_actions
from omnibench.bench.procedure import World
from omnibench.errors import UserError

MAX_ROUNDS = 10
PILOT = 0.5


@dataclass
class Round:
    """One plan-run-fit round: what was planned, what ran, what the fit then said."""

    index: int
    planned: dict[str, Any]
    ran: list[str]
    files: list[str]
    robot_seconds: float  # cumulative, the cost model's
    actions: dict[str, int]  # cumulative
    se: dict[str, float] = field(default_factory=dict)  # fitted SE after the round
    expected_se: dict[str, float] = field(default_factory=dict)  # the plan's prediction for its whole design
    block_expected_se: dict[str, float] = field(default_factory=dict)  # prediction for the block that ran


@dataclass
class AdaptiveResult:
    rounds: list[Round]
    targets: dict[str, float]
    met: bool
    stop_reason: str
    fit: Any
    refused: dict[str, str]
    obs: Any
    initial_se: dict[str, float] = field(default_factory=dict)

    @property
    def robot_seconds(self) -> float:
        return self.rounds[-1].robot_seconds if self.rounds else 0.0

    @property
    def actions(self) -> dict[str, int]:
        return self.rounds[-1].actions if self.rounds else {}

    @property
    def operator_actions(self) -> int:
        return int(sum(self.actions.values()))


def first_block(units: list[Unit]) -> list[Unit]:
    """The units up to the first change of pose (the next flip)."""
    if not units:
        return []
    mode = units[0].candidate.world.mode
    out = []
    for u in units:
        if u.candidate.world.mode != mode:
            break
        out.append(u)
    return out


def pilot(units: list[Unit], have: set[str], required: list[Any] = ()) -> list[Unit]:
    """For procedures without data yet: the best-ranked half of their units, half the repetitions
    (in the units' run order); `required` candidates (the diagnostic floor) always run in full."""
    keep: dict[int, int] = {id(u): u.reps for u in units if u.candidate in required}
    for proc in dict.fromkeys(u.candidate.procedure for u in units):
        us = [u for u in units if u.candidate.procedure == proc and id(u) not in keep]
        if proc in have:
            keep.update({id(u): u.reps for u in us})
        else:
            for u in sorted(us, key=lambda u: u.rank)[:max(1, math.ceil(PILOT * len(us)))]:
                keep[id(u)] = max(1, math.ceil(PILOT * u.reps))
    return [Unit(u.candidate, keep[id(u)], u.rank) for u in units if id(u) in keep]


def _fit(robot: Any, obs: Any, previous: Any = None) -> Any:
    """The fit of all data so far, started from the previous round's values (None if it fails)."""
    from omnibench.analysis.fitting import fit

    if obs is None:
        return None
    try:
        return fit(previous.robot if previous is not None else robot, obs)
    except UserError:
        return None


def adaptive_loop(robot: Any, targets: Mapping[str, tuple[float, bool]], files: Mapping[str, Path],
                  execute: Callable[[list[tuple[str, Path]], int], Any], folder: Path, *,
                  costs: Costs = Costs(), limits: Limits = Limits(), current: bool = True,
                  budget_seconds: float = math.inf, budget_actions: float = math.inf,
                  log: Callable[[str, dict[str, Any]], None] = lambda kind, rec: None,
                  max_rounds: int = MAX_ROUNDS, space: Space | None = None) -> AdaptiveResult:
    """Plan, run (`execute(files, round) -> Observations`), fit, re-plan; see the module doc."""
    from omnibench.analysis.observations import Observations

    space = space or space_from_files(robot, files, limits)
    floor = diagnostic_floor(robot, files, space)
    obs = None
    res = None
    world: World | None = None
    spent_s = 0.0
    acts = {"flip": 0, "wheels": 0, "payload": 0, "measure": 0}
    rounds: list[Round] = []
    refused: dict[str, str] = {}
    reason = f"stopped after {max_rounds} rounds"
    met = False
    initial_se: dict[str, float] = {}
    for r in range(1, max_rounds + 2):
        res = _fit(robot, obs, res)
        se = {p: (res.se.get(p, math.inf) if res is not None else math.inf) for p in targets}
        values = res.values if res is not None else {}
        tabs = target_se(targets, {p: values.get(p, _value(robot, p)) for p in targets})
        if rounds:
            rounds[-1].se = {p: _finite(v) for p, v in se.items()}
        else:
            initial_se = dict(se)
        live = [p for p in targets if p not in refused]
        if res is not None and live and all(se[p] <= tabs[p] for p in live):
            met, reason = True, "every target met"
            break
        if r > max_rounds:
            break
        n_acts = sum(acts.values())
        if spent_s >= budget_seconds or n_acts >= budget_actions:
            reason = "budget spent"
            break
        have = set(obs.procedures()) if obs is not None else set()
        design = plan(robot, res, targets, space, costs, current=current, start=world,
                      budget_seconds=budget_seconds - spent_s, budget_actions=budget_actions - n_acts,
                      required=[c for c in floor if c.procedure not in have])
        refused.update(design.refused)
        if not design.units:
            reason = "the plan adds nothing (targets refused or out of reach within the budget)"
            log("design_stop", {"round": r, "why": reason, "notes": design.notes})
            break
        if "sweep" not in have and any(u.candidate.procedure == "sweep" for u in design.units):
            # the paper's order: the ground runs' fit needs a, b, c (held at their file values otherwise)
            block = pilot([u for u in design.units if u.candidate.procedure == "sweep"], have, floor)
        else:
            block = pilot(first_block(design.units), have, floor)
        written = write_procedures(block, files, folder / f"round-{r:02d}", robot, seed=r)
        block_design = _block_prediction(robot, res, targets, space, costs, current, world, block)
        rec = {"round": r, "why": "largest drop of the weighted A-criterion per second of cost",
               "fit_se": {p: _finite(v) for p, v in se.items()}, "targets": tabs,
               "plan": design.to_json(), "runs_now": [u.candidate.label + f" x{u.reps}" for u in block],
               "expected_se_after_block": {p: _finite(block_design.get(p, math.inf)) for p in targets},
               "files": [str(p) for _, p in written]}
        log("design_round", rec)
        new = execute(written, r)
        obs = new if obs is None else Observations.concat([obs, new])
        worlds = [u.candidate.world for u in block for _ in range(u.reps)]
        a = sequence_actions(worlds, sum(u.candidate.measurements * u.reps for u in block), world, end=None)
        for k, n in a.items():
            acts[k] += n
        world = worlds[-1]
        spent_s += sum(u.candidate.robot_seconds * u.reps for u in block) + sum(
            2 * space.sweep_rest for _, p in written if "sweep" in p.name)
        rounds.append(Round(index=r, planned=design.to_json(), ran=rec["runs_now"], files=rec["files"],
                            robot_seconds=spent_s, actions=dict(acts),
                            expected_se={p: _finite(design.se_after.get(p, math.inf)) for p in targets},
                            block_expected_se=rec["expected_se_after_block"]))
    if rounds and world is not None:  # the campaign leaves the robot as it found it
        for k, n in world_actions(world, REST).items():
            rounds[-1].actions[k] += n
    final = AdaptiveResult(rounds=rounds, targets=tabs, met=met, stop_reason=reason, fit=res, refused=refused,
                           obs=obs, initial_se=initial_se)
    log("design_end", {"met": met, "why": reason, "robot_seconds": final.robot_seconds,
                       "operator_actions": final.operator_actions, "refused": refused})
    return final


def _block_prediction(robot: Any, res: Any, targets: Any, space: Space, costs: Costs, current: bool,
                      world: World | None, block: list[Unit]) -> dict[str, float]:
    """Expected SE after only `block` runs (the design's information restricted to it)."""
    import numpy as np

    from omnibench.analysis.design.information import candidate_information, prior_information
    from omnibench.analysis.design.planner import _se, planning_names

    model = res.robot if res is not None else robot
    names = planning_names(model, current)
    ci = candidate_information(model, [u.candidate for u in block], names, current=current,
                               group_s2=res.group_s2 if res is not None else None)
    M = prior_information(res, names, ci.scale) + np.einsum("k,kij->ij", np.array([u.reps for u in block], float),
                                                             ci.info)
    return dict(zip(names, _se(M, ci.scale)))


def _finite(v: float) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


def _value(robot: Any, p: str) -> float:
    from omnibench.analysis.fitting import param_value

    return param_value(robot, p)
