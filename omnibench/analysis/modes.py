"""Runs whose mode (where the robot was: in the air or on the floor) is unknown, profiled.

A trace-replay run that its import could not place (run.json `mode` null, `conditions.where`
unknown: docs/run-format.md) is never replayed in a default mode. predict replays it both ways
and keeps the better (predict.predict_runs). fit and diagnose fit every assignment of modes to
the k such runs that enter the fit (2^k fits, refused above MAX_UNKNOWN_MODES), keep the one of
lowest cost and say which mode each run was given and what the other assignments cost
(`ModeProfile`); diagnose keeps the chosen modes for everything after its declared fit.

The cost compared is the profile deviance sum_g n_g log(RSS_g / n_g) of the fitted residuals,
each group's noise scale profiled: the same measurements enter every assignment, and a group's
noise estimated from its own residual cannot hide a worse fit as a chi^2 per degree of freedom
(which is about 1 whatever the model when the noise is estimated) would.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

import numpy as np

from omnibench.analysis.observations import Observations
from omnibench.errors import UserError

#: above this many unknown-mode runs in one fit, the 2^k fits are refused (--where at import)
MAX_UNKNOWN_MODES = 3
MODES = ("upside_down", "ground")
WORDS = {"upside_down": "in the air", "ground": "on the floor"}

R = TypeVar("R")


def unknown_mode_runs(obs: Observations, procedures: Sequence[str] | None = None) -> list[str]:
    """The runs of `obs` whose mode is unknown (`mode` None) and that have rows in a replayed
    table among `procedures` (all when None): only those change the fit with their mode."""
    if procedures is not None and "step_response" not in procedures:
        return []
    table = obs.table("step_response")
    have = set(table["run"].astype(str)) if len(table) and "run" in table else set()
    return [r for r in obs.run_ids if "mode" in obs.runs.get(r, {}) and obs.runs[r]["mode"] is None
            and str(r) in have]


def assignments(runs: Sequence[str]) -> list[dict[str, str]]:
    """Every assignment of a mode to each run (2^k); refused in one line above MAX_UNKNOWN_MODES."""
    if len(runs) > MAX_UNKNOWN_MODES:
        raise UserError(f"{len(runs)} runs of unknown mode (where the robot was: {', '.join(runs)}): profiling "
                        f"them takes 2^{len(runs)} fits, at most {MAX_UNKNOWN_MODES} are profiled; import some "
                        "with --where air|floor, or leave them out")
    return [dict(zip(runs, combo)) for combo in itertools.product(MODES, repeat=len(runs))]


def with_modes(obs: Observations, modes: dict[str, str]) -> Observations:
    """`obs` with each run of `modes` given that mode (a copy; obs is unchanged)."""
    return replace(obs, runs={**obs.runs, **{r: {**obs.runs[r], "mode": m} for r, m in modes.items()}})


def profile_deviance(residual: np.ndarray, sigma: np.ndarray, group: np.ndarray) -> float:
    """sum_g n_g log(RSS_g / n_g) of the residuals over `sigma`, each group's sigma normalised by
    its geometric mean first (a group-wide noise scale a fit estimated drops out). Entries that
    are not finite are left out."""
    residual, sigma, group = np.asarray(residual, float), np.asarray(sigma, float), np.asarray(group)
    ok = np.isfinite(residual) & np.isfinite(sigma) & (sigma > 0)
    total = 0.0
    for g in np.unique(group[ok]):
        m = ok & (group == g)
        s = sigma[m] / math.exp(float(np.mean(np.log(sigma[m]))))
        rss = float(np.sum((residual[m] / s) ** 2))
        total += int(m.sum()) * math.log(max(rss / int(m.sum()), 1e-300))
    return total


@dataclass
class ModeProfile:
    """The assignments of modes tried and the one kept. `tried`: (assignment, cost) in the order
    fitted; `chosen`: the kept assignment (run -> mode); `statistic`: what the cost is."""

    chosen: dict[str, str]
    tried: list[tuple[dict[str, str], float]] = field(default_factory=list)
    statistic: str = "profile deviance"
    #: more per assignment (e.g. chi^2/dof), same order as `tried`
    extra: list[dict[str, float]] = field(default_factory=list)

    @property
    def cost(self) -> float:
        return next(c for a, c in self.tried if a == self.chosen)

    def text(self) -> str:
        """One line: each run's mode given, and every other assignment's cost against the kept one."""
        given = ", ".join(f"{r} {WORDS[m]}" for r, m in self.chosen.items())
        others = []
        for k, (a, c) in enumerate(self.tried):
            if a == self.chosen:
                continue
            diff = [f"{r} {WORDS[m]}" for r, m in a.items() if self.chosen[r] != m]
            more = "".join(f", {n} {v:.4g}" for n, v in (self.extra[k] if k < len(self.extra) else {}).items())
            others.append(f"{'; '.join(diff)}: {self.statistic} {c:.2f} (+{c - self.cost:.2f}{more})")
        mine = self.extra[[a for a, _ in self.tried].index(self.chosen)] if self.extra else {}
        kept = "".join(f", {n} {v:.4g}" for n, v in mine.items())
        return (f"where unknown, profiled over {len(self.tried)} assignments of modes: kept {given} "
                f"({self.statistic} {self.cost:.2f}{kept}); instead " + "; ".join(others))

    def to_json(self) -> dict[str, Any]:
        return {"chosen": dict(self.chosen), "statistic": self.statistic,
                "tried": [{"modes": dict(a), "cost": c, **(self.extra[k] if k < len(self.extra) else {})}
                          for k, (a, c) in enumerate(self.tried)]}


def profile_modes(obs: Observations, procedures: Sequence[str] | None,
                  fit_one: Callable[[Observations], tuple[R, float, dict[str, float]]],
                  say: Callable[[str], None] | None = None) -> tuple[Observations, R, ModeProfile | None]:
    """(obs with the kept modes, its fit, the profile or None): `fit_one(obs)` -> (fit, cost,
    extra) for each assignment of modes to the unknown-mode runs entering `procedures`; the lowest
    cost kept (a cost that is not finite never is, unless every one is). Without such runs:
    obs and its one fit, profile None."""
    runs = unknown_mode_runs(obs, procedures)
    if not runs:
        return obs, fit_one(obs)[0], None
    tried: list[tuple[dict[str, str], float]] = []
    extra: list[dict[str, float]] = []
    best: tuple[Observations, R] | None = None
    best_cost, best_k = math.inf, 0
    for k, a in enumerate(assignments(runs)):
        if say:
            say(f"where unknown for {len(runs)} run(s): assignment {k + 1} of {2 ** len(runs)} ("
                + ", ".join(f"{r} {WORDS[m]}" for r, m in a.items()) + ")")
        o = with_modes(obs, a)
        res, cost, more = fit_one(o)
        tried.append((a, cost))
        extra.append(more)
        if best is None or (math.isfinite(cost) and not cost >= best_cost):
            best, best_cost, best_k = (o, res), cost, k
    assert best is not None
    return best[0], best[1], ModeProfile(tried[best_k][0], tried, extra=extra)
