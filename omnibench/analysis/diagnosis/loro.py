"""Held-out runs for diagnose (`--loro`): the leave-one-run-out error of the declared model and
after each addition, and every addition that makes some run worse reported as a trade-off.

Stage k is the declared model plus the first k additions (library effects and core-parameter
re-estimates, in the order diagnose accepted them). Each stage is refitted with every run but
one (analysis/heldout_runs.py: a, b on the sweep, the rest on the traces) and predicts that
run. An addition whose stage predicts some run worse than the declared model by more than
TOLERANCE (relative; compared with the declared model, as diagnose's own held-out check, so
small losses cannot pile up) and, for a trace, by more than its noise (two standard errors of
the change by a moving-block bootstrap over the trace, analysis/heldout_noise.py) is a trade-off: reported with the runs it costs and what it gains,
and it and every later addition are left out of the model `--out` writes (`accepted`). A run
whose firmware timing is assumed (the 2019 floor run: no sketch documented) counts against an
addition only if it is worse under every documented timing it may have had; a loss under the
assumed timing alone is reported as not counted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from omnibench.analysis.heldout_runs import PhysicsModel, RunError, leave_one_run_out

TOLERANCE = 0.02  # relative change of a run's held-out NRMSE treated as noise


@dataclass
class HeldOutRuns:
    """Per stage label (declared, + effect, ...): the held-out error per run; trade-offs."""

    stages: list[str]
    errors: list[RunError]
    tradeoffs: list[dict[str, Any]] = field(default_factory=list)
    accepted: int = 0  # additions before the first trade-off
    #: losses on a run with assumed firmware timing that another documented timing does not show
    unproven: list[dict[str, Any]] = field(default_factory=list)

    @property
    def additions(self) -> list[str]:
        """The additions in the order of the stages."""
        return [label.lstrip("+ ").split(" + ")[-1] for label in self.stages[1:]]

    def text(self) -> str:
        from omnibench.analysis.heldout_runs import table

        lines = ["Leave-one-run-out NRMSE (each run predicted by the model refitted to the other runs):",
                 table(self.errors)]
        for t in self.tradeoffs:
            worse = ", ".join(f"{r} {100 * a:.2f} % -> {100 * b:.2f} %" for r, (a, b) in t["worse"].items())
            better = ", ".join(f"{r} {100 * a:.2f} % -> {100 * b:.2f} %" for r, (a, b) in t["better"].items())
            lines.append(f"trade-off: {t['addition']} makes {worse} worse"
                         + (f" (while {better} improve)" if better else ""))
        for u in self.unproven:
            alts = ", ".join(f"{100 * a:.2f} % -> {100 * b:.2f} % with the timing of {s}"
                             for s, (a, b) in u["alternatives"].items() if a is not None and b is not None)
            lines.append(f"not counted: {u['addition']} makes {u['run']} worse with its assumed firmware timing "
                         f"({100 * u['assumed'][0]:.2f} % -> {100 * u['assumed'][1]:.2f} %), not {alts}: "
                         f"the run's timing is not documented, so the loss is reported, not counted")
        if not self.tradeoffs:
            lines.append(f"no addition makes any run's held-out error worse than the declared model's "
                         f"(beyond {100 * TOLERANCE:.0f} % and its noise"
                         + (", under every firmware timing the run may have had)" if self.unproven else ")"))
        else:
            kept = ", ".join(self.additions[:self.accepted]) or "nothing"
            lines.append(f"accepted on held-out runs: {kept} (trade-offs are reported, not added to the written model)")
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        return {"stages": self.stages, "tolerance": TOLERANCE, "tradeoffs": self.tradeoffs,
                "accepted": self.additions[:self.accepted], "unproven": self.unproven,
                "runs": [{"run": e.run, "kind": e.kind, "signal": e.signal, "nrmse": e.nrmse,
                          **({"nrmse_with_other_timing": e.alternatives} if e.alternatives else {})}
                         for e in self.errors]}


def stage_models(diag: Any) -> dict[str, PhysicsModel]:
    """The declared model and each cumulative addition, with the parameters refitted per fold."""
    from omnibench.analysis.diagnosis.core_params import is_core

    final = diag.final_fit.robot
    base_free = [p for p in diag.base_fit.free if "." not in p]
    models = {"declared": PhysicsModel(diag.declared, free=base_free or None)}
    effects: dict[str, dict[str, float]] = {}
    free = list(base_free)
    robot = diag.declared
    label = "declared"
    for c in diag.selected:
        if is_core(c.name):
            free.append(c.name)
            robot = robot.replace(**{c.name: float(getattr(final, c.name))})
        else:
            effects[c.name] = dict(final.effects.get(c.name, {}))
            free += [p for p in diag.final_fit.free if p.startswith(c.name + ".")]
            robot = robot.replace(effects={**diag.declared.effects, **effects})
        label = f"{label} + {c.name}" if label == "declared" else f"+ {c.name}"
        models[label] = PhysicsModel(robot, free=list(free))
    return models


def heldout_runs(diag: Any, obs: Any, *, progress: Callable[[str], None] | None = None) -> HeldOutRuns:
    """Leave-one-run-out errors of every stage of `diag` on `obs` (module docstring)."""
    models = stage_models(diag)
    errors = leave_one_run_out(models, obs, baselines=True, progress=progress)
    labels = list(models)
    trade, accepted, unproven = find_tradeoffs(labels, errors)
    return HeldOutRuns(labels, errors, trade, accepted, unproven)


def find_tradeoffs(labels: list[str], errors: list[RunError]) -> tuple[list[dict[str, Any]], int, list[dict[str, Any]]]:
    """The trade-offs among the stages `labels` (declared first), how many additions come before
    the first, and the losses not counted: a run whose firmware timing is assumed vetoes an
    addition only if it is worse under every documented timing it may have had (a loss under
    the assumed one alone rests on the assumption, and is reported, not counted)."""
    trade, unproven = [], []
    accepted = len(labels) - 1
    for k, cur in enumerate(labels[1:]):
        addition = cur.lstrip("+ ").split(" + ")[-1]
        worse, better = {}, {}
        for e in errors:
            a, b = e.nrmse.get(labels[0]), e.nrmse.get(cur)
            if a is None or b is None:
                continue
            if _worse(a, b, e.series, labels[0], cur):
                others = {s: (alt.get(labels[0]), alt.get(cur)) for s, alt in e.alternatives.items()}
                if all(x is not None and y is not None and _worse(x, y, e.alt_series.get(s, {}), labels[0], cur)
                       for s, (x, y) in others.items()):
                    worse[e.run] = (a, b)
                else:
                    unproven.append({"addition": addition, "run": e.run, "assumed": (a, b),
                                     "alternatives": others})
            elif b < (1 - TOLERANCE) * a:
                better[e.run] = (a, b)
        if worse:
            trade.append({"addition": addition, "worse": worse, "better": better})
            accepted = min(accepted, k)
    return trade, accepted, unproven


def _worse(a: float, b: float, series: dict[str, Any], base: str, cur: str) -> bool:
    """From NRMSE a to b: worse by more than TOLERANCE and beyond the run's noise."""
    return b > (1 + TOLERANCE) * a and _beyond_noise(series, base, cur)


def _beyond_noise(series: dict[str, Any], base: str, cur: str) -> bool:
    """Is a run's loss from `base` to `cur` beyond its noise? For a trace (its `series`): more
    than 2 block-bootstrap standard errors (analysis/heldout_noise.py); without (a sweep): yes."""
    from omnibench.analysis.heldout_noise import worse_beyond_noise

    if base not in series or cur not in series:
        return True
    m, pa = series[base]
    return worse_beyond_noise(m, pa, series[cur][1])


def trimmed(diag: Any, held: HeldOutRuns, obs: Any) -> Any:
    """`diag` without the additions from the first trade-off on: its accepted stage refitted to
    every run (for `--out`)."""
    from dataclasses import replace

    from omnibench.analysis.heldout_runs import fit_physics

    if held.accepted >= len(diag.selected):
        return diag
    model = stage_models(diag)[held.stages[held.accepted]]
    return replace(diag, selected=diag.selected[:held.accepted], extended=fit_physics(model, obs))
