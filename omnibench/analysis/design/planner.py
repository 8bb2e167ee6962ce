"""Choose the next steps: the most information about the target parameters per unit of cost.

Criterion (weighted A-optimality on the unmet targets): with V the predicted covariance of
the scaled parameters and t_i the target SE of parameter i,

    Phi(M) = sum over targets of max(V_ii / t_i^2, 1),     V = M^-1.

Phi counts each target's squared SE in units of its target and stops caring once a target is
met. The user's request is a list of per-parameter SEs, which is what A-optimality (the trace
of the covariance) measures; D-optimality (det M) would shrink the joint volume, including
nuisance directions (k_e, R_a) and parameters already known well enough, and is blind to
which parameters were asked for. Weighting by 1/t_i^2 makes Phi invariant to units.

Greedy selection: from the information in hand M (fit + weak prior), repeatedly add the
candidate (repeated r = 1, 2, 4 or 8 times, at most MAX_REPS in all) with the largest drop
of Phi per second of cost. Operator actions to reach a world (flip, wheel swap, payload) are
discrete, so the greedy runs once per set of worlds, that set paying its setup up front, and
the cheapest set that meets the targets wins. Stops when every target is predicted met (at
`margin` of it), when no candidate lowers Phi, or at the budget; repetitions later choices
made redundant are then removed. The convex optimum over real repetitions (optimal.py),
rounded to whole pairs (integer parts completed by the greedy, pruned), competes with it; both
are then improved by exchanging pairs for cheaper ones that keep every target met, and the
cheaper design wins. The worlds are ordered to need the fewest actions.

Identifiability: a target the data in hand plus every candidate cannot separate (a null
direction of their information) is refused, with the experiment that would separate it; a
target the fit declared not identifiable is planned only when the candidates do separate it.
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from omnibench.analysis.design.information import (
    PRIOR_SD,
    CandidateInformation,
    candidate_information,
    prior_information,
)
from omnibench.analysis.design.optimal import cheapest_weights
from omnibench.analysis.design.space import (
    ACTION_WORDS,
    Candidate,
    Costs,
    Space,
    sequence_actions,
)
from omnibench.analysis.fitting import RANK_TOL, FitResult
from omnibench.analysis.least_squares import CORE, param_unit, param_value
from omnibench.errors import UserError
from omnibench.procedures import World

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

#: Fraction of each target the plan aims at (SE estimates scatter; aim a little below).
MARGIN = 0.9
REPS = (1, 2, 4, 8)
#: At most this many repetitions of one step per plan: replicated extremes are what an optimal
#: design for a perfect model asks for, but a level's repeats share its model error (any small
#: one), which the fit reads as structure and widens the intervals (fitting.residual_structure);
#: spreading over neighbouring levels keeps the prediction honest and diagnosis informed.
MAX_REPS = 8
#: A parameter whose weight in an invisible direction exceeds this is not separable (a small weight
#: still moves it: with one wheel load only a (1 + c F_N) is seen, a's weight is ~0.1).
NULL_WEIGHT = 0.05


def parse_targets(text: str, robot: Robot) -> dict[str, tuple[float, bool]]:
    """'a=2%,b=0.01' -> {name: (value, relative)}: '2%' is relative to the parameter's value,
    a plain number an absolute SE in SI units. UserError naming the bad item."""
    out: dict[str, tuple[float, bool]] = {}
    for item in [t.strip() for t in (text or "").split(",") if t.strip()]:
        m = re.fullmatch(r"([A-Za-z_][\w.]*)\s*=\s*([0-9.eE+-]+)\s*(%?)", item)
        if not m:
            raise UserError(f"--target-se {item!r}: expected NAME=VALUE% (relative) or NAME=VALUE (SI), e.g. a=2%")
        name, val, pct = m.group(1), m.group(2), m.group(3)
        try:
            v = float(val)
        except ValueError:
            raise UserError(f"--target-se {item!r}: {val!r} is not a number") from None
        if not v > 0 or not math.isfinite(v):
            raise UserError(f"--target-se {item!r}: the target SE must be a positive number")
        param_value(robot, name)  # validates the name
        out[name] = (v / 100.0 if pct else v, bool(pct))
    if not out:
        raise UserError("--target-se: give at least one target, e.g. a=2%,b=1%")
    return out


def target_se(targets: Mapping[str, tuple[float, bool]], values: Mapping[str, float]) -> dict[str, float]:
    """Absolute target SEs (SI) at the current parameter values."""
    return {p: (v * abs(values[p]) if rel else v) for p, (v, rel) in targets.items()}


@dataclass
class Unit:
    """A candidate chosen `reps` times (pairs of steps), with the rank in which it was chosen."""

    candidate: Candidate
    reps: int
    rank: int


@dataclass
class Design:
    """A plan: steps in run order, expected SE before/after, costs, refusals and why."""

    names: list[str]
    values: dict[str, float]
    targets: dict[str, float]  # SI
    se_before: dict[str, float]
    se_after: dict[str, float]
    units: list[Unit]
    robot_seconds: float
    actions: dict[str, int]
    cost: float
    refused: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    conditional: dict[str, str] = field(default_factory=dict)

    @property
    def met(self) -> dict[str, bool]:
        return {p: bool(self.se_after.get(p, math.inf) <= t) for p, t in self.targets.items()}

    @property
    def operator_actions(self) -> int:
        return int(sum(self.actions.values()))

    def table(self, robot: Robot | None = None) -> str:
        """Expected SE before and after the plan, against each target."""
        lines = [f"{'parameter':<22} {'value':>11} {'target SE':>11} {'SE now':>11} {'SE after':>11}  met"]
        for p, t in self.targets.items():
            v = self.values.get(p, math.nan)
            unit = f" {param_unit(robot, p)}" if robot is not None else ""
            if p in self.refused:
                lines.append(f"{p:<22} {v:>11.4g} {t:>11.3g} {'--':>11} {'--':>11}  refused: {self.refused[p]}")
                continue
            b, a = self.se_before.get(p, math.inf), self.se_after.get(p, math.inf)
            lines.append(f"{p:<22} {v:>11.4g} {t:>11.3g} {_fmt(b):>11} {_fmt(a):>11}  "
                         f"{'yes' if a <= t else 'NO'}{unit and ''}"
                         + (f"  ({_fmt(100 * a / abs(v))} % of the value)" if v and math.isfinite(a) else ""))
            if p in self.conditional:
                lines.append(f"    conditional: {self.conditional[p]}")
        acts = ", ".join(f"{n} {k}" for k, n in self.actions.items() if n)
        lines.append(f"plan: {sum(u.reps for u in self.units)} step pairs, {self.robot_seconds:.0f} s of robot time, "
                     f"{self.operator_actions} operator actions ({acts or 'none'}), cost {self.cost / 60:.1f} min")
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        def f(x: float) -> float | None:
            return float(x) if x is not None and math.isfinite(x) else None

        return {"targets": {p: f(t) for p, t in self.targets.items()},
                "values": {p: f(v) for p, v in self.values.items()},
                "se_before": {p: f(v) for p, v in self.se_before.items()},
                "se_after": {p: f(v) for p, v in self.se_after.items()},
                "met": self.met, "refused": self.refused, "conditional": self.conditional,
                "robot_seconds": float(self.robot_seconds), "actions": {k: int(v) for k, v in self.actions.items()},
                "operator_actions": self.operator_actions, "cost_s": float(self.cost), "notes": self.notes,
                "steps": [{"label": u.candidate.label, "procedure": u.candidate.procedure, "pairs": u.reps,
                           "rank": u.rank, "world": u.candidate.world.describe()} for u in self.units]}


def _fmt(x: float) -> str:
    return f"{x:.3g}" if math.isfinite(x) else "inf"


def planning_names(robot: Robot, current: bool = True) -> list[str]:
    """Parameters the fit of a whole campaign estimates (the paper's seven, the motor constants
    the sweep's currents give, every declared effect's): all of them enter the information."""
    names = list(CORE) + (["k_e", "R_a"] if current else [])
    for eff, params in robot.effects.items():
        names += [f"{eff}.{p}" for p in params]
    return names


def _phi(M: np.ndarray, tidx: np.ndarray, t2: np.ndarray) -> float:
    try:
        V = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return math.inf
    d = np.diag(V)[tidx]
    if np.any(d < 0):
        return math.inf
    return float(np.sum(np.maximum(d / t2, 1.0)))


def _null_params(M: np.ndarray, names: Sequence[str]) -> dict[str, dict[str, float]]:
    """Parameters carried by a direction the information M cannot see: {name: combination}."""
    d = np.sqrt(np.maximum(np.diag(M), 0))
    out: dict[str, dict[str, float]] = {}
    zero = d <= 1e-300
    for i in np.flatnonzero(zero):
        out[names[i]] = {names[i]: 1.0}  # type: ignore[call-overload]
    keep = np.flatnonzero(~zero)
    if not len(keep):
        return out
    Ms = M[np.ix_(keep, keep)] / np.outer(d[keep], d[keep])
    w, v = np.linalg.eigh(Ms)
    smax = math.sqrt(max(w.max(), 1e-300))
    for k in range(len(w)):
        if math.sqrt(max(w[k], 0.0)) <= RANK_TOL * 10 * smax:
            comb = {names[keep[i]]: float(v[i, k]) for i in range(len(keep)) if abs(v[i, k]) > NULL_WEIGHT}
            for n in comb:
                out.setdefault(n, comb)
    return out


def information_se(M: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Standard errors from the Fisher information M of the scaled parameters (x / scale), in x's units."""
    try:
        V = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        V = np.linalg.pinv(M)
    return np.sqrt(np.maximum(np.diag(V), 0)) * scale


def world_order(worlds: list[World], start: World | None, costs: Costs) -> list[World]:
    """The order of `worlds` that costs the operator least, starting from `start`."""
    if len(worlds) <= 1:
        return list(worlds)
    best, best_c = list(worlds), math.inf
    perms = itertools.permutations(worlds) if len(worlds) <= 7 else [sorted(
        worlds, key=lambda w: (w.mode != (start.mode if start else "ground"), w.wheel_set, w.payload))]
    for perm in perms:
        c = costs.of(0.0, sequence_actions(list(perm), 0, start))
        if c < best_c - 1e-9:
            best, best_c = list(perm), c
    return best


def plan(robot: Robot, res: FitResult | None, targets: Mapping[str, tuple[float, bool]], space: Space,
         costs: Costs = Costs(), *, current: bool = True, start: World | None = None,
         budget_seconds: float = math.inf, budget_actions: float = math.inf, margin: float = MARGIN,
         required: Sequence[Candidate] = (), info: CandidateInformation | None = None,
         max_units: int = 200, obs: Any = None, given: Sequence[Candidate] = (),
         done: Mapping[Candidate, int] | None = None) -> Design:
    """The next steps for `targets` from the fit `res` of `obs` (None: the prior alone) on `robot`.

    required: candidates always included (a diagnostic floor), unless the data already hold them
    or they inform nothing (a sweep level the model predicts stuck: the fit leaves it out).
    given: steps that will run anyway (one entry per pair): their information counts as if in
    hand, they are neither chosen nor priced (the adaptive campaign's later poses).
    done: pairs of each candidate the data already hold (the adaptive campaign's earlier rounds):
    the MAX_REPS cap counts them, so that rounds do not pile repetitions of one level up past it."""
    model = res.robot if res is not None else robot
    names = planning_names(model, current)
    for p in targets:
        if p not in names:
            raise UserError(f"--target-se {p}: the campaign's fit does not estimate {p} "
                            f"(it estimates {', '.join(names)})")
    values = {p: param_value(model, p) for p in names}
    tabs = target_se(targets, values)
    group_s2 = res.group_s2 if res is not None else None
    if info is None:
        info = candidate_information(model, space.candidates, names, current=current, group_s2=group_s2,
                                     group_dof=res.group_dof if res is not None else None)
    scale = info.scale
    M0 = prior_information(res, names, scale, obs)
    data0 = M0 - np.eye(len(names)) / PRIOR_SD ** 2
    se_before = dict(zip(names, information_se(M0, scale)))
    for p in names:  # parameters the fit has not estimated yet have no SE of their own
        if res is None or p not in res.cov.index:
            se_before[p] = math.inf
    index = {c: k for k, c in enumerate(space.candidates)}
    for c in given:
        if c in index and info.usable[index[c]]:
            M0 = M0 + info.info[index[c]]
    # ---- identifiability over the whole design space
    refused: dict[str, str] = {}
    conditional: dict[str, str] = {}
    all_info = data0 + info.info[info.usable].sum(axis=0)
    null = _null_params(all_info, names)
    for p in targets:
        if p in null:
            comb = " ".join(f"{w:+.2f} {n}" for n, w in null[p].items())
            main = max(null[p], key=lambda n: abs(null[p][n]))  # the direction's main parameter
            refused[p] = (f"not separable with the candidate steps (only {comb} is seen); "
                          + separating_experiment(main))
        elif res is not None and p in res.identifiable and res.identifiable[p].condition:
            conditional[p] = res.identifiable[p].condition
    notes: list[str] = []
    active = [p for p in targets if p not in refused]
    tidx = np.array([names.index(p) for p in active], dtype=int)
    t2 = np.array([(margin * tabs[p] / scale[names.index(p)]) ** 2 for p in active])
    # ---- greedy selection inside each set of worlds; the cheapest set that meets the targets wins
    cands = space.candidates
    room = np.array([float(max(MAX_REPS - (done or {}).get(c, 0), 0)) for c in cands])
    req = [k for c in required for k, x in enumerate(cands) if x == c and info.usable[k]]
    worlds = list(dict.fromkeys(cands[k].world for k in np.flatnonzero(info.usable)))
    subsets = ([list(s) for n in range(1, len(worlds) + 1) for s in itertools.combinations(worlds, n)]
               if len(worlds) <= 7 else [worlds])
    averages: dict[Any, set[float]] = {}  # each upside-down world's sweep averaging times
    for c in cands:
        if c.procedure == "sweep":
            averages.setdefault(c.world, set()).add(c.duration)
    best = None
    setups = []
    for ws in subsets:
        if any(cands[k].world not in ws for k in req):
            continue
        order = world_order(ws, start, costs)
        setup_acts = sequence_actions(order, 0, start)
        rest = sum(2 * space.sweep_rest for w in ws if w.mode == "upside_down")
        setups.append((costs.of(rest, setup_acts), ws, order, setup_acts, rest))
    setups.sort(key=lambda x: x[0])
    for setup_cost, ws, order, setup_acts, rest in setups:
        if best is not None and not best[0][0] and setup_cost >= best[0][2]:
            break  # every remaining set of worlds costs more to set up than the best plan in total
        if sum(setup_acts.values()) > budget_actions or rest > budget_seconds:
            continue
        ks = np.array([k for k in np.flatnonzero(info.usable) if cands[k].world in ws and (room[k] > 0 or k in req)],
                      dtype=int)
        # the rest of a second sweep file in a world whose levels come at two averaging times is kept
        # out of the robot-time budget: the selection below does not see it
        two = sum(1 for w in ws if len(averages.get(w, ())) > 1)
        bs, ba = budget_seconds - rest - 2 * space.sweep_rest * two, budget_actions - sum(setup_acts.values())
        chosen, M, spent_s, spent_a, why = _greedy(M0, info.info, cands, ks, req, tidx, t2, costs, max_units, bs, ba,
                                                      room)
        chosen, M = _prune(chosen, M, infos=info.info, cands=cands, req=req, tidx=tidx, t2=t2, costs=costs)
        chosen, M = _exchange(chosen, M, infos=info.info, cands=cands, ks=ks, req=req, tidx=tidx, t2=t2, costs=costs,
                              room=room)
        greedy_total = costs.of(rest, setup_acts) + _units_cost(chosen, cands, costs)
        rounded = None
        if not _misses(M, tidx, t2) and (best is None or best[0][0] or greedy_total <= GATE * best[0][2]):
            rounded = _continuous(M0, info.info, cands, _columns(M, info.info, ks, chosen, req, tidx, t2, cands, costs),
                                  req, tidx, t2, costs, max_units, bs, ba, room)
        if rounded is not None and (_misses(rounded[1], tidx, t2), _units_cost(rounded[0], cands, costs)) < (
                _misses(M, tidx, t2), _units_cost(chosen, cands, costs) - 1e-9):
            chosen, M, why = rounded  # the rounded convex optimum: cheaper (or meets what the greedy missed)
        if not _misses(M, tidx, t2) and (best is None or best[0][0]
                                         or costs.of(rest, setup_acts) + _units_cost(chosen, cands, costs)
                                         <= GATE * best[0][2]):
            chosen, M = _improve(chosen, M, M0=M0, infos=info.info, cands=cands, ks=ks, req=req, tidx=tidx, t2=t2,
                                 costs=costs, room=room, max_units=max_units, budget_s=bs, budget_a=ba)
        phi = _phi(M, tidx, t2) if len(tidx) else 0.0
        # a world's sweep levels at two averaging times are two files: each rests before its directions
        extra = 2 * space.sweep_rest * (len(_sweep_files(chosen, cands)) - len({cands[k].world for k in chosen
                                                                               if cands[k].procedure == "sweep"}))
        total = costs.of(rest + extra, setup_acts) + sum(
            costs.of(cands[k].robot_seconds, {"measure": cands[k].measurements}) * r for k, r in chosen.items())
        key = (round(phi - len(tidx), 6) > 1e-6, phi if phi > len(tidx) + 1e-6 else 0.0, total)
        if best is None or key < best[0]:
            best = (key, chosen, M, order, why)
    if best is None:
        raise UserError("no step fits the budget (the first world change alone exceeds it)")
    _, chosen, M, order, why = best
    if why:
        notes.append(why)
    ranks = {k: i for i, k in enumerate(chosen)}
    # ---- order: worlds by least operator cost, inside a world by procedure and level
    order = [w for w in order if any(cands[k].world == w for k in chosen)]
    units = []
    for w in order:
        ks = sorted((k for k in chosen if cands[k].world == w),  # type: ignore[assignment]
                    key=lambda k: (cands[k].procedure, cands[k].duration, cands[k].duty, cands[k].heading,
                                   cands[k].speed))
        units += [Unit(cands[k], chosen[k], ranks[k]) for k in ks]
    robot_s = sum(u.candidate.robot_seconds * u.reps for u in units) + 2 * space.sweep_rest * len(
        _sweep_files(chosen, cands))
    acts = sequence_actions(order, sum(u.candidate.measurements * u.reps for u in units), start)
    se_after = dict(zip(names, information_se(M, scale)))
    for p in names:
        if not np.isfinite(se_after[p]) or se_after[p] >= 0.999 * PRIOR_SD * scale[names.index(p)]:
            se_after[p] = se_before[p]  # nothing but the prior: no SE of its own
    for p in active:
        if se_after[p] > tabs[p]:
            notes.append(f"{p}: the plan does not reach its target (expected SE {se_after[p]:.3g}, target "
                         f"{tabs[p]:.3g})")
    return Design(names=names, values=values, targets=tabs, se_before=se_before, se_after=se_after, units=units,
                  robot_seconds=robot_s, actions=acts, cost=costs.of(robot_s, acts), refused=refused,
                  notes=notes, conditional=conditional)


def _sweep_files(chosen: Mapping[int, int], cands: Sequence[Candidate]) -> set[tuple[Any, float]]:
    """The sweep files a choice is written as: one per world and averaging time."""
    return {(cands[k].world, cands[k].duration) for k in chosen if cands[k].procedure == "sweep"}


def _greedy(M0: np.ndarray, infos: np.ndarray, cands: Sequence[Candidate], ks: np.ndarray, required: Sequence[int],
            tidx: np.ndarray, t2: np.ndarray, costs: Costs, max_units: int, budget_s: float,
            budget_a: float, room: np.ndarray | None = None) -> tuple[dict[int, int], np.ndarray, float, float, str]:
    """Add, one at a time, the candidate of `ks` (repeated r in REPS times) with the largest drop of
    Phi per second of cost; (chosen {k: reps}, information, robot s, actions, why it stopped).
    room: pairs each candidate (index into cands) may still get (default MAX_REPS)."""
    M = M0.copy()
    chosen: dict[int, int] = {}
    spent_s = spent_a = 0.0
    for k in required:
        M = M + infos[k]
        chosen[k] = chosen.get(k, 0) + 1
        spent_s += cands[k].robot_seconds
        spent_a += cands[k].measurements
    if not len(tidx) or not len(ks):
        return chosen, M, spent_s, spent_a, ""
    reps = np.array(REPS, dtype=float)
    unit = np.array([costs.of(cands[k].robot_seconds, {"measure": cands[k].measurements}) for k in ks])
    rs = np.array([cands[k].robot_seconds for k in ks])
    ms = np.array([cands[k].measurements for k in ks])
    I = infos[ks]
    cap = room[ks] if room is not None else np.full(len(ks), float(MAX_REPS))
    for _ in range(max_units):
        phi = _phi(M, tidx, t2)
        if phi <= len(tidx) + 1e-9:
            return chosen, M, spent_s, spent_a, ""
        have = np.array([chosen.get(int(k), 0) for k in ks])
        ok = ((spent_s + reps[:, None] * rs[None] <= budget_s + 1e-9) & (spent_a + reps[:, None] * ms[None] <= budget_a)
              & (have[None] + reps[:, None] <= cap[None] + 1e-9))
        # only the steps the budget and the repetition cap allow are inverted (each matrix's
        # inverse is the same, bit for bit, in any batch)
        ri, ji = np.nonzero(ok)
        Ms = M[None] + reps[ri][:, None, None] * I[ji]
        try:
            V = np.linalg.inv(Ms)
        except np.linalg.LinAlgError:
            V = np.linalg.pinv(Ms)
        d = np.diagonal(V, axis1=-2, axis2=-1)[..., tidx]
        ratio = np.full(ok.shape, -np.inf)
        ratio[ri, ji] = (phi - np.where(np.all(d >= 0, axis=-1), np.sum(np.maximum(d / t2, 1.0), axis=-1), np.inf)) / (
            reps[ri] * unit[ji])
        r, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        if not ratio[r, j] > 0:
            return chosen, M, spent_s, spent_a, ("stopped at the budget" if not ok.all() else "")
        k = int(ks[j])
        M = M + reps[r] * infos[k]
        chosen[k] = chosen.get(k, 0) + int(reps[r])
        spent_s += reps[r] * cands[k].robot_seconds
        spent_a += reps[r] * cands[k].measurements
    return chosen, M, spent_s, spent_a, "stopped at the step limit"


#: Passes of the large-neighbourhood search over a rounded design (each pass tries every removal
#: of one or two pairs and re-completes greedily; it stops early when a pass finds nothing cheaper).
IMPROVE_PASSES = 4


def _improve(chosen: dict[int, int], M: np.ndarray, *, M0: np.ndarray, infos: np.ndarray,
             cands: Sequence[Candidate], ks: np.ndarray, req: Sequence[int], tidx: np.ndarray, t2: np.ndarray,
             costs: Costs, room: np.ndarray, max_units: int, budget_s: float, budget_a: float
             ) -> tuple[dict[int, int], np.ndarray]:
    """Large-neighbourhood search on whole pairs: take out one or two pairs (of one or two
    candidates), complete the rest again with the greedy over every candidate, prune and exchange;
    keep the result when it meets the targets for less. The greedy, the rounding and the single-pair
    exchange each stop at a design no one-pair move improves; a dear step is often replaced only by
    two cheaper ones together (a 4.5 s lateral pair by a 3 s one plus a sweep level)."""
    # the rounding's exchange ran over its columns only: first every candidate of the worlds
    chosen, M = _exchange(chosen, M, infos=infos, cands=cands, ks=ks, req=req, tidx=tidx, t2=t2, costs=costs,
                          room=room)
    best_cost = _units_cost(chosen, cands, costs)
    for _ in range(IMPROVE_PASSES):
        keys = [k for k in chosen if chosen[k] > (1 if k in req else 0)]
        moves = [(k,) for k in keys] + [(k, j) for i, k in enumerate(keys) for j in keys[i:]
                                        if k != j or chosen[k] - (1 if k in req else 0) >= 2]
        found = None
        for move in moves:
            base = dict(chosen)
            for k in move:
                base[k] -= 1
            start = [k for k, r in base.items() for _ in range(r)]
            trial, Mt, spent_s, spent_a, _why = _greedy(M0, infos, cands, ks, start, tidx, t2, costs, max_units,
                                                        budget_s, budget_a, room)
            if _misses(Mt, tidx, t2) or spent_s > budget_s + 1e-9 or spent_a > budget_a + 1e-9:
                continue
            trial, Mt = _prune(trial, Mt, infos=infos, cands=cands, req=req, tidx=tidx, t2=t2, costs=costs)
            c = _units_cost(trial, cands, costs)
            if c < best_cost - 1e-6 and (found is None or c < found[0]):
                found = (c, trial, Mt)
        if found is None:
            break
        best_cost, chosen, M = found
        chosen, M = _exchange(chosen, M, infos=infos, cands=cands, ks=ks, req=req, tidx=tidx, t2=t2, costs=costs,
                              room=room)
        best_cost = _units_cost(chosen, cands, costs)
    return chosen, M


def _misses(M: np.ndarray, tidx: np.ndarray, t2: np.ndarray) -> bool:
    return bool(len(tidx)) and _phi(M, tidx, t2) > len(tidx) + 1e-9


def _units_cost(chosen: Mapping[int, int], cands: Sequence[Candidate], costs: Costs) -> float:
    return sum(costs.of(cands[k].robot_seconds, {"measure": cands[k].measurements}) * r for k, r in chosen.items())


#: The convex optimum is solved only for a set of worlds where the greedy meets the targets, at a
#: cost of at most GATE times the best design so far (it rarely saves more than a third; the
#: solve is the planner's dearest step).
GATE = 1.5
#: Candidates the convex optimum is solved over (the solver's cost grows fast with their number).
COLUMNS = 30


def _columns(M: np.ndarray, infos: np.ndarray, ks: np.ndarray, chosen: Mapping[int, int], required: Sequence[int],
             tidx: np.ndarray, t2: np.ndarray, cands: Sequence[Candidate], costs: Costs) -> np.ndarray:
    """The candidates worth solving over: the greedy's and the required ones, and the COLUMNS that
    shrink the weighted target variances most per second of cost at the greedy's design
    (the directional derivative of the weighted A-criterion, sum_i (V M_k V)_ii / t_i^2)."""
    try:
        V = np.linalg.inv(M)[:, tidx]
    except np.linalg.LinAlgError:
        return ks
    gain = np.einsum("ni,knm,mi->k", V, infos[ks], V / t2[None, :])
    unit = np.array([costs.of(cands[k].robot_seconds, {"measure": cands[k].measurements}) for k in ks])
    top = ks[np.argsort(-gain / unit)[:COLUMNS]]
    keep = set(int(k) for k in top) | {int(k) for k in chosen} | {int(k) for k in required}
    return np.array([k for k in ks if int(k) in keep], dtype=int)


def _continuous(M0: np.ndarray, infos: np.ndarray, cands: Sequence[Candidate], ks: np.ndarray,
                required: Sequence[int], tidx: np.ndarray, t2: np.ndarray, costs: Costs, max_units: int,
                budget_s: float, budget_a: float, room: np.ndarray | None = None
                ) -> tuple[dict[int, int], np.ndarray, str] | None:
    """The convex optimum over real repetitions (optimal.cheapest_weights), rounded to whole pairs:
    its integer parts, completed by the greedy (from there, over the candidates the optimum uses
    first), then pruned. None when the optimum is not found or the rounded design misses a
    target the greedy's reach."""
    if not len(tidx) or not len(ks):
        return None
    unit = np.array([costs.of(cands[k].robot_seconds, {"measure": cands[k].measurements}) for k in ks])
    lo = np.array([float(sum(1 for r in required if r == k)) for k in ks])
    hi = room[ks] if room is not None else np.full(len(ks), float(MAX_REPS))
    w = cheapest_weights(M0, infos[ks], unit, tidx, t2, lo, np.maximum(hi, lo))
    if w is None:
        return None
    base = [int(k) for k, x in zip(ks, w) for _ in range(int(math.floor(x + 1e-6)))]
    base += [k for k in required if k not in base]
    support = np.array([k for k, x in zip(ks, w) if x > 1e-3], dtype=int)
    best = None
    # complete the integer parts over the optimum's own candidates, or over all (a fraction of a dear
    # step is often bought cheaper as a whole cheap one); prune; keep the cheaper that meets the targets
    for pool in (support, ks):
        chosen, M, spent_s, spent_a, why = _greedy(M0, infos, cands, pool, base, tidx, t2, costs, max_units,
                                                   budget_s, budget_a, room)
        if spent_s > budget_s + 1e-9 or spent_a > budget_a + 1e-9:
            continue
        chosen, M = _prune(chosen, M, infos=infos, cands=cands, req=required, tidx=tidx, t2=t2, costs=costs)
        chosen, M = _exchange(chosen, M, infos=infos, cands=cands, ks=ks, req=required, tidx=tidx, t2=t2, costs=costs,
                              room=room)
        key = (_misses(M, tidx, t2), _units_cost(chosen, cands, costs))
        if best is None or key < best[0]:
            best = (key, (chosen, M, why))
    return best[1] if best is not None else None


def _prune(chosen: dict[int, int], M: np.ndarray, *, infos: np.ndarray, cands: Sequence[Candidate],
           req: Sequence[int], tidx: np.ndarray, t2: np.ndarray, costs: Costs) -> tuple[dict[int, int], np.ndarray]:
    """Drop repetitions the targets no longer need (greedy picks early steps that later ones make
    redundant), dearest first, while every target stays met."""
    if not len(tidx) or _phi(M, tidx, t2) > len(tidx) + 1e-9:
        return chosen, M
    chosen = dict(chosen)
    order = sorted(chosen, key=lambda k: -costs.of(cands[k].robot_seconds, {"measure": cands[k].measurements}))
    for k in order:
        while chosen.get(k, 0) > (1 if k in req else 0):
            trial = M - infos[k]
            if _phi(trial, tidx, t2) > len(tidx) + 1e-9:
                break
            M = trial
            chosen[k] -= 1
        if chosen.get(k) == 0:
            del chosen[k]
    return chosen, M


def _exchange(chosen: dict[int, int], M: np.ndarray, *, infos: np.ndarray, cands: Sequence[Candidate],
              ks: np.ndarray, req: Sequence[int], tidx: np.ndarray, t2: np.ndarray,
              costs: Costs, room: np.ndarray | None = None) -> tuple[dict[int, int], np.ndarray]:
    """Exchange (Fedorov's idea, on whole pairs): replace one pair by the cheapest candidate of `ks`
    that keeps every target met, dearest pair first, while that lowers the cost. Whole pairs
    overshoot (one long run can carry several times what a target needs); a cheaper step often
    carries enough."""
    if not len(tidx) or not len(ks) or _phi(M, tidx, t2) > len(tidx) + 1e-9:
        return chosen, M
    chosen = dict(chosen)
    unit = np.array([costs.of(cands[k].robot_seconds, {"measure": cands[k].measurements}) for k in ks])
    I = infos[ks]
    for k in sorted(chosen, key=lambda k: -costs.of(cands[k].robot_seconds, {"measure": cands[k].measurements})):
        ck = costs.of(cands[k].robot_seconds, {"measure": cands[k].measurements})
        while chosen.get(k, 0) > (1 if k in req else 0):
            left = (room[ks] if room is not None else np.full(len(ks), float(MAX_REPS))) - np.array(
                [chosen.get(int(j), 0) for j in ks])
            cheaper = np.flatnonzero((unit < ck - 1e-9) & (left >= 1))
            if not len(cheaper):
                break
            Ms = (M - infos[k])[None] + I[cheaper]
            try:
                V = np.linalg.inv(Ms)
            except np.linalg.LinAlgError:
                break
            d = np.diagonal(V, axis1=-2, axis2=-1)[:, tidx]
            ok = np.all(d >= 0, axis=1) & np.all(d <= t2 * (1 + 1e-9), axis=1)
            if not ok.any():
                break
            j = int(cheaper[np.flatnonzero(ok)[np.argmin(unit[cheaper][ok])]])
            M = M - infos[k] + I[j]
            chosen[k] -= 1
            chosen[int(ks[j])] = chosen.get(int(ks[j]), 0) + 1
        if chosen.get(k) == 0:
            del chosen[k]
    return chosen, M


#: Which experiment separates each parameter (said when the candidates cannot).
SEPARATES = {
    "c": "an upside-down sweep with a second wheel set of another mass (another [[wheel_sets]] entry) "
         "separates the load term c from b",
    "c_r": "lateral runs with at least two payloads (payloads = [...]) separate c_r from b_r",
    "C_r": "forward runs on the ground measure the rolling resistance C_r",
    "a_r": "lateral runs at two speeds or more separate a_r from b_r",
    "b_r": "lateral runs at two speeds or more separate b_r from a_r",
    "a": "logging the motor current in the sweep separates a from the back-EMF damping eta k_t k_e / R_a",
    "b": "an upside-down sweep at two duties or more",
    "k_e": "logging the motor current in the sweep", "R_a": "logging the motor current in the sweep",
}


def separating_experiment(name: str) -> str:
    return SEPARATES.get(name, "an experiment whose observations depend on it differently from the others")


def describe_actions(actions: Mapping[str, int]) -> str:
    return ", ".join(f"{n} x {ACTION_WORDS[k]}" for k, n in actions.items() if n) or "none"
