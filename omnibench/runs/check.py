"""Is a run fit for analysis? Analysis commands refuse incomplete or corrupt runs (or skip
them by name with --skip-bad), never read the same run twice, and never write over a run.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from pathlib import Path

from omnibench.errors import UserError


def run_problem(path: Path) -> str | None:
    """Why run directory `path` cannot be analysed (None: it can)."""
    from omnibench.runs import read_run

    try:
        meta = json.loads((path / "run.json").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        return f"run.json unreadable ({type(exc).__name__})"
    if not isinstance(meta, dict):
        return "run.json is not a run description"
    if meta.get("status") != "complete":
        return f"run is {meta.get('status')!r}, not complete (resume it, or leave it out)"
    if not (path / "samples.csv").is_file():
        return "samples.csv is missing"
    steps = path / "steps.jsonl"
    if steps.is_file():
        for n, line in enumerate(steps.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            try:
                rec = json.loads(line) if line.strip() else {}
            except json.JSONDecodeError:
                return f"steps.jsonl line {n} is not JSON"
            if line.strip() and not (isinstance(rec, dict) and "step" in rec):
                return f"steps.jsonl line {n} is not a step record"
    try:
        run = read_run(path)
    except UserError as exc:
        return str(exc)
    except Exception as exc:  # noqa: BLE001 - any unreadable file makes the run corrupt
        return f"unreadable ({type(exc).__name__})"
    planned = meta.get("steps_planned")
    if isinstance(planned, int) and len(run.steps) < planned:
        return f"{len(run.steps)} of {planned} steps recorded"
    for _, st in run.steps.iterrows():
        t_end = st.get("t_end")
        if isinstance(t_end, float) and math.isfinite(t_end):
            s = run.step_samples(int(st["step"]))
            if not len(s) or float(s["t"].max()) < t_end - 1e-6:
                return f"samples.csv is cut: step {int(st['step'])} has no samples up to its end"
    return None


def checked_runs(paths: Iterable[str | Path], *, skip_bad: bool = False,
                 echo: Callable[[str], None] | None = None) -> list[Path]:
    """The run directories under `paths`, each once; UserError naming a bad run (or, with
    `skip_bad`, a line per skipped run and the good ones; UserError if none is left)."""
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
            raise UserError(f"{d}: {why} (--skip-bad leaves such runs out)")
    if not good:
        raise UserError("no usable run left after skipping the bad ones")
    return good


def check_output(out: Path, runs: Iterable[Path] = ()) -> None:
    """Refuse an output file that is a directory or lies in a run directory (never write over
    a run's files)."""
    out = Path(out)
    if out.is_dir():
        raise UserError(f"--out {out}: is a directory; give a file name")
    parent = out.resolve().parent
    if (parent / "run.json").is_file() or any(parent == Path(r).resolve() for r in runs):
        raise UserError(f"--out {out}: is inside the run directory {parent}; write elsewhere (a run's files are "
                        "never overwritten)")
