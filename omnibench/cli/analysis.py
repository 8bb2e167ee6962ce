"""`omnibench fit`, `omnibench validate-energy`, `omnibench predict`: read run directories,
never the port. See docs/fit.md."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import click

from omnibench.cli.params import NonEmptyPath
from omnibench.errors import UserError
from omnibench.runs.check import check_out_folder, checked_runs
from omnibench.runs.provenance import model_build


def _echo_json(obj: Any) -> None:
    from omnibench.runs.store import json_ready

    click.echo(json.dumps(json_ready(obj), indent=2, allow_nan=False))


def _free(text: str | None) -> list[str] | None:
    if text is None:
        return None
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise UserError("--free: give parameter names separated by commas, e.g. a,b,c")
    return names


@click.command("fit")
@click.argument("runs", nargs=-1, required=True, type=NonEmptyPath(path_type=Path))
@click.option("--robot", "robot_file", type=NonEmptyPath(path_type=Path), default=None,
              help="Robot or model file to start from (default: the shipped Omnibot).")
@click.option("--out", "out", type=NonEmptyPath(path_type=Path), default=Path("model.toml"), show_default=True,
              help="Model file to write: the robot file with the fitted values and a [fit] table.")
@click.option("--free", "free", default=None, metavar="P1,P2,...",
              help="Parameters to fit (paper symbols, or <effect>.<param>). Default: what the runs measure.")
@click.option("--procedures", "procedures", default=None, metavar="P1,P2,...",
              help="Observation tables that enter the fit: sweep, forward, lateral, energy, step_response "
                   "(default: the sweep, forward and lateral runs given; e.g. --procedures step_response "
                   "--free I_w fits the wheel inertia to step responses).")
@click.option("--force", is_flag=True,
              help="Overwrite --out even if omnibench did not write it (a hand-edited robot file, any other file).")
@click.option("--per-wheel/--no-per-wheel", default=True, show_default=True,
              help="Also fit the upside-down sweep of each wheel on its own (a, b, c per wheel).")
@click.option("--plots", "plots", type=NonEmptyPath(path_type=Path), default=None,
              help="Folder for the figures (sweep with fitted curves, residuals).")
@click.option("--skip-bad", is_flag=True, help="Leave out incomplete or corrupt runs (named on stderr) instead of refusing.")
@click.option("--allow-mixed", is_flag=True, help="Combine runs of different robots, boards or worlds (simulated and real) anyway, with a warning line; the shared coefficients are fitted from all of them.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def fit_command(runs: tuple[Path, ...], robot_file: Path | None, out: Path, free: str | None,
                procedures: str | None, per_wheel: bool, plots: Path | None, as_json: bool,
                skip_bad: bool = False, force: bool = False, allow_mixed: bool = False) -> None:
    """Fit every coefficient the RUN directories measure, with standard errors, 95 % intervals,
    correlations and an identifiability verdict per parameter; write the model file."""
    from omnibench.campaign.analysis_commands import fit_runs

    procs = None if procedures is None else [p.strip() for p in procedures.split(",") if p.strip()]
    done = fit_runs(runs, out=out, robot_file=robot_file, free=_free(free), procedures=procs, per_wheel=per_wheel,
                    plots=plots, skip_bad=skip_bad, force=force, allow_mixed=allow_mixed,
                    progress=lambda line: click.echo(line, err=True),
                    say=(lambda line: None) if as_json else click.echo)
    if as_json:
        click.echo(done.json_text())
        return
    result, wheels, model_path, figures = done.result, done.wheels, done.model_path, done.figures
    click.echo(result.table())
    if len(result.corr) > 1:
        click.echo("correlation matrix:")
        names = list(result.corr.columns)
        click.echo("        " + " ".join(f"{n:>8}" for n in names))
        for a in names:
            click.echo(f"{a:>8}" + " ".join(f"{result.corr.loc[a, b]:>8.3f}" for b in names))
    for c in result.confounded:
        click.echo(f"not separable: {', '.join(c['with'])} and the fixed {c['fixed']} "
                   f"(only {c['combination']} is seen)")
    if wheels:
        click.echo("per-wheel upside-down sweep fits:")
        for j, r in wheels.items():
            vals = []
            for p in r.free:
                v = r.identifiable[p]
                if v.ok and math.isfinite(r.se[p]):
                    vals.append(f"{p} = {r.values[p]:.4g} +/- {r.se[p]:.2g}" + (f" ({v.status})" if v.status != "identified" else ""))
                else:
                    vals.append(f"{p}: {v.status}")
            st = r.structure.get("sweep/omega")
            smooth = (f", residual smoothness {st['z']:.1f} sigma" + (" (structured)" if st["z"] > 3 else "")
                      if st else "")
            click.echo(f"  wheel {j}: " + ", ".join(vals) + f"; chi2/dof {r.s2:.3g}{smooth}")
        reasons = {p: r.identifiable[p].reason for r in wheels.values() for p in r.free
                   if not r.identifiable[p].ok}
        for p, why in reasons.items():
            click.echo(f"  {p}: {why}")
    for n in result.notes:
        click.echo(f"note: {n}")
    click.echo(f"model file written: {model_path}")
    for f in figures:
        click.echo(f"figure: {f}")


@click.command("validate-energy")
@click.argument("runs", nargs=-1, required=True, type=NonEmptyPath(path_type=Path))
@click.option("--model", "model", type=NonEmptyPath(path_type=Path), required=True,
              help="Model file from `omnibench fit` (or a robot file).")
@click.option("--plots", "plots", type=NonEmptyPath(path_type=Path), default=None,
              help="Folder for the current-trace figure.")
@click.option("--skip-bad", is_flag=True, help="Leave out incomplete or corrupt runs (named on stderr) instead of refusing.")
@click.option("--allow-mixed", is_flag=True, help="Combine runs of different robots, boards or worlds (simulated and real) anyway, with a warning line; the shared coefficients are fitted from all of them.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def validate_command(runs: tuple[Path, ...], model: Path, plots: Path | None, as_json: bool,
                     skip_bad: bool = False, allow_mixed: bool = False) -> None:
    """Replay each energy run's duties through the model and compare predicted with measured
    battery energy (paper IV)."""
    from omnibench.campaign.analysis_commands import validate_runs

    done = validate_runs(runs, model=model, plots=plots, skip_bad=skip_bad, allow_mixed=allow_mixed,
                         progress=lambda line: click.echo(line, err=True))
    if as_json:
        click.echo(done.json_text())
        return
    val, fig = done.validation, done.figure
    click.echo(f"{'run':<40} {'step':>4} {'trajectory':<14} {'measured J':>11} {'model J':>11} {'error %':>8}")
    for _, r in val.table.iterrows():
        click.echo(f"{r['run']!s:<40} {int(r['step']):>4} {r['trajectory']!s:<14} {r['measured_J']:>11.2f} "
                   f"{r['predicted_J']:>11.2f} {r['error_pct']:>+8.2f}")
    click.echo(f"mean absolute error {val.mean_abs_error_pct:.2f} %, largest {val.max_abs_error_pct:.2f} %")
    if fig:
        click.echo(f"figure: {fig}")


@click.command("predict")
@click.argument("runs", nargs=-1, required=True, type=NonEmptyPath(path_type=Path))
@click.option("--model", "model", type=NonEmptyPath(path_type=Path), required=True,
              help="Model file from `omnibench fit` (or a robot file).")
@click.option("--plots", "plots", type=NonEmptyPath(path_type=Path), default=None,
              help="Folder for the measured-vs-model figures.")
@click.option("--skip-bad", is_flag=True, help="Leave out incomplete or corrupt runs (named on stderr) instead of refusing.")
@click.option("--allow-mixed", is_flag=True, help="Combine runs of different robots, boards or worlds (simulated and real) anyway, with a warning line; the shared coefficients are fitted from all of them.")
@click.option("--baseline", is_flag=True,
              help="Also leave-one-run-out: refit the model (a, b on the sweep; I_w and its effects on the "
                   "traces) and the per-wheel black boxes (first-order lag + Coulomb offset, with and "
                   "without dead time) on the other runs, and print each run's held-out NRMSE side by side.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def predict_command(runs: tuple[Path, ...], model: Path, plots: Path | None, baseline: bool, as_json: bool,
                    skip_bad: bool = False, allow_mixed: bool = False) -> None:
    """Replay a logged RUN (any procedure, including imported step responses) through the model:
    NRMSE of wheel speeds, positions and currents where measured."""
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.predict import predict_runs
    from omnibench.campaign.analysis_commands import model_robot

    if plots is not None:
        check_out_folder(plots, "--plots")
    robot, _ = model_robot(model)
    obs = Observations.from_runs(checked_runs(runs, skip_bad=skip_bad, echo=lambda line: click.echo(line, err=True),
                                            allow_mixed=allow_mixed,
                                            model=(f"the model {model}", model_build(robot))),
                                 robot)
    preds = predict_runs(robot, obs, profile_timing=True)  # a run's own firmware timing (issue 36)
    if not preds:
        raise UserError("the runs hold nothing to predict")
    loro_note = ""
    if baseline:
        # a run of unknown mode enters the refits in the mode its replay through the model chose
        from omnibench.analysis.modes import WORDS, with_modes

        chosen = {p.run: p.mode for p in preds if p.mode_profiled and p.mode}
        loro = _baseline(robot, with_modes(obs, chosen), model)
        loro_note = "".join(f"\n{r}: where unknown, in the refits {WORDS[m]} (its better replay above)"
                            for r, m in chosen.items())
    else:
        loro = None
    figs: list[str] = []
    if plots is not None:
        from omnibench.analysis.plots import plot_prediction

        for p in preds:
            f = plot_prediction(p, plots)
            if f:
                figs.append(str(f))
    pooled: dict[str, list[float]] = {}
    for p in preds:
        for k, v in p.nrmse.items():
            pooled.setdefault(k, []).append(v)
    top = {k: (v[0] if len(v) == 1 else float(math.sqrt(sum(x * x for x in v) / len(v)))) for k, v in pooled.items()}
    if as_json:
        _echo_json({"model": str(model), "nrmse": top,
                    "runs": [{"run": p.run, "procedure": p.procedure, "nrmse": p.nrmse, "firmware_timing": p.firmware,
                              **({"firmware_profiled": p.firmware_profiled} if p.firmware_profiled else {}),
                              **({"mode": p.mode, "mode_profiled": p.mode_profiled} if p.mode_profiled else {})}
                             for p in preds],
                    "plots": figs,
                    "leave_one_run_out": None if loro is None else [
                        {"run": e.run, "kind": e.kind, "signal": e.signal, "nrmse": e.nrmse} for e in loro]})
        return
    for p in preds:
        click.echo(f"{p.run} ({p.procedure}" + (f"; {p.firmware_text()}" if p.firmware else "")
                   + (f"; {p.mode_text()}" if p.mode_profiled else "") + "):")
        for k, v in p.nrmse.items():
            click.echo(f"  NRMSE {k:<16} {v:8.4f}  ({100 * v:.1f} %)")
    for f in figs:  # type: ignore[assignment]
        click.echo(f"figure: {f}")
    if loro is not None:
        from omnibench.analysis.heldout_runs import table

        click.echo("\nLeave-one-run-out NRMSE (each run predicted by models fitted to the other runs; "
                   "floor runs by models fitted to every run in the air):")
        click.echo(table(loro) + loro_note)


def _baseline(robot, obs, model: Path) -> list:
    """Leave-one-run-out errors of the model and the two black boxes (analysis/heldout_runs.py)."""
    from omnibench.analysis.heldout_runs import PhysicsModel, leave_one_run_out

    if len(obs.run_ids) < 2:
        raise UserError("--baseline needs at least two runs (each is predicted from the others)")
    return leave_one_run_out({f"physics ({model.name})": PhysicsModel(robot)}, obs,
                             progress=lambda s: click.echo(f"baseline: {s}", err=True))


commands = {"fit": fit_command, "validate-energy": validate_command, "predict": predict_command}
