"""Choosing between designs whose information depends on parameters no data have measured yet.

A lateral pair's information depends on the roller terms, and before the first lateral run those
are the robot file's guesses. A design that is best at the guess can be poor at the truth: on the
independent physics (seed 7 of benchmarks/design.py) the pilot chosen at a_r 2.0, c_r 0.01 gave
an SE on a_r 1.6 x the one it promised, 2.4 x the SE of the design chosen on other seeds (at
a_r 2.5, c_r 0.02), and cost a second lateral round. So each candidate design (the planner's
own, made at one prior point each) is judged over all the points, by its expected cost to meet
the targets: cost x the mean over points of max_p (SE_p / target_p)^2, the number of times the
design would have to run to meet every unmeasured target at that point (the data in hand say
nothing about those parameters, so their information scales with the repetitions). This is
pseudo-Bayesian design (the criterion averaged over a prior, not the information: an average
information matrix is dominated by the points where information is large).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

#: Prior points: each unmeasured parameter times and divided by this factor (one at a time).
SPREAD = 2.0


def prior_points(robot: Robot, unmeasured: Sequence[str]) -> list[dict[str, float]]:
    """Values of the unmeasured parameters to plan at: the robot file's, and each one times and
    divided by SPREAD with the others at the file's (2 n + 1 points; an order of magnitude is all
    the lab is assumed to know before the first run that measures them)."""
    from omnibench.analysis.least_squares import param_value

    centre = {p: float(param_value(robot, p)) for p in unmeasured}
    out = [dict(centre)]
    for p in unmeasured:
        for f in (SPREAD, 1.0 / SPREAD):
            out.append({**centre, p: centre[p] * f})
    return out


def at_point(res: Any, point: Mapping[str, float]) -> Any:
    """The fit `res` with its robot's unmeasured parameters set to `point` (its noise kept)."""
    return dataclasses.replace(res, robot=res.robot.replace(**point))


def expected_repeats(res: Any, obs: Any, units: Sequence[Any], targets: Mapping[str, tuple[float, bool]],
                     unmeasured: Sequence[str], points: Sequence[Mapping[str, float]], current: bool = True) -> float:
    """Mean over `points` of max over `unmeasured` of (SE / target)^2 after `units` run, at the
    noise the fit `res` found (groups without data: expected_s2's rule)."""
    return expected_repeats_of(res, obs, [units], targets, unmeasured, points, current)[0]


def expected_repeats_of(res: Any, obs: Any, designs: Sequence[Sequence[Any]], targets: Mapping[str, tuple[float, bool]],
                        unmeasured: Sequence[str], points: Sequence[Mapping[str, float]],
                        current: bool = True) -> list[float]:
    """`expected_repeats` of each design, the information of the data in hand and of every
    candidate computed once per point (not once per design and point: each is a Jacobian of all
    the rows, the most of the pilot's planning time)."""
    from omnibench.analysis.design.information import candidate_information, prior_information
    from omnibench.analysis.design.planner import information_se, planning_names, target_se
    from omnibench.analysis.least_squares import param_value

    cands = list(dict.fromkeys(u.candidate for d in designs for u in d))
    where = {c: k for k, c in enumerate(cands)}
    scores: list[list[float]] = [[] for _ in designs]
    for pt in points:
        r = at_point(res, pt)
        names = planning_names(r.robot, current)
        ci = candidate_information(r.robot, cands, names, current=current, group_s2=res.group_s2,
                                   group_dof=res.group_dof)
        M0 = prior_information(r, names, ci.scale, obs)
        tabs = target_se(targets, {p: param_value(r.robot, p) for p in targets})
        for d, design in enumerate(designs):
            M = M0 + sum((u.reps * ci.info[where[u.candidate]] for u in design), np.zeros_like(M0))
            se = information_se(M, ci.scale)
            scores[d].append(max((se[names.index(p)] / tabs[p]) ** 2 for p in unmeasured if p in names))
    return [float(np.mean(sc)) if sc else math.inf for sc in scores]
