"""The corrupted-run-file matrix (issue 38): every field of run.json and steps.jsonl, and every
column of a samples.csv row, x a bad kind (wrong type, NaN, inf, huge, negative, missing, a
path trick) over the commands that read runs: fit, validate-energy, predict, diagnose,
`sweep --resume` and `campaign --resume`.

Each case is a copy of a good run with one field of one file damaged. It is classified:

- clear: non-zero exit, ONE line on stderr starting "omnibench:", and when the reader refused the
  file, the line names the file (run.json / steps.jsonl) and the field;
- correct: exit 0 on a value the reader accepts, with every observation of the good run kept
  (nothing silently dropped), no NaN in what was written and, for a resume, a run fit accepts;
- unclear: refused, but the line names neither the file nor the field;
- silent: exit 0 on a value the reader refuses, or rows dropped, or a NaN written;
- internal: a traceback, "internal error", or more than one line;
- escape: a file written outside --out/--plots (the run id's path trick), or a refused
  command changed a file;
- hang: no answer within the time limit.

diagnose and campaign do seconds of work on an accepted run: they get only the cases the reader
refuses (they must fail at validation, before any heavy compute). Used by
tests/reliability/test_run_matrix.py (a subset) and benchmarks/reliability.py (all).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from reliability.badinput import ROOT, SIM, _state, make_fixture, run_cli

OUTCOMES = ("clear", "correct", "unclear", "silent", "internal", "escape", "hang")
ESCAPE = "escape-RUNMATRIX"
MISSING = object()
KINDS = ("wrong type", "nan", "inf", "huge", "negative", "missing", "path trick")
COMMANDS = ("fit", "validate-energy", "predict", "diagnose", "resume", "campaign")
#: Commands that do heavy work on an accepted run: only the cases the reader refuses go to them.
HEAVY = ("diagnose", "campaign")
MODEL = str(ROOT / "omnibench" / "model" / "omnibot.toml")


def bad_value(kind: str, good: Any) -> Any:
    """The value a damaged field gets (MISSING: the key is removed)."""
    if kind == "wrong type":
        if isinstance(good, bool):
            return "yes"
        if isinstance(good, (int, float)):
            return "abc"
        return 12345 if isinstance(good, str) else "abc"
    return {"nan": float("nan"), "inf": float("inf"), "huge": 1e308, "negative": -1, "missing": MISSING,
            "path trick": f"x/../../../../{ESCAPE}"}[kind]


@dataclass
class Damage:
    file: str   # "run.json" | "steps.jsonl" | "samples.csv"
    field: str
    kind: str
    run: str    # "sweep" | "energy"

    @property
    def name(self) -> str:
        return f"{self.run} {self.file} {self.field} {self.kind}"


def _set(doc: dict[str, Any], key: str, value: Any) -> None:
    if value is MISSING:
        doc.pop(key, None)
    else:
        doc[key] = value


def apply(d: Path, dmg: Damage, good: Any) -> None:
    """Damage run folder `d` (a copy): one field of one file (line 2 of steps.jsonl, or its only line)."""
    if dmg.file == "samples.csv":
        lines = (d / "samples.csv").read_text().splitlines()
        header = lines[0].split(",")
        cells = lines[SAMPLE_LINE - 1].split(",")
        cells[header.index(dmg.field)] = SAMPLE_BAD[dmg.kind]
        lines[SAMPLE_LINE - 1] = ",".join(cells)
        (d / "samples.csv").write_text("\n".join(lines) + "\n")
        return
    value = bad_value(dmg.kind, good)
    if dmg.file == "run.json":
        doc = json.loads((d / "run.json").read_text())
        _set(doc, dmg.field, value)
        (d / "run.json").write_text(json.dumps(doc, indent=2, allow_nan=True))
    else:
        lines = (d / "steps.jsonl").read_text().splitlines()
        k = _line(lines)
        rec = json.loads(lines[k])
        _set(rec, dmg.field, value)
        lines[k] = json.dumps(rec, allow_nan=True)
        (d / "steps.jsonl").write_text("\n".join(lines) + "\n")


#: samples.csv: the line damaged (a sample of the first step) and the text each kind writes.
SAMPLE_LINE = 6
SAMPLE_BAD = {"wrong type": "abc", "nan": "nan", "inf": "inf", "huge": "1e308", "negative": "-1",
              "missing": "", "path trick": f"x/../../../../{ESCAPE}"}


def _line(lines: list[str]) -> int:
    """The step record damaged: the second (a middle one), or the only one."""
    return 1 if len(lines) > 1 else 0


def damages(runs: dict[str, Path]) -> list[tuple[Damage, Any]]:
    """Every (damage, the field's good value) over both runs' run.json and steps.jsonl."""
    out = []
    for which, d in runs.items():
        meta = json.loads((d / "run.json").read_text())
        lines = (d / "steps.jsonl").read_text().splitlines()
        rec = json.loads(lines[_line(lines)])
        for file, doc in (("run.json", meta), ("steps.jsonl", rec)):
            for key, good in doc.items():
                for kind in KINDS:
                    out.append((Damage(file, key, kind, which), good))
        for col in (d / "samples.csv").read_text().splitlines()[0].split(","):
            for kind in KINDS:
                out.append((Damage("samples.csv", col, kind, which), None))
    return out


def reader_verdict(d: Path) -> str | None:
    """The one-line reason the validating reader refuses run `d` for analysis (None: accepted)."""
    from omnibench.runs.check import run_problem

    return run_problem(d)


def _rows(d: Path) -> dict[str, int]:
    from omnibench.analysis.observations import PROCEDURES, Observations

    obs = Observations.from_runs([d])
    return {p: len(obs.table(p)) for p in PROCEDURES}


def _escaped(root: Path) -> bool:
    for anc in [root, *list(root.parents)[:5]]:
        try:
            if any(ESCAPE in p.name for p in anc.iterdir()):
                return True
        except OSError:
            continue
    return any(ESCAPE in p.name for p in root.rglob(f"*{ESCAPE}*"))


def argv_for(cmd: str, d: Path, out: Path) -> list[str]:
    return {
        "fit": ["fit", str(d), "--out", str(out / "model.toml"), "--no-per-wheel", "--json"],
        "validate-energy": ["validate-energy", str(d), "--model", MODEL, "--plots", str(out / "plots"), "--json"],
        "predict": ["predict", str(d), "--model", MODEL, "--plots", str(out / "plots"), "--json"],
        "diagnose": ["diagnose", str(d), "--model", MODEL, "--procedures", "sweep", "--out",
                     str(out / "diagnosis.json")],
        "resume": ["sweep", "--port", SIM, "--resume", str(d)],
        "campaign": ["campaign", "--port", SIM, "--out", str(d.parent.parent), "--resume"],
    }[cmd]


def classify(code: int | None, err: str, dmg: Damage, refused_by_reader: str | None, *, changed: bool,
             escaped: bool, dropped: bool = False, nan: bool = False, resumed_bad: bool = False) -> str:
    if escaped or (changed and code != 0):
        return "escape"
    if code is None:
        return "hang"
    if "internal error" in err or "Traceback" in err:
        return "internal"
    lines = [x for x in err.strip().splitlines() if x.strip()]
    if code == 0:
        if refused_by_reader or dropped or nan or resumed_bad:
            return "silent"
        return "correct"
    if len(lines) != 1 or not lines[0].startswith("omnibench:"):
        return "internal"
    if refused_by_reader and (dmg.file not in lines[0] or dmg.field not in lines[0]):
        return "unclear"
    return "clear"


def _has_nan(out: Path) -> bool:
    for p in out.rglob("*"):
        if p.is_file() and p.suffix in (".json", ".toml", ".md", ".csv"):
            if re.search(r"\bnan\b", p.read_text(errors="replace"), flags=re.I):
                return True
    return False


def run_matrix(root: Path | None = None, commands: tuple[str, ...] = COMMANDS,
               select: Callable[[int, Damage, str], bool] | None = None,
               progress: Callable[[str], None] | None = None,
               run_accepted: Callable[[Damage], bool] = lambda dmg: True,
               ) -> tuple[dict[str, dict[str, int]], list[str]]:
    """Run the matrix: counts per command and outcome, and a line per case not clear/correct.
    `select(i, damage, command)` keeps a subset (the test's); a case the reader accepts (a whole
    analysis or resume: seconds) runs only for the damages `run_accepted(damage)` keeps."""
    own = root is None
    root = Path(tempfile.mkdtemp(prefix="omnibench-runmatrix-")) if own else Path(root)
    cwd = os.getcwd()
    counts = {c: {k: 0 for k in OUTCOMES} for c in commands}
    worst: list[str] = []
    try:
        (root / "cwd").mkdir(parents=True, exist_ok=True)
        os.chdir(root / "cwd")
        runs = make_fixture(root)
        good_rows = {k: _rows(v) for k, v in runs.items()}
        for i, (dmg, good) in enumerate(damages(runs)):
            for cmd in commands:
                if (cmd == "validate-energy") != (dmg.run == "energy"):
                    continue
                if select is not None and not select(i, dmg, cmd):
                    continue
                case = root / "case"
                shutil.rmtree(case, ignore_errors=True)
                d = case / "campaign" / "runs" / runs[dmg.run].name
                shutil.copytree(runs[dmg.run], d)
                if cmd == "resume":  # an interrupted run, so resuming it is the point
                    meta = json.loads((d / "run.json").read_text())
                    meta["status"] = "aborted"
                    (d / "run.json").write_text(json.dumps(meta, indent=2))
                apply(d, dmg, good)
                why = reader_verdict(d) if cmd != "resume" else _resume_verdict(d)
                if why is None and (cmd in HEAVY or not run_accepted(dmg)):
                    continue
                out = root / "out"
                shutil.rmtree(out, ignore_errors=True)
                out.mkdir()
                watch = root / "case"
                before = _state(watch)
                code, err = run_cli(argv_for(cmd, d, out), 120)
                after = _state(watch)
                changed = any(after.get(p) != v for p, v in before.items()) or (
                    code != 0 and any(p not in before for p in after))
                if code == 0 and cmd in ("resume", "campaign"):
                    changed = False  # a resume writes its run: that is its job
                dropped = nan = resumed_bad = False
                if code == 0 and cmd in ("fit", "predict", "validate-energy"):
                    dropped = _rows(d) != good_rows[dmg.run]
                    nan = _has_nan(out)
                if code == 0 and cmd == "resume":
                    resumed_bad = reader_verdict(d) is not None
                outcome = classify(code, err, dmg, why, changed=changed, escaped=_escaped(root), dropped=dropped,
                                   nan=nan, resumed_bad=resumed_bad)
                counts[cmd][outcome] += 1
                if outcome not in ("clear", "correct"):
                    last = (err.strip().splitlines() or [""])[-1][:200]
                    worst.append(f"{outcome}: {cmd} {dmg.name}: exit {code}: {last}"
                                 + (f" (reader: {why})" if why and outcome == "silent" else "")
                                 + (" (rows dropped)" if dropped else "") + (" (NaN written)" if nan else "")
                                 + (" (resumed run refused by fit)" if resumed_bad else ""))
                    if progress:
                        progress(worst[-1])
                for p in root.parent.glob(f"*{ESCAPE}*"):
                    p.unlink()
        return counts, worst
    finally:
        os.chdir(cwd)
        if own:
            shutil.rmtree(root, ignore_errors=True)


def _resume_verdict(d: Path) -> str | None:
    """Why `--resume` must refuse `d` (None: it may resume it)."""
    from omnibench.errors import UserError
    from omnibench.runs.record import check_resumable

    try:
        check_resumable(d)
    except UserError as exc:
        return str(exc)
    return None


def total(counts: dict[str, dict[str, int]]) -> dict[str, int]:
    out = {k: 0 for k in OUTCOMES}
    for per in counts.values():
        for k, v in per.items():
            out[k] += v
    return out


