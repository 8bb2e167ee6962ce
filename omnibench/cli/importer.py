"""`omnibench import`: convert other data into run directories (docs/run-format.md)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from omnibench.cli.params import NonEmptyPath


@click.group("import")
def command() -> None:
    """Convert other data (the 2019 TFM logs) into runs."""


@command.command("tfm")
@click.argument("files", nargs=-1, required=True, type=NonEmptyPath(path_type=Path))
@click.option("--signs", default=None, metavar="S1,S2,S3,S4",
              help="Per-wheel sign map (FL,FR,RL,RR) applied to the logged encoder counts so a "
                   "positive duty gives a positive wheel speed. Default: +1,-1,+1,-1 for the raw "
                   "square-wave logs, +1,+1,+1,+1 for results_jacked.mat and results_ground_x.mat "
                   "(already corrected), read off the data for the RC log (inputs.mat).")
@click.option("--sketch", type=click.Choice(["square", "rc"]), default=None,
              help="Which 2019 sketch recorded the files (its command timing: send order and when "
                   "the commands left relative to the time stamp). Default: the RC sketch for "
                   "inputs.mat, the square-wave sketch otherwise (for results_ground_x.mat an "
                   "assumption: the data README names no sketch; the run says so).")
@click.option("--out", "out", default=Path("runs"), show_default=True,
              type=NonEmptyPath(path_type=Path), help="Folder that receives the run directories.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def tfm(files: tuple[Path, ...], signs: str | None, sketch: str | None, out: Path, as_json: bool) -> None:
    """Import 2019 thesis logs: results_jacked.mat (upside-down sweep), square_*.mat (step responses),
    results_ground_x.mat (step responses on the floor), inputs.mat (RC-driven random duty)."""
    from omnibench.runs import read_run
    from omnibench.runs.tfm import import_tfm, parse_signs

    from omnibench.cli.params import check_out_folder

    check_out_folder(out)
    sign_map = parse_signs(signs) if signs is not None else None
    results = []
    for f in files:
        path = import_tfm(f, out, signs=sign_map, sketch=sketch)
        run = read_run(path)
        results.append({"file": str(f), "run": str(path), "procedure": run.procedure,
                        "steps": int(len(run.steps)), "samples": int(len(run.samples)),
                        "sign_map": run.metadata["sign_map"],
                        "mode": run.metadata.get("mode"), "firmware_timing": run.metadata.get("firmware_timing")})
        if not as_json:
            click.echo(f"{f}: {run.procedure} run with {len(run.steps)} steps and "
                       f"{len(run.samples)} samples -> {path} (sign map {run.metadata['sign_map']}, "
                       f"{run.metadata.get('mode')}, commands sent in wheel order "
                       f"{run.metadata['firmware_timing']['command_order']}"
                       + (f"; timing {run.metadata['firmware_timing']['source']}"
                          if "assumed" in run.metadata['firmware_timing'].get("source", "") else "") + ")")
    if as_json:
        click.echo(json.dumps(results, indent=2))
