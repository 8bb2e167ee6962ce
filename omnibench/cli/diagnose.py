"""`omnibench diagnose`: find what the model still gets wrong, add the missing effect, report
the held-out error before and after (docs/diagnose.md)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from omnibench.cli.params import FINITE, NonEmptyPath
from omnibench.errors import UserError


def parse_candidates(text: str | None) -> list[str] | None:
    if text is None:
        return None
    from omnibench.effects import EFFECTS

    names = [t.strip() for t in text.split(",") if t.strip()]
    bad = [n for n in names if n not in EFFECTS]
    if bad or not names:
        raise UserError(f"--candidates: unknown effect(s) {', '.join(bad) or '(none given)'}; known: {', '.join(EFFECTS)}")
    return names


def _procedures(text: str | None) -> list[str] | None:
    if text is None:
        return None
    from omnibench.analysis.observations import PROCEDURES

    names = [t.strip() for t in text.split(",") if t.strip()]
    bad = [n for n in names if n not in PROCEDURES]
    if bad or not names:
        raise UserError(f"--procedures: unknown {', '.join(bad) or '(none given)'}; choose from {', '.join(PROCEDURES)}")
    return names


@click.command("diagnose")
@click.option("--model", "model", required=True, type=NonEmptyPath(path_type=Path),
              help="Robot TOML of the declared model (e.g. the one `omnibench fit` wrote).")
@click.argument("runs", nargs=-1, required=True, type=NonEmptyPath(path_type=Path))
@click.option("--out", "out", type=NonEmptyPath(path_type=Path), default=None,
              help="Write the extended model (refitted coefficients + added effects) to this TOML file.")
@click.option("--plots", "plots", type=NonEmptyPath(path_type=Path), default=None,
              help="Folder for PNG plots: residual vs the variable that exposed each effect, before/after.")
@click.option("--json", "as_json", is_flag=True, help="Print the diagnosis as JSON.")
@click.option("--candidates", default=None, metavar="NAME,...",
              help="Only these candidate effects (default: the whole library, docs/effects.md).")
@click.option("--procedures", default=None, metavar="NAME,...",
              help="Only these observation tables (sweep, forward, lateral, energy, step_response).")
@click.option("--alpha", default=1e-3, show_default=True, type=FINITE,
              help="Family-wise significance level for adding an effect.")
@click.option("--max-effects", default=3, show_default=True, type=int, help="Add at most this many effects.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the held-out fold assignment.")
@click.option("--loro", is_flag=True,
              help="Also leave-one-run-out: refit the declared model and each addition to all runs but one, "
                   "predict that run (with the black boxes beside); report additions that cost a run as trade-offs.")
def command(model: Path, runs: tuple[Path, ...], out: Path | None, plots: Path | None, as_json: bool,
            candidates: str | None, procedures: str | None, alpha: float, max_effects: int, seed: int,
            loro: bool) -> None:
    """Fit the declared model to RUN..., find residual structure, add the library effect that
    earns its parameters on held-out run steps, repeat; report before/after errors."""
    if not (0.0 < alpha < 0.5) or not math.isfinite(alpha):
        raise UserError(f"--alpha {alpha}: give a significance level between 0 and 0.5, e.g. 0.001")
    if max_effects < 0:
        raise UserError(f"--max-effects {max_effects}: must be 0 or more")
    names = parse_candidates(candidates)
    procs = _procedures(procedures)
    from omnibench.analysis.diagnosis import diagnose
    from omnibench.analysis.diagnosis.report import write_model, write_plots
    from omnibench.analysis.observations import Observations
    from omnibench.cli.params import check_out_folder
    from omnibench.runs.check import check_output, checked_runs

    runs = tuple(checked_runs(runs))
    if out is not None:
        check_output(out, runs)
    if plots is not None:
        check_out_folder(plots, "--plots")
    from omnibench.analysis.model_file import load_model
    from omnibench.model import load_robot

    robot = load_robot(model)  # its errors name a robot file: any robot file is a model
    fit_info = load_model(model)[1]  # [fit]: was this model fitted to these very runs?
    obs = Observations.from_runs(runs, robot=robot)
    if not obs.procedures():
        raise UserError("the runs hold no measurements diagnose can use (sweep, forward, lateral, energy, step_response)")

    def progress(msg: str) -> None:
        click.echo(f"diagnose: {msg}", err=True)

    diag = diagnose(robot, obs, candidates=names, procedures=procs, alpha=alpha, max_effects=max_effects,
                    seed=seed, progress=progress, fit_info=fit_info)
    held = None
    if loro:
        from omnibench.analysis.diagnosis.loro import heldout_runs

        if len(obs.run_ids) < 2:
            raise UserError("--loro needs at least two runs (each is predicted from the others)")
        held = heldout_runs(diag, obs, progress=progress)
    written: dict[str, object] = {}
    if out is not None:
        if held is not None and held.tradeoffs:
            from omnibench.analysis.diagnosis.loro import trimmed

            written["model"] = str(write_model(trimmed(diag, held, obs), out))
        else:
            written["model"] = str(write_model(diag, out))
    if plots is not None:
        written["plots"] = [str(p) for p in write_plots(diag, plots)]
    if as_json:
        click.echo(json.dumps({**diag.to_json(), "written": written,
                               "leave_one_run_out": held.to_json() if held else None}, indent=2, default=_jsonable))
        return
    click.echo(diag.text())
    if held is not None:
        click.echo(held.text())
    if "model" in written:
        click.echo(f"extended model written to {written['model']}")
    if "plots" in written:
        click.echo(f"plots: {', '.join(written['plots'])}")  # type: ignore[arg-type]


def _jsonable(x: object) -> object:
    try:
        v = float(x)  # type: ignore[arg-type]  # numpy scalars
    except (TypeError, ValueError):
        return str(x)
    return v if math.isfinite(v) else None
