"""Is a run fit for analysis? Analysis commands refuse incomplete or corrupt runs (or skip
them by name with --skip-bad), never read the same run twice, and never write over a run.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from omnibench.errors import UserError
from omnibench.files import check_new_output, check_writable_folder
from omnibench.runs.record import read_info, refuse_duplicate_ids, sample_header


def run_problem(path: Path) -> str | None:
    """Why run directory `path` cannot be analysed (None: it can). Every file is validated by
    the one reader (omnibench.runs.record): the reason names the file, the line and the field."""
    from omnibench.runs import read_run
    from omnibench.runs.record import duties_disagree, missing_for_analysis, unmeasured

    try:
        run = read_run(path)
    except UserError as exc:
        return str(exc)
    info = run.info or read_info(path)
    if info.status != "complete":
        return f"run is {info.status!r}, not complete (resume it, or leave it out)"
    if not (path / "samples.csv").is_file():
        return "samples.csv is missing"
    if sample_header(path / "samples.csv") is None:
        return f"{path / 'samples.csv'}:1: no complete header line"
    why = missing_for_analysis(path, info)
    if why:
        return why
    why = unmeasured(path, run.samples)
    if why:
        return why
    why = duties_disagree(path, run.steps.to_dict("records"), run.samples)
    if why:
        return why
    planned = info.steps_planned
    if planned is not None and len(run.steps) < planned:
        return f"{len(run.steps)} of {planned} steps recorded"
    for _, st in run.steps.iterrows():
        t_end = st.get("t_end")
        if isinstance(t_end, float) and math.isfinite(t_end):
            s = run.step_samples(int(st["step"]))
            if not len(s) or float(s["t"].max()) < t_end - 1e-6:
                return f"samples.csv is cut: step {int(st['step'])} has no samples up to its end"
    return None


def checked_runs(paths: Iterable[str | Path], *, skip_bad: bool = False,
                 echo: Callable[[str], None] | None = None, allow_mixed: bool = False,
                 model: tuple[str, Mapping[str, Any]] | None = None) -> list[Path]:
    """The run directories under `paths`, each once; UserError naming a bad run (or, with
    `skip_bad`, a line per skipped run and the good ones; UserError if none is left), or two
    runs of different robots, boards or worlds (unless `allow_mixed`: then a warning line).
    model: (its name, `provenance.model_build(robot)`) of the model the runs are predicted with,
    checked against them the same way."""
    from omnibench.runs import find_runs

    dirs: list[Path] = []
    seen: dict[Path, Path] = {}
    for p in paths:
        p = Path(p)
        if not p.exists():
            raise UserError(f"{p}: no such run directory")
        found = find_runs(p) if p.is_dir() else []
        if not found:
            raise UserError(f"{p}: no run directory here (no run.json)")
        for d in found:
            key = d.resolve()
            if key in seen:
                raise UserError(f"{d}: the same run is given twice (as {seen[key]}): each run counts once")
            seen[key] = d
            dirs.append(d)
    good = []
    for d in dirs:
        why = run_problem(d)
        if why is None:
            good.append(d)
        elif skip_bad:
            (echo or print)(f"skipping {d}: {why}")
        else:
            where = "" if why.startswith(str(d)) else f"{d}: "
            raise UserError(f"{where}{why} (--skip-bad leaves such runs out)")
    if not good:
        raise UserError("no usable run left after skipping the bad ones")
    infos = [read_info(d) for d in good]
    refuse_duplicate_ids(infos)
    from omnibench.runs.provenance import refuse_mixed

    named: list[tuple[str, Mapping[str, Any]]] = [(str(i.path), i.raw) for i in infos]
    refuse_mixed(([model] if model is not None else []) + named, allow_mixed=allow_mixed,
                 warn=echo or (lambda line: print(line, file=sys.stderr)))
    return good


def check_output(out: Path, runs: Iterable[Path] = (), *, force: bool | None = None) -> None:
    """Refuse an output file that is a directory, lies in a run directory (never write over a
    run's files) or cannot be written; with `force` given (a model file), also one that exists
    and was not written by the tool, unless `force` is True."""
    out = Path(out)
    if out.is_dir():
        raise UserError(f"--out {out}: is a directory; give a file name")
    if force is not None:
        check_new_output(out, "--out", force=force)
    parent = out.resolve().parent
    if (parent / "run.json").is_file() or any(parent == Path(r).resolve() for r in runs):
        raise UserError(f"--out {out}: is inside the run directory {parent}; write elsewhere (a run's files are "
                        "never overwritten)")
    check_writable_folder(out.parent, "--out")


def in_run(path: Path) -> Path | None:
    """The run directory that `path` is, or lies in (None: not in a run)."""
    p = Path(path).resolve()
    for d in (p, *p.parents):
        if (d / "run.json").is_file():
            return d
    return None


def check_out_folder(path: Path, option: str = "--out") -> None:
    """Refuse an output folder that is an existing file or lies in a run directory."""
    if Path(path).exists() and not Path(path).is_dir():
        raise UserError(f"{option} {path}: is a file, not a folder")
    run = in_run(path)
    if run is not None:
        raise UserError(f"{option} {path}: is inside the run directory {run}; write elsewhere (a run's files "
                        "are never overwritten)")
    check_writable_folder(path, option)
