"""Held-out means held-out runs: leave-one-run-out errors of the physics model and of the
black-box baselines, trained on the same runs.

For each run R of the runs given: every model is fitted to the *other* runs (wheels in the air:
the sweep and the step-response / random-duty traces), then predicts R, and the error is R's
wheel-speed NRMSE (its steady-speed NRMSE for a sweep). Runs on the floor are a procedure of
their own: they are predicted by the models fitted on every in-air run (leave-one-procedure-out).

The physics model refits `free` (default: a, b, I_w and the fitted parameters of every effect
the robot declares) with `fitting.fit`; the black boxes (analysis/baseline.py) are fitted to the
training traces' wheel speeds.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from omnibench.analysis.observations import Observations

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

PHYSICS_FREE = ("a", "b", "I_w")
SWEEP_FREE = ("a", "b", "c")  # what the sweep measures (paper III.i)


def physics_free(robot: Robot) -> list[str]:
    """Parameters refitted per fold: a, b, I_w and every declared effect's fitted parameters."""
    from omnibench.effects import EFFECTS

    return list(PHYSICS_FREE) + [f"{e}.{p}" for e in robot.effects if e in EFFECTS for p in EFFECTS[e].fit]


@dataclass
class PhysicsModel:
    """A physics model as LORO refits it: the start robot, the parameters refitted per fold
    (default `physics_free`), and whether each training run's supply is re-estimated
    (sessions.py: a gain that differs between measurement days)."""

    robot: Robot
    free: Sequence[str] | None = None
    run_supplies: bool = False
    #: the paper's order: friction (a, b) from the sweep alone, then the rest from the traces
    staged: bool = True


@dataclass
class RunError:
    """One held-out run: NRMSE per model (label -> value) and the signal it is measured on."""

    run: str
    kind: str  # "in-air trace", "sweep", "floor trace"
    signal: str
    nrmse: dict[str, float] = field(default_factory=dict)
    #: per label, the held-out trace's wheel speeds (measured, predicted), (n, 4) each in time
    #: order: what `heldout_noise` resamples (traces only; empty for a sweep)
    series: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)
    #: a run whose firmware timing is assumed: per other documented timing (its sketch), the
    #: same models' NRMSE and series with that timing (the fits are the same: trained elsewhere)
    alternatives: dict[str, dict[str, float]] = field(default_factory=dict)
    alt_series: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = field(default_factory=dict, repr=False)
    #: the sketch whose timing was assumed (a run with `alternatives`)
    assumed_sketch: str = "the assumed timing"

    def profiled(self, label: str) -> tuple[float | None, str, tuple[np.ndarray, np.ndarray] | None]:
        """The model's NRMSE at its better documented timing, that timing and the series: a run's
        undocumented timing is a nuisance with a few documented values, profiled out per model
        (each model is scored with the timing that suits it, so none is judged by a guess)."""
        options = [(self.nrmse.get(label), self.assumed_sketch, self.series.get(label))]
        options += [(alt.get(label), sketch, self.alt_series.get(sketch, {}).get(label))
                    for sketch, alt in self.alternatives.items()]
        options = [o for o in options if o[0] is not None and np.isfinite(o[0])]
        return min(options, key=lambda o: o[0]) if options else (None, self.assumed_sketch, None)  # type: ignore[arg-type, return-value]


def run_kind(obs: Observations, run: str) -> str:
    if (obs.sweep["run"] == run).any():
        return "sweep"
    return "floor trace" if obs.runs.get(run, {}).get("mode") == "ground" else "in-air trace"


def run_error(robot: Robot, obs: Observations, run: str) -> tuple[float, tuple[np.ndarray, np.ndarray] | None]:
    """The run's held-out NRMSE and, for a trace, its wheel speeds (measured, predicted)."""
    from omnibench.analysis.predict import predict_runs

    pred = predict_runs(robot, obs.select(runs=[run]))[0]
    if run_kind(obs, run) == "sweep":
        return float(pred.nrmse.get("steady_speed", float("nan"))), None
    reps = [pred.traces[k] for k in sorted(pred.traces)]
    series = None
    if reps:
        series = tuple(np.concatenate([r[[f"w{j}_{x}" for j in range(1, 5)]].to_numpy() for r in reps])
                       for x in ("meas", "pred"))
    return float(pred.nrmse.get("wheel_speed", float("nan"))), series  # type: ignore[return-value]


def _sweep_measures(name: str, sweep: Any = None) -> bool:
    """Friction the sweep measures: a, b, c, and the parameters of library effects that show in
    the sweep alone, against speed or wheel (per-wheel gearbox friction, drag: a sweep of steady
    speeds per wheel over the duty range pins them). Other effects' parameters are fitted on the
    traces: a one-direction sweep cannot see direction asymmetry, nor time or transients, and an
    effect that also shows in step responses (Stribeck) is measured best where it shows most."""
    from omnibench.effects import EFFECTS

    if name in SWEEP_FREE:
        return True
    eff = EFFECTS.get(name.split(".")[0]) if "." in name else None
    # in the air (what leave-one-run-out fits) it must show in the sweep and not in the step
    # responses; where else it shows on the ground (asymmetry in forward runs) does not matter
    if eff is None or "upside_down_sweep" not in eff.procedures or "step_response" in eff.procedures:
        return False
    if eff.variable == "direction":  # only a sweep run both ways shows it
        return sweep is not None and len(sweep) > 0 and bool((sweep["u"] < 0).any() and (sweep["u"] > 0).any())
    return eff.variable in ("speed", "wheel")


def fit_physics(model: PhysicsModel, train: Observations, max_nfev: int = 30) -> Any:
    """The model's robot fitted to `train` (sweep and traces in the air)."""
    from omnibench.analysis.fitting import fit
    from omnibench.analysis.sessions import fit_with_run_supplies

    procs = [p for p in ("sweep", "step_response") if len(train.table(p))]
    free = list(model.free or physics_free(model.robot))
    robot = model.robot
    if model.staged and len(train.sweep) and len(train.step_response):
        sweep_free = [p for p in free if _sweep_measures(p, train.sweep)]
        if sweep_free:
            robot = fit(robot, train, sweep_free, procedures=["sweep"], max_nfev=max_nfev).robot
        free, procs = [p for p in free if p not in sweep_free], ["step_response"]
    if not free:
        return robot
    if model.run_supplies and procs == ["step_response"]:
        return fit_with_run_supplies(robot, train, free, procs, max_nfev=max_nfev).fit.robot
    return fit(robot, train, free, procedures=procs, max_nfev=max_nfev).robot


def leave_one_run_out(models: dict[str, PhysicsModel], obs: Observations, *, baselines: bool = True,
                      max_nfev: int = 30, progress: Callable[[str], None] | None = None) -> list[RunError]:
    """Leave-one-run-out NRMSE of each physics model (label -> PhysicsModel) and, with
    `baselines`, of the two black boxes, over every run of `obs` (module docstring)."""
    from omnibench.analysis import baseline

    say = progress or (lambda s: None)
    runs = obs.run_ids
    air = [r for r in runs if run_kind(obs, r) != "floor trace"]
    floor = [r for r in runs if r not in air]
    folds: list[tuple[str, list[str]]] = [(r, [x for x in air if x != r]) for r in air]
    if floor:
        folds += [(r, air) for r in floor]
    out = []
    t0, done = time.process_time(), 0  # CPU seconds and folds done: the ETA of the rest
    for k, (held, train_runs) in enumerate(folds):
        if not train_runs:
            continue
        eta = (f"; about {_mmss((time.process_time() - t0) / done * (len(folds) - k))} CPU left"
               if done else "")
        done += 1
        train = obs.select(runs=train_runs)
        err = RunError(held, run_kind(obs, held), "steady speed" if run_kind(obs, held) == "sweep" else "wheel speed")
        alts = _timing_alternatives(obs, held)
        if alts:
            err.assumed_sketch = str(obs.runs[held].get("timing_sketch", err.assumed_sketch))
        for label, model in models.items():
            say(f"{held} (held-out run {k + 1} of {len(folds)}{eta}): fitting {label} to {len(train_runs)} other run(s)")
            eta = ""
            fitted = fit_physics(model, train, max_nfev)
            err.nrmse[label], series = run_error(fitted, obs, held)
            if series is not None:
                err.series[label] = series
            for sketch, alt_obs in alts.items():
                err.alternatives.setdefault(sketch, {})[label], s_alt = run_error(fitted, alt_obs, held)
                if s_alt is not None:
                    err.alt_series.setdefault(sketch, {})[label] = s_alt
        held_tr = baseline.traces(obs, [held]) if err.kind == "in-air trace" else []
        train_tr = baseline.traces(obs, train_runs)
        if baselines and held_tr and train_tr:
            for dead, label in ((False, "black box (lag + Coulomb)"), (True, "black box + dead time")):
                say(f"{held}: fitting {label}")
                err.nrmse[label] = baseline.fit_black_box(train_tr, dead).nrmse(held_tr[0])
        out.append(err)
    return out


def _mmss(seconds: float) -> str:
    return f"{int(seconds // 60)}:{int(seconds % 60):02d}"


def _timing_alternatives(obs: Observations, run: str) -> dict[str, Observations]:
    """For a run whose firmware timing is assumed: per other documented timing (by sketch),
    `obs` with that timing for the run (observations.py `timing_alternatives`)."""
    from dataclasses import replace

    info = obs.runs.get(run, {})
    out = {}
    for alt in info.get("timing_alternatives", []):
        runs = {**obs.runs, run: {**info, "command_order": alt["command_order"], "command_offset": alt["command_offset"]}}
        out[alt["sketch"]] = replace(obs, runs=runs)
    return out


def table(errors: Sequence[RunError]) -> str:
    """Held-out NRMSE per run and model, with the mean over in-air traces."""
    labels: list[str] = []
    for e in errors:
        labels += [k for k in e.nrmse if k not in labels]
    width = max(12, *(len(x) for x in labels))
    lines = [f"{'held-out run':<44} {'kind':<13} " + " ".join(f"{x:>{width}}" for x in labels)]
    for e in errors:
        lines.append(f"{e.run[:44]:<44} {e.kind:<13} "
                     + " ".join(f"{100 * e.nrmse[x]:>{width - 2}.2f} %" if x in e.nrmse else f"{'--':>{width}}"
                                for x in labels))
        for sketch, alt in e.alternatives.items():  # its timing is assumed: the other documented one
            lines.append(f"{'  with the timing of ' + sketch:<44.44} {'':<13} "
                         + " ".join(f"{100 * alt[x]:>{width - 2}.2f} %" if x in alt else f"{'--':>{width}}"
                                    for x in labels))
    air = [e for e in errors if e.kind == "in-air trace"]
    if air:
        means = {x: float(np.mean([e.nrmse[x] for e in air if x in e.nrmse])) for x in labels
                 if all(x in e.nrmse for e in air)}
        lines.append(f"{'mean over in-air traces':<44} {'':<13} "
                     + " ".join(f"{100 * means[x]:>{width - 2}.2f} %" if x in means else f"{'--':>{width}}"
                                for x in labels))
    return "\n".join(lines)
