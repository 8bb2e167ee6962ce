"""The adaptive campaign: plan, run, fit, re-plan until every target SE is met or the budget
(robot minutes, operator actions) is spent.

Each round fits all data so far, plans the whole remaining design from that fit
(omnibench.analysis.design), and runs only its first block in one pose (up to the next flip):
the flip is where the operator is busy anyway, and re-planning there uses the newest data.
The first time a procedure runs, only a pilot (its diagnostic floor, else its planned steps
at half the repetitions) is run: its fit measures the noise the plan assumed (each observation group's
chi^2/dof), so the rest is planned with the noise the robot actually has. Round 1 is the whole
diagnostic floor, the forward pair first where the robot rests (C_r is then measured before the
sweep is topped up); the lateral runs' first visit is the plan for half the information (their
values and noise are guesses until then), made at each prior point of the roller terms (the
file's values, each times and divided by 2) and chosen by its expected cost over all of them. When the floor's fit says the declared model misses
something, the rest of the lab's own grid runs instead of a plan, for diagnose.

With `prior` (the fit of the robot's previous campaign, `campaign --adaptive --prior-runs`) the
noise and values are not guesses: round 1 is planned at the previous fit's values and each
group's chi^2/dof (its data are not counted: the robot may have changed), the whole upside-down
part of that plan runs at once, the lateral runs get no pilot, and every fit starts from the
previous values.

`adaptive_loop` is independent of how steps are executed: `execute(files)` runs procedure
files and returns their Observations (the campaign runs them through the runner on a port;
benchmarks/design.py simulates them). Every decision is passed to `log` (the campaign writes
it into each run's events and the report).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omnibench.analysis.design.files import diagnostic_floor, fixed_grid_units, space_from_files, write_procedures
from omnibench.analysis.design.planner import Unit, parse_targets, plan, target_se
from omnibench.analysis.design.space import REST, Costs, Limits, Space, sequence_actions, world_actions
from omnibench.campaign.run import Analyse
from omnibench.errors import UserError
from omnibench.files import save_figure, write_atomic
from omnibench.locks import holds_out_folder
from omnibench.procedures import World
from omnibench.runs.store import run_dirs

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

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
    # SEs by parameter (None: not finite, not estimated)
    se: dict[str, float | None] = field(default_factory=dict)  # fitted SE after the round
    expected_se: dict[str, float | None] = field(default_factory=dict)  # the plan's prediction for its whole design
    block_expected_se: dict[str, float | None] = field(default_factory=dict)  # prediction for the block that ran


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


def half_information_pilot(block: list[Unit], replan: Callable[[dict[str, tuple[float, bool]]], Any],
                           targets: Mapping[str, tuple[float, bool]]) -> list[Unit]:
    """The lateral runs' first visit: the plan for every target at sqrt(2) x its value (half the
    information), in the current pose. Until they run, the roller terms are planned at the robot
    file's values (a relative target on c_r at half its value asks for 4 x the information) and
    the lateral groups' noise at the forward runs'; half of it measures both, the rest is planned
    with them. (A single pair does not separate a_r from b_r: the pilot must be a design, not a step.)"""
    try:
        half = replan({p: (v * math.sqrt(2.0), rel) for p, (v, rel) in targets.items()})
    except UserError:
        return block
    mode = block[0].candidate.world.mode
    out = [u for u in first_block(half.units) if u.candidate.world.mode == mode]
    return out if any(u.candidate.procedure == "lateral" for u in out) else block


def pilot_over_prior(block: list[Unit], res: Any, obs: Any, targets: Mapping[str, tuple[float, bool]],
                     unmeasured: list[str], replan_at: Callable[[Any, dict[str, tuple[float, bool]]], Any],
                     cost_of: Callable[[list[Unit]], float], current: bool = True) -> list[Unit]:
    """The half-information pilot made at each prior point of the parameters no data have measured
    (omnibench.analysis.design.robust), the one with the least expected cost to meet the targets
    over all the points: cost_of(pilot) x mean over points of max (SE / target)^2. A pilot planned at
    the robot file's guesses alone can be poor at the truth and cost a second round."""
    from omnibench.analysis.design.robust import at_point, expected_repeats_of, prior_points

    if res is None or not unmeasured:
        return half_information_pilot(block, lambda t: replan_at(res, t), targets)
    points = prior_points(res.robot, unmeasured)
    options: list[list[Unit]] = []
    for pt in points:
        def replan_here(t: dict[str, tuple[float, bool]], _r: Any = at_point(res, pt)) -> Any:
            return replan_at(_r, t)

        b = half_information_pilot(block, replan_here, targets)
        if not any(sorted((u.candidate.label, u.reps) for u in b) == sorted((u.candidate.label, u.reps) for u in o)
                   for o in options):
            options.append(b)
    if len(options) == 1:
        return options[0]
    repeats = expected_repeats_of(res, obs, options, targets, unmeasured, points, current)
    return min(zip(options, repeats), key=lambda o: cost_of(o[0]) * o[1])[0]


def pilot(units: list[Unit], have: set[str], required: Sequence[Any] = ()) -> list[Unit]:
    """For procedures without data yet: their `required` candidates (the diagnostic floor) alone
    if the plan has any, else all their units at half the repetitions (a subset of the steps may
    not separate the targets the whole does). The pilot's fit measures the noise; the rest is
    planned with it."""
    keep: dict[int, int] = {}
    for proc in dict.fromkeys(u.candidate.procedure for u in units):
        us = [u for u in units if u.candidate.procedure == proc]
        floor = [u for u in us if u.candidate in required]
        if proc in have:
            keep.update({id(u): u.reps for u in us})
        elif floor:  # the diagnostic floor of this procedure, once, is its pilot
            keep.update({id(u): 1 for u in floor})
        else:  # every step the plan chose (together they separate the targets), at half the repetitions
            keep.update({id(u): max(1, math.ceil(PILOT * u.reps)) for u in us})
    return [Unit(u.candidate, keep[id(u)], u.rank) for u in units if id(u) in keep]


def rest_of_lab_grid(grid: list[Unit], done: Mapping[Any, int], world: World | None,
                     budget_seconds: float = math.inf) -> list[Unit]:
    """The lab's own grid (`fixed_grid_units`) less the pairs already run, the current pose (and
    world) first, within `budget_seconds` of robot time. What the campaign runs when the declared
    model misses something: the planner's information assumes the model, and diagnose is
    validated on the lab's grid (benchmarks/diagnose.py). A sweep level run at another averaging
    time (the diagnostic floor's) counts as run."""
    def step(c: Any) -> tuple:
        return (c.procedure, c.world, c.duty, c.heading, c.speed, None if c.procedure == "sweep" else c.duration)

    ran: dict[tuple, int] = {}
    for c, n in done.items():
        ran[step(c)] = ran.get(step(c), 0) + n
    left = [Unit(u.candidate, u.reps - ran.get(step(u.candidate), 0), u.rank) for u in grid
            if u.reps > ran.get(step(u.candidate), 0)]
    if world is not None:
        left.sort(key=lambda u: (u.candidate.world.mode != world.mode, u.candidate.world != world, u.rank))
    out, spent = [], 0.0
    for u in left:
        if spent + u.candidate.robot_seconds * u.reps > budget_seconds:
            continue
        spent += u.candidate.robot_seconds * u.reps
        out.append(u)
    return out


def ground_pilot(units: list[Unit], have: set[str], floor: list[Any]) -> list[Unit]:
    """The ground part of the diagnostic floor (one forward pair), run first, where the robot
    starts (on the ground, before the flip to the sweep): the first fit then measures C_r and the
    ground runs' noise together with a, b, c, so the sweep is topped up for C_r at its measured
    value. C_r's SE is limited by a, b, c (the forward runs see C_r together with the wheel
    friction), and more sweep levels (1.1 s each) are its cheapest source; planned at the robot
    file's value, the sweep would buy for a guess, and after the ground block a miss of a few per
    cent costs a flip back."""
    return [Unit(u.candidate, 1, u.rank) for u in units
            if u.candidate in floor and u.candidate.world.mode == "ground" and u.candidate.procedure not in have]


def _calibrated(design: Any, targets: Mapping[str, tuple[float, bool]], se: Mapping[str, float],
                tabs: Mapping[str, float], replan: Callable[[dict[str, tuple[float, bool]]], Any]
                ) -> tuple[Any, Mapping[str, tuple[float, bool]]]:
    """(The plan, the targets it aimed at): the plan again, each unmet target divided by k = fitted SE / the plan's SE of the same data,
    when k > 1. The plan's SE of the data in hand is sqrt(diag (J^T J / s2_g)^-1); the fit's can be
    larger (correlation inflation, a parameter it held fixed), and a plan that thinks a target met
    that the fit does not would add nothing and end the campaign short of it."""
    k = {p: se[p] / design.se_before[p] for p in targets
         if p not in design.refused and math.isfinite(se.get(p, math.inf)) and se[p] > tabs[p]
         and 0 < design.se_before.get(p, math.inf) < se[p]}
    if not k:
        return design, targets
    aims = {p: ((v / k[p]) if p in k else v, rel) for p, (v, rel) in targets.items()}
    return replan(aims), aims


def defer_unmeasured(units: list[Unit], robot: Robot, res: Any, targets: Mapping[str, tuple[float, bool]],
                     refused: Mapping[str, str], se: Mapping[str, float], space: Space, costs: Costs, *,
                     current: bool, start: World | None, floor: list[Any], have: set[str], obs: Any,
                     budget_seconds: float, budget_actions: float,
                     done: Mapping[Any, int] | None = None) -> tuple[list[Unit], list[str]]:
    """The plan's steps with the current pose's part bought only for the targets the data have
    measured; (units, the targets deferred).

    A target on a parameter the data have not estimated yet (the roller terms and C_r before any
    ground run) is planned at the robot file's value and at sensitivities taken there: a guess
    (a relative target at a value 2/3 of the truth asks for 2.25 x the information). What the
    current pose buys cannot be taken back without a flip, while the later poses, which measure
    those parameters, can still buy what they need once their value and noise are known. So the
    current pose's steps are re-planned for the measured targets only, with the later poses'
    planned steps counted as information to come (`plan(given=...)`)."""
    if res is None or not units:
        return units, []
    pose = units[0].candidate.world.mode
    later = [u for u in units if u.candidate.world.mode != pose]
    live = [p for p in targets if p not in refused]
    deferred = [p for p in live if not math.isfinite(se.get(p, math.inf))]
    known = {p: targets[p] for p in live if p not in deferred}
    if not later or not deferred or not known:
        return units, []
    given = [u.candidate for u in later for _ in range(u.reps)]
    try:
        now = plan(robot, res, known, space, costs, current=current, start=start, budget_seconds=budget_seconds,
                   budget_actions=budget_actions,
                   required=[c for c in floor if c.procedure not in have and c not in given],
                   obs=obs, given=given, done=done)
    except UserError:
        return units, []
    here = [u for u in now.units if u.candidate.world.mode == pose]
    return here + later, deferred


def _fit(robot: Robot, obs: Any, previous: Any = None) -> Any:
    """The fit of all data so far, started from the previous round's values (else `robot`'s;
    None if it fails)."""
    from omnibench.analysis.fitting import fit

    if obs is None:
        return None
    try:
        return fit(previous.robot if previous is not None else robot, obs)
    except UserError:
        return None


@dataclass(frozen=True)
class _Setting:
    """What every round of one adaptive campaign shares and never changes."""

    robot: Robot
    targets: Mapping[str, tuple[float, bool]]  #: parameter -> (target SE, relative?)
    files: Mapping[str, Path]  #: the lab's procedure files, by procedure
    folder: Path  #: where each round's procedure files are written
    space: Space  #: the candidate steps the lab's files allow
    floor: list[Any]  #: the diagnostic floor's candidates
    costs: Costs
    current: bool  #: the battery current is logged
    budget_seconds: float  #: robot time, s
    budget_actions: float  #: operator actions
    log: Callable[[str, dict[str, Any]], None]
    prior: Any  #: the previous campaign's FitResult, or None


@dataclass
class _State:
    """What the loop knows between rounds (the data, the fit, where the robot is, what was spent)."""

    obs: Any = None  #: Observations of every block run so far (None before the first)
    res: Any = None  #: the fit of them (None before data, or when the fit failed)
    world: World | None = None  #: the robot's world after the last block
    spent_s: float = 0.0  #: robot time spent, s (the cost model's)
    acts: dict[str, int] = field(default_factory=lambda: {"flip": 0, "wheels": 0, "payload": 0, "measure": 0})
    rounds: list[Round] = field(default_factory=list)
    refused: dict[str, str] = field(default_factory=dict)  #: targets a plan refused, with why
    initial_se: dict[str, float] = field(default_factory=dict)  #: the SEs before round 1
    done: dict[Any, int] = field(default_factory=dict)  #: pairs of each candidate run so far (the repetition cap)
    fell_back: str = ""  #: why the rest of the lab's grid ran instead of a plan (the model misses something)
    floor_checked: bool = False  #: the diagnostic floor's fit was judged for misfit (once)


@dataclass
class _View:
    """One round's reading of the data so far."""

    se: dict[str, float]  #: fitted SE per target (inf: not estimated)
    tabs: dict[str, float]  #: each target as an absolute SE
    pres: Any  #: the fit the plans see (the previous campaign's noise where no data yet)
    have: set[str]  #: procedures with data
    n_acts: int  #: operator actions so far
    live: list[str]  #: the targets no plan had refused when the round began


@dataclass
class _Block:
    """What a round runs: its steps, the design they come from (None: the rest of the lab's grid),
    why, and the targets left to the later poses."""

    units: list[Unit]
    design: Any
    why: str
    deferred: list[str] = field(default_factory=list)


def adaptive_loop(robot: Robot, targets: Mapping[str, tuple[float, bool]], files: Mapping[str, Path],
                  execute: Callable[[list[tuple[str, Path]], int], Any], folder: Path, *,
                  costs: Costs = Costs(), limits: Limits = Limits(), current: bool = True,
                  budget_seconds: float = math.inf, budget_actions: float = math.inf,
                  log: Callable[[str, dict[str, Any]], None] = lambda kind, rec: None,
                  max_rounds: int = MAX_ROUNDS, space: Space | None = None, prior: Any = None) -> AdaptiveResult:
    """Plan, run (`execute(files, round) -> Observations`), fit, re-plan; see the module doc.
    prior: the FitResult of the robot's previous campaign (its values and noise), or None.

    Each round: `_read` (fit all data so far), `_stop` (targets met, rounds or budget spent, the
    lab's grid already run), `_choose` (the block to run: the lab's grid when the model misses
    something, else the plan's first block or a pilot), `_run` (write, execute, account)."""
    space = space or space_from_files(robot, files, limits)
    setting = _Setting(robot, targets, files, folder, space, diagnostic_floor(robot, files, space), costs, current,
                       budget_seconds, budget_actions, log, prior)
    st = _State()
    met, reason = False, f"stopped after {max_rounds} rounds"
    start_robot = prior.robot if prior is not None else robot
    tabs: dict[str, float] = {}
    for r in range(1, max_rounds + 2):
        view = _read(setting, st, start_robot)
        tabs = view.tabs
        stop = _stop(setting, st, view, r, max_rounds)
        if stop is None:
            chosen = _choose(setting, st, view, r)
            if isinstance(chosen, _Block):
                _run(setting, st, view, chosen, r, execute)
                continue
            stop = chosen
        met = stop == _MET
        reason = stop or reason
        break
    return _finish(setting, st, tabs, met, reason)


_MET = "every target met"


def _read(s: _Setting, st: _State, start_robot: Robot) -> _View:
    """Fit all data so far (from the last fit's values) and read the SEs against the targets."""
    st.res = _fit(start_robot, st.obs, st.res)
    pres = _with_prior_noise(st.res, s.prior)  # what the plans see: the previous campaign's noise where no data yet
    se = {p: (st.res.se.get(p, math.inf) if st.res is not None else math.inf) for p in s.targets}
    values = st.res.values if st.res is not None else {}
    tabs = target_se(s.targets, {p: values.get(p, _value(s.robot, p)) for p in s.targets})
    if st.rounds:
        st.rounds[-1].se = {p: _finite(v) for p, v in se.items()}
    else:
        st.initial_se = dict(se)
    have: set[str] = set(st.obs.procedures()) if st.obs is not None else set()
    return _View(se, tabs, pres, have, sum(st.acts.values()), [p for p in s.targets if p not in st.refused])


def _stop(s: _Setting, st: _State, view: _View, r: int, max_rounds: int) -> str | None:
    """Why the campaign ends before round `r` plans ("" to end with the default reason), else None."""
    if st.res is not None and view.live and all(view.se[p] <= view.tabs[p] for p in view.live):
        return _MET
    if r > max_rounds:
        return ""
    if st.spent_s >= s.budget_seconds or view.n_acts >= s.budget_actions:
        return "budget spent"
    if st.fell_back:
        return st.fell_back
    return None


def _choose(s: _Setting, st: _State, view: _View, r: int) -> _Block | str:
    """The block round `r` runs, or why the campaign ends (the plan adds nothing, no grid left)."""
    misfit: list[str] = []
    if not st.floor_checked and st.res is not None and all(c.procedure in view.have for c in s.floor):
        # judged once, on the diagnostic floor (one pair per level, made for diagnosis): later rounds
        # repeat levels, and identical levels whose residuals agree read as structure to the fit
        st.floor_checked = True
        misfit = st.res.misses_something()
    if misfit:
        return _lab_grid_block(s, st, misfit, r)
    if s.prior is not None and st.res is None:  # round 1 from the previous campaign's values and noise
        return _prior_block(s, st, view, r)
    return _planned_block(s, st, view, r)


def _lab_grid_block(s: _Setting, st: _State, misfit: list[str], r: int) -> _Block | str:
    """The declared model misses something: the rest of the lab's own grid, for diagnose."""
    grid = fixed_grid_units(s.robot, s.files)
    rests = 2 * s.space.sweep_rest * len({u.candidate.world for u in grid if u.candidate.procedure == "sweep"})
    units = rest_of_lab_grid(grid, st.done, st.world, s.budget_seconds - st.spent_s - rests)
    st.fell_back = (f"the declared model misses something ({'; '.join(misfit)}): a plan from its information "
                    "would be a fiction, so the rest of the lab's own grid ran, for omnibench diagnose; declare "
                    "what it finds and plan again")
    if not units:
        return st.fell_back
    s.log("design_misfit", {"round": r, "why": st.fell_back, "misses": misfit})
    return _Block(units, None, st.fell_back)


def _nothing_to_add(s: _Setting, design: Any, r: int) -> str:
    reason = "the plan adds nothing (targets refused or out of reach within the budget)"
    s.log("design_stop", {"round": r, "why": reason, "notes": design.notes})
    return reason


def _prior_block(s: _Setting, st: _State, view: _View, r: int) -> _Block | str:
    """Round 1 planned at the previous campaign's values and noise: the ground pilot, then the
    whole upside-down part of that plan."""
    design = _plan_from_prior(s.prior, s.targets, s.space, s.costs, current=s.current, start=st.world,
                              budget_seconds=s.budget_seconds - st.spent_s,
                              budget_actions=s.budget_actions - view.n_acts, required=s.floor)
    st.refused.update(design.refused)
    if not design.units:
        return _nothing_to_add(s, design, r)
    units = ground_pilot(design.units, view.have, s.floor) + [u for u in design.units
                                                              if u.candidate.world.mode == "upside_down"]
    return _Block(units, design, "largest drop of the weighted A-criterion per second of cost, at the previous "
                                 "campaign's noise")


def _planned_block(s: _Setting, st: _State, view: _View, r: int) -> _Block | str:
    """The plan from the fit so far (aimed lower where the fit's SE exceeds the plan's), and its
    first block: the sweep's pilot first (with the ground pilot where the robot starts), else the
    current pose's steps for the measured targets, piloted where a procedure has no data yet."""
    have = view.have
    required = [c for c in s.floor if c.procedure not in have]

    def replan(res: Any, aims: Mapping[str, tuple[float, bool]]) -> Any:
        return plan(s.robot, res, aims, s.space, s.costs, current=s.current, start=st.world,
                    budget_seconds=s.budget_seconds - st.spent_s, budget_actions=s.budget_actions - view.n_acts,
                    required=required, obs=st.obs, done=st.done)

    design = replan(view.pres, s.targets)
    design, aims = _calibrated(design, s.targets, view.se, view.tabs, lambda t: replan(view.pres, t))
    st.refused.update(design.refused)
    if not design.units:
        return _nothing_to_add(s, design, r)
    why = "largest drop of the weighted A-criterion per second of cost"
    if "sweep" not in have and any(u.candidate.procedure == "sweep" for u in design.units):
        # the paper's order: the ground runs' fit needs a, b, c (held at their file values otherwise)
        block = pilot([u for u in design.units if u.candidate.procedure == "sweep"], have, s.floor)
        if st.world is None or st.world.mode == "ground":
            block = ground_pilot(design.units, have, s.floor) + block
        return _Block(block, design, why)
    units, deferred = defer_unmeasured(design.units, s.robot, view.pres, aims, st.refused, view.se, s.space, s.costs,
                                       current=s.current, start=st.world, floor=s.floor, have=have, obs=st.obs,
                                       budget_seconds=s.budget_seconds - st.spent_s,
                                       budget_actions=s.budget_actions - view.n_acts, done=st.done)
    block = pilot(first_block(units), have, s.floor)
    if s.prior is None and "lateral" not in have and any(u.candidate.procedure == "lateral" for u in block):
        block = pilot_over_prior(block, view.pres, st.obs, aims,
                                 [p for p in view.live if not math.isfinite(view.se[p])],
                                 replan, lambda b: s.costs.of(_robot_seconds(b), sequence_actions(
                                     [u.candidate.world for u in b for _ in range(u.reps)],
                                     sum(u.candidate.measurements * u.reps for u in b), st.world, end=None)),
                                 s.current)
    return _Block(block, design, why, deferred)


def _robot_seconds(units: list[Unit]) -> float:
    """The robot time of `units`, s (the cost model's)."""
    return sum(u.candidate.robot_seconds * u.reps for u in units)


def _run(s: _Setting, st: _State, view: _View, block: _Block, r: int,
         execute: Callable[[list[tuple[str, Path]], int], Any]) -> None:
    """Write the block's procedure files, log the decision, run them, and account the data, the
    pairs done, the operator's actions, the robot time and the round."""
    from omnibench.analysis.observations import Observations

    units, design, targets = block.units, block.design, s.targets
    written = write_procedures(units, s.files, s.folder / f"round-{r:02d}", s.robot, seed=r)
    block_design = _block_prediction(s.robot, view.pres, st.obs, s.current, units, s.prior)
    rec: dict[str, Any] = {
        "round": r, "why": block.why
        + (f"; in this pose only what {', '.join(p for p in targets if p not in block.deferred and p not in st.refused)} "
           f"need (the later poses measure {', '.join(block.deferred)})" if block.deferred else ""),
        "fit_se": {p: _finite(v) for p, v in view.se.items()}, "targets": view.tabs,
        "plan": design.to_json() if design is not None else None,
        "runs_now": [u.candidate.label + f" x{u.reps}" for u in units],
        "expected_se_after_block": {p: _finite(block_design.get(p, math.inf)) for p in targets},
        "files": [str(p) for _, p in written]}
    s.log("design_round", rec)
    new = execute(written, r)
    st.obs = new if st.obs is None else Observations.concat([st.obs, new])
    for u in units:
        st.done[u.candidate] = st.done.get(u.candidate, 0) + u.reps
    worlds = [u.candidate.world for u in units for _ in range(u.reps)]
    a = sequence_actions(worlds, sum(u.candidate.measurements * u.reps for u in units), st.world, end=None)
    for k, n in a.items():
        st.acts[k] += n
    st.world = worlds[-1]
    st.spent_s += _robot_seconds(units) + sum(2 * s.space.sweep_rest for _, p in written if "sweep" in p.name)
    st.rounds.append(Round(index=r, planned=rec["plan"] or {}, ran=rec["runs_now"], files=rec["files"],
                           robot_seconds=st.spent_s, actions=dict(st.acts),
                           expected_se={p: _finite(design.se_after.get(p, math.inf) if design is not None
                                                   else math.inf) for p in targets},
                           block_expected_se=rec["expected_se_after_block"]))


def _finish(s: _Setting, st: _State, tabs: dict[str, float], met: bool, reason: str) -> AdaptiveResult:
    """The result (the robot put back at rest: the last round counts those actions) and its log line."""
    if st.rounds and st.world is not None:  # the campaign leaves the robot as it found it
        for k, n in world_actions(st.world, REST).items():
            st.rounds[-1].actions[k] += n
    final = AdaptiveResult(rounds=st.rounds, targets=tabs, met=met, stop_reason=reason, fit=st.res,
                           refused=st.refused, obs=st.obs, initial_se=st.initial_se)
    s.log("design_end", {"met": met, "why": reason, "robot_seconds": final.robot_seconds,
                         "operator_actions": final.operator_actions, "refused": st.refused})
    return final


def _with_prior_noise(res: Any, prior: Any) -> Any:
    """`res` with the previous campaign's noise (chi^2/dof and dof) for the groups it has no data
    of yet (the lateral runs before they run), so that their plan is not made at noise lent from
    another group; `res` itself when there is no previous campaign."""
    if res is None or prior is None:
        return res
    import dataclasses

    missing = [g for g in prior.group_s2 if g not in res.group_s2]
    if not missing:
        return res
    return dataclasses.replace(res, group_s2={**res.group_s2, **{g: prior.group_s2[g] for g in missing}},
                               group_dof={**res.group_dof, **{g: prior.group_dof.get(g, 0.0) for g in missing}})


def _plan_from_prior(prior: Any, targets: Mapping[str, tuple[float, bool]], space: Space, costs: Costs, *,
                     current: bool, start: World | None, budget_seconds: float, budget_actions: float,
                     required: list[Any]) -> Any:
    """The whole campaign planned at the previous fit's values and each group's noise, its data
    not counted (the prior alone as information)."""
    from omnibench.analysis.design.information import candidate_information
    from omnibench.analysis.design.planner import planning_names

    info = candidate_information(prior.robot, space.candidates, planning_names(prior.robot, current),
                                 current=current, group_s2=prior.group_s2, group_dof=prior.group_dof)
    return plan(prior.robot, None, targets, space, costs, current=current, start=start,
                budget_seconds=budget_seconds, budget_actions=budget_actions, required=required, info=info)


def _block_prediction(robot: Robot, res: Any, obs: Any, current: bool, block: list[Unit],
                      prior: Any = None) -> dict[str, float]:
    """Expected SE after only `block` runs (the design's information restricted to it; before any
    data at the previous campaign's values and noise when there is one)."""
    import numpy as np

    from omnibench.analysis.design.information import candidate_information, prior_information
    from omnibench.analysis.design.planner import information_se, planning_names

    noise = res if res is not None else prior
    model = noise.robot if noise is not None else robot
    names = planning_names(model, current)
    ci = candidate_information(model, [u.candidate for u in block], names, current=current,
                               group_s2=noise.group_s2 if noise is not None else None,
                               group_dof=noise.group_dof if noise is not None else None)
    M = prior_information(res, names, ci.scale, obs) + np.einsum("k,kij->ij", np.array([u.reps for u in block], float),
                                                             ci.info)
    return dict(zip(names, information_se(M, ci.scale)))


def _finite(v: float) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


def _value(robot: Robot, p: str) -> float:
    from omnibench.analysis.least_squares import param_value

    return param_value(robot, p)


# --------------------------------------------------------------------------- the campaign on a port
def _append_event(run_dir: Path, kind: str, rec: Mapping[str, Any]) -> None:
    """Add a design decision to a finished run's event log (same line format as the runner's)."""
    from omnibench.runs.store import append_event

    append_event(run_dir, kind, **rec)


@holds_out_folder("an adaptive campaign")  # two campaigns never write into one --out
def run_adaptive_campaign(port: str, out: Path, target_text: str, *, robot_file: Path | None = None,
                          procedures_dir: Path | None = None, costs: Costs = Costs(), limits: Limits = Limits(),
                          current: bool = True, budget_minutes: float | None = None,
                          budget_actions: int | None = None, echo: Callable[[str], None] = print,
                          stages: tuple[str, ...] = ("fit", "validate-energy", "diagnose"),
                          energy: bool = True, analyse: "Analyse | None" = None,
                          prior_runs: tuple[Path, ...] = (), ammeter: str | None = None,
                          without_current: bool = False) -> dict[str, Any]:
    """`omnibench campaign --adaptive`: the adaptive loop on `port` through the runner, then the
    energy trajectories, the analysis stages and the report (with the design's rounds).

    analyse: as for `run_campaign` (the command line passes omnibench.campaign.stages.run_analysis).
    prior_runs: run folders of the robot's previous campaign: their fit's values and noise plan
    round 1 (their data are not counted in this campaign's SEs). ammeter: SCPI ammeter URL for
    the energy trajectories' battery current (else the board's sensor); without_current: drive
    them without any (no energy measured)."""
    from omnibench import __version__
    from omnibench.analysis.observations import Observations
    from omnibench.bench.session import load_robot_file, preflight, run_command
    from omnibench.campaign.run import finish_campaign, make_plots, procedure_files, write_report
    from omnibench.procedures import COMMAND_OF
    from omnibench.runs.store import json_ready

    out = Path(out)
    robot, _, _ = load_robot_file(robot_file)
    targets = parse_targets(target_text or "", robot)
    files = procedure_files(procedures_dir)
    space = space_from_files(robot, files, limits)
    if not port:
        raise UserError("no --port given (sim:// for the simulated robot)")
    for name, v in (("--budget-minutes", budget_minutes), ("--budget-actions", budget_actions)):
        if v is not None and not v > 0:
            raise UserError(f"{name} {v}: a budget must be a positive number")
    prior = None
    if prior_runs:
        from omnibench.analysis.fitting import fit
        from omnibench.runs.check import checked_runs

        prior = fit(robot, Observations.from_runs(tuple(checked_runs(prior_runs)), robot))
    runs_dir = out / "runs"
    if run_dirs(runs_dir):
        raise UserError(f"{runs_dir} already holds runs; an adaptive campaign starts in an empty folder (give another --out)")
    if energy:
        from omnibench.procedures import load_plan

        preflight([load_plan(files["energy_trajectories"], robot, expect="energy_trajectories")], port,
                  ammeter=ammeter, without_current=without_current)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    log_path = out / "design.jsonl"
    pending: dict[str, Any] = {}
    results: dict[str, Any] = {"port": port, "out": str(out), "tool_version": __version__,
                               "robot_file": str(robot_file) if robot_file else "default", "procedures": {},
                               "analysis": {}, "runs": [], "status": "running"}
    where = "design round 1"

    def log(kind: str, rec: dict[str, Any]) -> None:
        nonlocal where
        from omnibench.runs.store import dumps

        with open(log_path, "a", encoding="utf-8") as fh:
            fh.write(dumps({"kind": kind, **rec}) + "\n")
        if kind == "design_round":
            where = f"design round {rec['round']}"
            pending.clear()
            pending.update(rec)
            echo(f"== design round {rec['round']}: " + "; ".join(rec["runs_now"]))
        else:
            echo(f"== design: {rec.get('why')}")

    def execute(written: list[tuple[str, Path]], r: int) -> Any:
        nonlocal where
        dirs = []
        for proc, path in written:
            where = COMMAND_OF[proc]
            echo(f"== {proc}: {path}")
            res = run_command(proc, port=port, procedure_file=path, robot_file=robot_file, out=runs_dir, echo=echo,
                              progress=False)
            _append_event(Path(res["run"]), "design", {k: pending.get(k) for k in (
                "round", "why", "fit_se", "targets", "runs_now", "expected_se_after_block", "files")})
            results["procedures"][proc] = res
            results["runs"].append(res["run"])
            dirs.append(res["run"])
            where = f"design round {r}"  # its runs' analysis, the next round's plan
        return Observations.from_runs(dirs, robot)

    try:
        result = adaptive_loop(robot, targets, files, execute, out / "design", costs=costs, limits=limits,
                               current=current, budget_seconds=60 * budget_minutes if budget_minutes else math.inf,
                               budget_actions=budget_actions if budget_actions is not None else math.inf,
                               log=log, space=space, prior=prior)
        if energy:
            where = COMMAND_OF["energy_trajectories"]
            echo("== energy: " + str(files["energy_trajectories"]))
            results["procedures"]["energy_trajectories"] = run_command(
                "energy_trajectories", port=port, procedure_file=files["energy_trajectories"], robot_file=robot_file,
                out=runs_dir, echo=echo, progress=False, ammeter=ammeter, without_current=without_current)
        where = "analysis"
        if analyse is not None:
            analyse(runs_dir, out, robot_file, echo, stages, into=results["analysis"])
    except KeyboardInterrupt:
        # as run_campaign: the runner stopped the motors and marked its run aborted; what finished
        # is written with where it stopped (an adaptive campaign does not resume: the next one
        # plans from these runs)
        where = next((n for n, st in results["analysis"].items() if st.get("status") == "interrupted"), where)
        results.update(status="interrupted", stopped_at=where)
        echo(f"campaign interrupted (Ctrl-C) in {where}: the motors are stopped, the runs and design.jsonl are "
             f"kept in {out}; an adaptive campaign does not resume: plan the next one from these runs with "
             f"--adaptive --prior-runs RUN (each of {runs_dir}) and another --out")
        finish_campaign(results, out, robot, t0, echo, summary=False)
        raise
    results["status"] = "complete"
    results["plots"] = make_plots(results, out, robot)
    summary = design_summary(result, robot, files, space, costs, current)
    summary["prior_runs"] = [str(p) for p in prior_runs]
    results["design"] = summary
    results["plots"]["design"] = design_plot(summary, out / "plots" / "design_se_vs_time.png")
    results["host_seconds"] = time.monotonic() - t0
    report = write_report(results, out, robot)
    with open(report, "a", encoding="utf-8") as fh:
        fh.write("\n" + "\n".join(design_lines(summary, out)) + "\n")
    results["report"] = str(report)
    write_atomic(out / "campaign.json", json.dumps(json_ready(results), indent=2, default=str) + "\n",
                 "campaign summary")
    echo(f"report: {report}")
    return results


def design_summary(result: AdaptiveResult, robot: Robot, files: Mapping[str, Path], space: Space, costs: Costs,
                   current: bool) -> dict[str, Any]:
    """The rounds, and the fixed grid's expected SE against robot time (its information at the
    final fit, in the order the shipped procedures run) for comparison."""
    from omnibench.analysis.design.files import fixed_grid_units
    from omnibench.analysis.design.information import candidate_information, prior_information
    from omnibench.analysis.design.planner import information_se, planning_names

    targets = result.targets
    fixed = fixed_grid_units(robot, files)
    curve: list[dict[str, Any]] = []
    fixed_s = fixed_a = math.nan
    if result.fit is not None:
        model = result.fit.robot
        names = planning_names(model, current)
        ci = candidate_information(model, [u.candidate for u in fixed], names, current=current,
                                   group_s2=result.fit.group_s2, group_dof=result.fit.group_dof)
        M = prior_information(None, names, ci.scale)
        t = 0.0
        seen_rest: set[Any] = set()
        for k, u in enumerate(fixed):
            M = M + u.reps * ci.info[k]
            t += u.reps * u.candidate.robot_seconds
            if u.candidate.procedure == "sweep" and u.candidate.world not in seen_rest:
                seen_rest.add(u.candidate.world)
                t += 2 * space.sweep_rest
            se = dict(zip(names, information_se(M, ci.scale)))
            curve.append({"robot_seconds": t, "se": {p: _finite(se[p]) for p in targets}})
        fixed_s = t
        fixed_a = sum(sequence_actions([u.candidate.world for u in fixed for _ in range(u.reps)],
                                       sum(u.candidate.measurements * u.reps for u in fixed)).values())
    return {"targets": targets, "met": result.met, "stop_reason": result.stop_reason, "refused": result.refused,
            "robot_seconds": result.robot_seconds, "actions": result.actions,
            "operator_actions": result.operator_actions,
            "rounds": [{"round": r.index, "robot_seconds": r.robot_seconds, "actions": r.actions,
                        "operator_actions": int(sum(r.actions.values())), "ran": r.ran, "se": r.se,
                        "expected_se": r.block_expected_se} for r in result.rounds],
            "fixed_grid": {"robot_seconds": fixed_s, "operator_actions": fixed_a, "curve": curve},
            "final_se": {p: _finite(result.fit.se.get(p, math.nan)) if result.fit is not None else None
                         for p in targets}}


def design_plot(summary: Mapping[str, Any], path: Path) -> str:
    """SE / target against robot time: the adaptive rounds (fitted) and the fixed grid (expected)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    targets = summary["targets"]
    for n, p in enumerate(targets):
        color = f"C{n % 10}"
        pts = [(r["robot_seconds"], r["se"].get(p)) for r in summary["rounds"] if r["se"].get(p)]
        if pts:
            ax.plot([x for x, _ in pts], [y / targets[p] for _, y in pts], "o-", color=color, label=f"{p} adaptive")
        cur = [(c["robot_seconds"], c["se"].get(p)) for c in summary["fixed_grid"]["curve"] if c["se"].get(p)]
        if cur:
            ax.plot([x for x, _ in cur], [y / targets[p] for _, y in cur], "--", color=color, lw=0.9, alpha=0.8)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("robot time (s)")
    ax.set_ylabel("SE / target")
    ax.set_title("adaptive (fitted, o-) vs the fixed grid (expected, --)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return str(path)


def design_lines(summary: Mapping[str, Any], out: Path) -> list[str]:
    """Markdown for the report: targets, rounds, the comparison with the fixed grid."""
    fx = summary["fixed_grid"]
    lines = ["## Adaptive design", "",
             f"- stopped: {summary['stop_reason']} after {len(summary['rounds'])} round(s); "
             f"robot time {summary['robot_seconds']:.0f} s, {summary['operator_actions']} operator actions "
             f"({', '.join(f'{k} {v}' for k, v in summary['actions'].items() if v)})",
             f"- the fixed grid (the procedure files as shipped): {fx['robot_seconds']:.0f} s, "
             f"{fx['operator_actions']} operator actions; ratio adaptive / fixed: robot time "
             f"{summary['robot_seconds'] / fx['robot_seconds']:.2f}, operator actions "
             f"{summary['operator_actions'] / max(fx['operator_actions'], 1):.2f}" if fx["robot_seconds"] == fx["robot_seconds"]
             else "- the fixed grid: not priced (no fit)", ""]
    if summary.get("prior_runs"):
        lines.append("- planned from the previous campaign's values and noise (`--prior-runs`, its data not counted): "
                     + ", ".join(f"`{p}`" for p in summary["prior_runs"]))
    for p, why in summary["refused"].items():
        lines.append(f"- refused target {p}: {why}")
    lines += ["", "| parameter | target SE | SE reached |", "|---|---|---|"]
    for p, t in summary["targets"].items():
        lines.append(f"| {p} | {t:.3g} | {_fmt(summary['final_se'].get(p))} |")
    lines += ["", "| round | ran | robot s | actions | " + " | ".join(f"SE {p}" for p in summary["targets"]) + " |",
              "|---|---|---|---|" + "---|" * len(summary["targets"])]
    for r in summary["rounds"]:
        lines.append(f"| {r['round']} | {'; '.join(r['ran'])} | {r['robot_seconds']:.0f} | {r['operator_actions']} | "
                     + " | ".join(_fmt(r["se"].get(p)) for p in summary["targets"]) + " |")
    lines += ["", "Every round's decision (fit SE, plan, expected SE) is in `design.jsonl` and in the events of "
              "the runs it made (`kind = design`).", "",
              "![SE against robot time](plots/design_se_vs_time.png)", ""]
    return lines


def _fmt(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, (int, float)) and math.isfinite(v) else "--"
