"""`omnibench import`: convert other data into run directories (docs/run-format.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from omnibench.cli.params import NonEmptyPath
from omnibench.errors import UserError
from omnibench.runs.record import RunInfo, read_info
from omnibench.runs.store import run_dirs


@click.group("import")
def command() -> None:
    """Convert other data (the 2019 TFM logs, your own CSV logs) into runs."""


@command.command("tfm")
@click.argument("files", nargs=-1, required=True, type=NonEmptyPath(path_type=Path))
@click.option("--signs", default=None, metavar="S1,S2,S3,S4",
              help="Per-wheel sign map (FL,FR,RL,RR) applied to the logged encoder counts so a "
                   "positive duty gives a positive wheel speed. Default: +1,-1,+1,-1 for the raw "
                   "square-wave logs, +1,+1,+1,+1 for results_jacked.mat and results_ground_x.mat "
                   "(already corrected), read off the data for the RC log (inputs.mat).")
@click.option("--sketch", type=click.Choice(["square", "rc"]), default=None,
              help="Which 2019 sketch recorded the files (its command timing: send order and when "
                   "the commands left relative to the time stamp). Default: stated by the RC layout "
                   "(inputs.mat's 6-row data); otherwise read off the loop period (median time-stamp "
                   "spacing within 3 ms of square.ino's 30 ms or ardu.ino.ino's 44 ms), else unknown "
                   "(the analysis profiles over both). A loop that clearly says the other sketch is refused.")
@click.option("--where", type=click.Choice(["air", "floor"]), default=None,
              help="Where the robot was: wheels in the air or on the floor. Default: stated by the sweep, "
                   "square-wave and RC layouts (in the air); for the floor-run layout read off the wheels' "
                   "dynamics (the logged duties replayed through the robot file in both modes, the wheel's "
                   "inertia and lag profiled: one best wheel-speed NRMSE at most half the other's), else "
                   "unknown (fit, predict and diagnose profile over both and say which they kept). A "
                   "statement the layout or the data contradict is refused.")
@click.option("--direction", type=click.Choice(["forward", "sideways", "rotation", "diagonal"]), default=None,
              help="Which axis a floor run (results_ground_*.mat) drove: each wheel's duty is its sign in "
                   "the kinematics times the logged drive value. Default: read off the data (the sign of "
                   "each wheel's travel against the command); a log that disagrees with the given one is refused.")
@click.option("--force", is_flag=True,
              help="Import as --where / --sketch say even when the file's layout or its data say otherwise "
                   "(the run's conditions record what the option overrode).")
@click.option("--out", "out", default=Path("runs"), show_default=True,
              type=NonEmptyPath(path_type=Path), help="Folder that receives the run directories.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def tfm(files: tuple[Path, ...], signs: str | None, sketch: str | None, direction: str | None, where: str | None,
        force: bool, out: Path, as_json: bool) -> None:
    """Import 2019 thesis logs: results_jacked.mat (upside-down sweep), square_*.mat (step responses),
    results_ground_x.mat (step responses on the floor), inputs.mat (RC-driven random duty), or any
    log in one of these layouts. Every condition the file does not state (where the robot was, the
    sketch, the sign map, a floor run's direction) is read off the data or kept unknown, and run.json
    `conditions` records each with how it was decided and the statistic (docs/run-format.md)."""
    from omnibench.cli import verbosity
    from omnibench.runs import read_run
    from omnibench.runs.check import check_out_folder
    from omnibench.runs.tfm import file_digest, import_tfm, parse_signs

    check_out_folder(out)
    sign_map = parse_signs(signs) if signs is not None else None
    quiet = verbosity() < 0
    earlier = _imported(out)
    results = []
    for f in files:
        try:
            digest = file_digest(f)
        except OSError as exc:
            raise UserError(f"{f}: cannot read ({exc.strerror or type(exc).__name__})") from None
        if digest in earlier:
            path, info = earlier[digest]
            _check_same_options(f, path, info, sign_map, sketch, where)
            run = read_run(path)
            results.append({"file": str(f), "run": str(path), "procedure": run.procedure, "already_imported": True,
                            "steps": int(len(run.steps)), "samples": int(len(run.samples))})
            if not as_json:
                click.echo(str(path) if quiet else f"{f}: already imported as {path} (same file): nothing changed")
            continue
        path = import_tfm(f, out, signs=sign_map, sketch=sketch, direction=direction, where=where, force=force)
        run = read_run(path)
        info = run.info
        earlier[digest] = (path, info)
        results.append({"file": str(f), "run": str(path), "procedure": run.procedure, "already_imported": False,
                        "steps": int(len(run.steps)), "samples": int(len(run.samples)),
                        "sign_map": info.sign_map, "mode": info.mode, "firmware_timing": info.firmware_timing,
                        "conditions": info.raw.get("conditions"),
                        **({"direction": info.direction} if info.direction else {})})
        if as_json:
            continue
        if quiet:  # the one line a script needs
            click.echo(str(path))
            continue
        ft = info.firmware_timing or {}
        place = {"ground": "on the floor", "upside_down": "in the air"}.get(str(info.mode), "where unknown")
        place += f", driving {info.direction}" if info.direction and info.mode == "ground" else ""
        if ft.get("sketch") == "unknown":
            firmware = (f"firmware unknown (neither the file nor its loop tells the sketch): profiled over {', '.join(ft.get('profiled_over', []))}, "
                        f"replayed by default with {ft.get('default_sketch')}'s timing")
        else:
            firmware = (f"firmware {ft.get('sketch')}: commands sent in wheel order {ft['command_order']}, "
                        f"{1000 * ft.get('packet_s', 0):.2f} ms apart, {ft.get('commands', '')}")
        click.echo(f"{f}: {run.procedure} run with {len(run.steps)} steps and "
                   f"{len(run.samples)} samples -> {path} (sign map {info.sign_map}, {place}; {firmware})")
        for name, c in (info.raw.get("conditions") or {}).items():
            click.echo(f"  {name}: {_shown(c.get('value'))} ({c.get('decided')}"
                       + (f": {c['evidence']}" if c.get("evidence") else "") + ")")
    if as_json:
        click.echo(json.dumps(results, indent=2))


def _imported(out: Path) -> dict[str, tuple[Path, RunInfo]]:
    """Runs already imported into `out`, by the SHA-256 of their source file."""
    found: dict[str, tuple[Path, RunInfo]] = {}
    for run_dir in run_dirs(out):
        try:
            info = read_info(run_dir)
        except UserError:
            continue  # not ours to judge here; the analysis commands name unreadable runs
        if info.source_sha256 is not None:
            found.setdefault(info.source_sha256, (run_dir, info))
    return found


def _check_same_options(f: Path, path: Path, info: RunInfo, sign_map: Any, sketch: str | None,
                        where: str | None = None) -> None:
    """A second import of the same file with other --signs, --sketch or --where is refused: the folder
    would hold the same log twice, and every later analysis would count it twice."""
    if sign_map is not None and list(sign_map) != list(info.sign_map or []):
        raise UserError(f"{f}: already imported as {path} with sign map {info.sign_map}; remove that run "
                        "to import it again with other --signs, or give another --out")
    timing = info.firmware_timing or {}
    if sketch is not None and sketch != _sketch_key(timing):
        raise UserError(f"{f}: already imported as {path} with the {timing.get('sketch')} timing; remove that run "
                        "to import it again with another --sketch, or give another --out")
    was = {"upside_down": "air", "ground": "floor"}.get(str(info.mode))
    if where is not None and where != was:
        raise UserError(f"{f}: already imported as {path} with where {was or 'unknown'}; remove that run "
                        "to import it again with another --where, or give another --out")


def _sketch_key(timing: dict[str, Any]) -> str | None:
    from omnibench.runs.tfm import SKETCHES

    return next((k for k, v in SKETCHES.items() if v.get("sketch") == timing.get("sketch")), None)


@command.command("csv")
@click.argument("files", nargs=-1, required=True, type=NonEmptyPath(path_type=Path))
@click.option("--map", "map_file", required=True, metavar="MAP",
              help="Map file (TOML) naming the columns, their units and what is known of the log "
                   "(docs/run-format.md); or the name of a shipped map: "
                   "omnibench-samples, tfm-square-serial, example.")
@click.option("--out", "out", default=Path("runs"), show_default=True,
              type=NonEmptyPath(path_type=Path), help="Folder that receives the run directories.")
@click.option("--robot", "robot_file", default=None, type=NonEmptyPath(path_type=Path),
              help="Robot file of the robot that was logged (else the map's, else the shipped Omnibot).")
@click.option("--procedure", default=None, type=click.Choice(["step_response", "random_duty"]),
              help="What the log is: square waves (step_response) or a hand-driven trace (random_duty); "
                   "else the map's.")
@click.option("--where", default=None, type=click.Choice(["air", "floor"]),
              help="Where the robot was: wheels in the air or on the floor (else the map's, the file "
                   "name's, the data's, or unknown). A statement the map or the data contradict is refused.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def csv(files: tuple[Path, ...], map_file: str, out: Path, robot_file: Path | None, procedure: str | None,
        where: str | None, as_json: bool) -> None:
    """Import your own logs, CSV or other delimited text, with a map of their columns: one run per
    FILE, replayed whole by fit, predict and diagnose. Every condition a log does not state is read
    off the data (with its statistic) or recorded as unknown, in run.json `conditions`."""
    from omnibench.cli import verbosity
    from omnibench.runs import read_run
    from omnibench.runs.check import check_out_folder
    from omnibench.runs.csv_import import Options, load_map, read_log, shipped_map, write_run
    from omnibench.runs.tfm import file_digest

    check_out_folder(out)
    fmap = load_map(shipped_map(map_file))
    opts = Options(where=where, procedure=procedure, robot_file=robot_file)
    quiet = verbosity() < 0
    earlier = _imported(out)
    todo: dict[str, tuple[Path, Any]] = {}  # digest -> (file, log) to write
    plan: list[tuple[Path, str, dict[str, Any] | None]] = []  # each file: its digest, and its earlier run
    for f in files:  # every file read and decided before anything is written
        try:
            digest = file_digest(f)
        except OSError as exc:
            raise UserError(f"{f}: cannot read ({exc.strerror or type(exc).__name__})") from None
        log = read_log(f, fmap, opts)
        if digest in earlier:
            path, info = earlier[digest]
            _check_same_reading(f, path, info, fmap.sha256, log)
            plan.append((f, digest, {"file": str(f), "run": str(path), "already_imported": True}))
            continue
        todo.setdefault(digest, (f, log))
        plan.append((f, digest, None))
    written: dict[str, dict[str, Any]] = {}
    for digest, (f, log) in todo.items():
        path = write_run(log, out)
        run = read_run(path)
        written[digest] = {"file": str(f), "run": str(path), "procedure": run.procedure, "already_imported": False,
                           "steps": int(len(run.steps)), "samples": int(len(run.samples)),
                           "conditions": run.info.raw.get("conditions")}
    ordered: list[dict[str, Any]] = []
    first: set[str] = set()
    for f, digest, before in plan:
        if before is not None:
            ordered.append(before)
        elif digest in first:  # the same bytes again in this command: imported once
            ordered.append({"file": str(f), "run": written[digest]["run"], "already_imported": True})
        else:
            first.add(digest)
            ordered.append(written[digest])
    if as_json:
        click.echo(json.dumps(ordered, indent=2))
        return
    for r in ordered:
        if quiet:
            click.echo(r["run"])
        elif r["already_imported"]:
            click.echo(f"{r['file']}: already imported as {r['run']} (same file, same map): nothing changed")
        else:
            click.echo(f"{r['file']}: {r['procedure']} run with {r['steps']} steps and {r['samples']} samples "
                       f"-> {r['run']}")
            for name, c in (r["conditions"] or {}).items():
                click.echo(f"  {name}: {_shown(c.get('value'))} ({c.get('source')})")


def _shown(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    return "unknown" if value is None else str(value)


def _check_same_reading(f: Path, path: Path, info: RunInfo, map_sha: str, log: Any) -> None:
    """A file imported before (into --out) is imported again only as it was: with another map or
    other conditions it would be a second reading of the same log, counted twice by every analysis."""
    raw = info.raw
    if raw.get("csv_map_sha256") != map_sha:
        raise UserError(f"{f}: already imported as {path} with another map ({raw.get('csv_map')}); remove that run "
                        "to import it again, or give another --out")
    before = raw.get("conditions") or {}
    for key in ("procedure", "where", "signs", "duty_timing", "direction"):
        old = (before.get(key) or {}).get("value")
        new = (log.conditions.get(key) or {}).get("value")
        if old != new:
            raise UserError(f"{f}: already imported as {path} with {key} {_shown(old)}, now {_shown(new)}; remove "
                            "that run to import it again, or give another --out")
