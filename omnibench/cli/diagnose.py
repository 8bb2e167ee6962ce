"""`omnibench diagnose`: find what the model still gets wrong, add the missing effect, report
the held-out error before and after (docs/diagnose.md)."""

from __future__ import annotations

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
@click.option("--force", is_flag=True,
              help="Overwrite --out even if omnibench did not write it (a hand-edited robot file, any other file).")
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
@click.option("--allow-mixed", is_flag=True, help="Combine runs (and the model) of different robots, boards or "
              "worlds (simulated and real) anyway, with a warning line.")
def command(model: Path, runs: tuple[Path, ...], out: Path | None, plots: Path | None, as_json: bool,
            candidates: str | None, procedures: str | None, alpha: float, max_effects: int, seed: int,
            loro: bool, force: bool = False, allow_mixed: bool = False) -> None:
    """Fit the declared model to RUN..., find residual structure, add the library effect that
    earns its parameters on held-out run steps, repeat; report before/after errors."""
    if not (0.0 < alpha < 0.5) or not math.isfinite(alpha):
        raise UserError(f"--alpha {alpha}: give a significance level between 0 and 0.5, e.g. 0.001")
    if max_effects < 0:
        raise UserError(f"--max-effects {max_effects}: must be 0 or more")
    from omnibench.campaign.diagnose_command import diagnose_runs

    done = diagnose_runs(runs, model=model, out=out, plots=plots, candidates=parse_candidates(candidates),
                         procedures=_procedures(procedures), alpha=alpha, max_effects=max_effects, seed=seed,
                         loro=loro, force=force, allow_mixed=allow_mixed,
                         progress=lambda line: click.echo(line, err=True))
    if as_json:
        click.echo(done.json_text())
        return
    click.echo(done.diagnosis.text())
    if done.held is not None:
        click.echo(done.held.text())
    if "model" in done.written:
        click.echo(f"extended model written to {done.written['model']}")
    if "plots" in done.written:
        click.echo(f"plots: {', '.join(done.written['plots'])}")
