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
whose firmware timing is not documented (the 2019 floor run: no sketch named) is scored per
stage with the documented timing that predicts it better (its timing is a nuisance with two
known values, profiled out, so no model is judged by a guess); the table shows both timings and
the report names the one each stage chose.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from omnibench.analysis.heldout_runs import PhysicsModel, RunError, leave_one_run_out

TOLERANCE = 0.02  # relative change of a run's held-out NRMSE treated as noise


@dataclass
class HeldOutRuns:
    """Per stage label (declared, + effect, ...): the held-out error per run; trade-offs."""

    stages: list[str]
    errors: list[RunError]
    tradeoffs: list[dict[str, Any]] = field(default_factory=list)
    accepted: int = 0  # additions before the first trade-off
    #: runs whose firmware timing is not documented: per stage, (the sketch whose timing scores it, NRMSE)
    timing: dict[str, dict[str, tuple[str, float]]] = field(default_factory=dict)

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
        for run, chosen in self.timing.items():
            lines.append(f"firmware timing of {run} not documented: each stage scored with the timing that "
                         "predicts it better: " + ", ".join(f"{label} {100 * v:.2f} % ({sketch})"
                                                             for label, (sketch, v) in chosen.items()))
        if not self.tradeoffs:
            lines.append(f"no addition makes any run's held-out error worse than the declared model's "
                         f"(beyond {100 * TOLERANCE:.0f} % and its noise"
                         + ("; a run of undocumented timing at each stage's better timing)" if self.timing else ")"))
        else:
            kept = ", ".join(self.additions[:self.accepted]) or "nothing"
            lines.append(f"accepted on held-out runs: {kept} (trade-offs are reported, not added to the written model)")
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        return {"stages": self.stages, "tolerance": TOLERANCE, "tradeoffs": self.tradeoffs,
                "accepted": self.additions[:self.accepted],
                "timing_profiled": {run: {label: {"sketch": sk, "nrmse": v} for label, (sk, v) in c.items()}
                                    for run, c in self.timing.items()},
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
    trade, accepted, timing = find_tradeoffs(labels, errors)
    return HeldOutRuns(labels, errors, trade, accepted, timing)


def find_tradeoffs(labels: list[str], errors: list[RunError]
                   ) -> tuple[list[dict[str, Any]], int, dict[str, dict[str, tuple[str, float]]]]:
    """The trade-offs among the stages `labels` (declared first), how many additions come before
    the first, and, per run of undocumented firmware timing, the timing each stage is scored
    with (RunError.profiled: the documented timing that predicts it better)."""
    trade = []
    accepted = len(labels) - 1
    timing = {e.run: {label: (sketch, v) for label in labels
                      for v, sketch, _ in [e.profiled(label)] if v is not None}
              for e in errors if e.alternatives}
    for k, cur in enumerate(labels[1:]):
        addition = cur.lstrip("+ ").split(" + ")[-1]
        worse, better = {}, {}
        for e in errors:
            (a, _, sa), (b, _, sb) = e.profiled(labels[0]), e.profiled(cur)
            if a is None or b is None:
                continue
            if b > (1 + TOLERANCE) * a and _beyond_noise(sa, sb):
                worse[e.run] = (a, b)
            elif b < (1 - TOLERANCE) * a:
                better[e.run] = (a, b)
        if worse:
            trade.append({"addition": addition, "worse": worse, "better": better})
            accepted = min(accepted, k)
    return trade, accepted, timing


def _beyond_noise(base: tuple[np.ndarray, np.ndarray] | None, cur: tuple[np.ndarray, np.ndarray] | None) -> bool:
    """Is a run's loss from the `base` (measured, predicted) series to `cur`'s beyond its noise?
    For a trace: more than 2 block-bootstrap standard errors (analysis/heldout_noise.py);
    without series (a sweep) or with series that do not pair: yes."""
    from omnibench.analysis.heldout_noise import worse_beyond_noise

    if base is None or cur is None or base[0].shape != cur[0].shape:
        return True
    return worse_beyond_noise(base[0], base[1], cur[1])


def trimmed(diag: Any, held: HeldOutRuns, obs: Any) -> Any:
    """`diag` without the additions from the first trade-off on: its accepted stage refitted to
    every run (for `--out`)."""
    from dataclasses import replace

    from omnibench.analysis.heldout_runs import fit_physics

    if held.accepted >= len(diag.selected):
        return diag
    model = stage_models(diag)[held.stages[held.accepted]]
    return replace(diag, selected=diag.selected[:held.accepted], extended=fit_physics(model, obs))


# --------------------------------------------------------------------------------------------
# Leave one firmware out (issue 36): the latencies diagnose finds are firmware timing; a model
# fitted on the logs of one sketch must predict the logs of another with that sketch's timing.

@dataclass
class HeldOutFirmware:
    """Per run of a documented sketch: its NRMSE per stage, each stage refitted on the logs of
    the *other* sketches (and predicting with the run's own firmware timing). `worse`: runs the
    last stage predicts worse than the declared model beyond TOLERANCE and the run's noise."""

    stages: list[str]
    errors: list[RunError]
    sketch: dict[str, str]  # run -> the sketch that recorded it
    trained_on: dict[str, list[str]]  # run -> the runs its models were fitted to
    worse: dict[str, tuple[float, float]] = field(default_factory=dict)
    left_out: list[str] = field(default_factory=list)  # runs of unknown firmware

    def text(self) -> str:
        if not self.errors:
            return ("Leave-one-firmware-out: needs logs of at least two documented sketches"
                    + (f" (unknown firmware, left out: {', '.join(self.left_out)})" if self.left_out else ""))
        width = max(12, *(len(x) for x in self.stages))
        lines = [("Leave-one-firmware-out NRMSE (each run predicted, with its own firmware's timing, by the model "
                  "refitted to the logs of the other sketch(es)):"),
                 f"{'held-out run':<34} {'recorded by':<28} " + " ".join(f"{x:>{width}}" for x in self.stages)]
        for e in self.errors:
            lines.append(f"{e.run[:34]:<34} {self.sketch.get(e.run, '?')[:28]:<28} "
                         + " ".join(f"{100 * e.nrmse[x]:>{width - 2}.2f} %" if x in e.nrmse else f"{'--':>{width}}"
                                    for x in self.stages))
        for run, train in self.trained_on.items():
            lines.append(f"  {run}: fitted to {', '.join(train)}")
        if self.left_out:
            lines.append(f"  unknown firmware, in no fold: {', '.join(self.left_out)}")
        last = self.stages[-1]
        if self.worse:
            lines.append(f"{last} predicts worse than the declared model (beyond {100 * TOLERANCE:.0f} % and the run's "
                         "noise): " + ", ".join(f"{r} {100 * a:.2f} % -> {100 * b:.2f} %" for r, (a, b) in self.worse.items()))
        else:
            lines.append(f"the diagnosed model ({last}) predicts no log of another sketch worse than the declared "
                         f"model (beyond {100 * TOLERANCE:.0f} % and the run's noise)")
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        return {"stages": self.stages, "tolerance": TOLERANCE, "left_out": self.left_out,
                "worse": {r: list(v) for r, v in self.worse.items()},
                "runs": [{"run": e.run, "sketch": self.sketch.get(e.run), "trained_on": self.trained_on.get(e.run),
                          "kind": e.kind, "signal": e.signal, "nrmse": e.nrmse} for e in self.errors]}


def run_sketch(obs: Any, run: str) -> str:
    """The sketch that recorded a run ('unknown' when no sketch is documented)."""
    return str(obs.runs.get(run, {}).get("sketch") or "unknown")


def leave_one_firmware_out(diag: Any, obs: Any, *, progress: Callable[[str], None] | None = None,
                           max_nfev: int = 30) -> HeldOutFirmware:
    """Every stage of `diag` refitted on the logs of all sketches but one, predicting that one's
    logs (runs of unknown firmware are in no fold: their timing is not documented)."""
    from omnibench.analysis.heldout_runs import fit_physics, run_error, run_kind

    say = progress or (lambda s: None)
    models = stage_models(diag)
    labels = list(models)
    groups: dict[str, list[str]] = {}
    left_out = []
    for r in obs.run_ids:
        sk = run_sketch(obs, r)
        if sk == "unknown":
            left_out.append(r)
        else:
            groups.setdefault(sk, []).append(r)
    out = HeldOutFirmware(labels, [], {r: run_sketch(obs, r) for r in obs.run_ids}, {}, left_out=left_out)
    if len(groups) < 2:
        return out
    for k, (sketch, held) in enumerate(groups.items()):
        train_runs = [r for s, rs in groups.items() if s != sketch for r in rs]
        train = obs.select(runs=train_runs)
        errs = {r: RunError(r, run_kind(obs, r), "steady speed" if run_kind(obs, r) == "sweep" else "wheel speed")
                for r in held}
        for label, model in models.items():
            say(f"{sketch} (firmware {k + 1} of {len(groups)}): fitting {label} to {len(train_runs)} run(s) of other sketches")
            fitted = fit_physics(model, train, max_nfev)
            for r in held:
                errs[r].nrmse[label], series = run_error(fitted, obs, r)
                if series is not None:
                    errs[r].series[label] = series
        for r in held:
            out.errors.append(errs[r])
            out.trained_on[r] = list(train_runs)
    first, last = labels[0], labels[-1]
    for e in out.errors:
        a, b = e.nrmse.get(first), e.nrmse.get(last)
        if a is None or b is None or not (np.isfinite(a) and np.isfinite(b)):
            continue
        if b > (1 + TOLERANCE) * a and _beyond_noise(e.series.get(first), e.series.get(last)):
            out.worse[e.run] = (a, b)
    return out
