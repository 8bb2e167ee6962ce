"""The validating reader of run files: a typed run record (`RunInfo`) and checked step records.

Every value read from a run directory is checked here before any other module sees it: the
type, the range and the finiteness of every field of run.json and of every step record in
steps.jsonl, every cell of samples.csv, and the run id (a safe name: it becomes part of file
names such as ``predict_<run id>.png``, so it must never hold a path separator or ``..``).

Every failure is a `RunFileError` (a `UserError`: one line, exit 2) naming the file, the line
and the field, e.g. ``runs/x/steps.jsonl:7: w1: "fast" is not a number``. Nothing is dropped
without a word: a bad value is an error, never a silently skipped point.

See docs/run-format.md for the fields and their units.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import re
import signal
import threading
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from omnibench.errors import UserError

FORMAT = "omnibench-run"
RUN_FILE = "run.json"  #: a run directory's description (its presence makes a folder a run directory)
FORMAT_VERSION = 1
STATUSES = ("running", "complete", "aborted", "failed")

#: Columns of samples.csv, in order. Units: t s, u duty [-1, 1], enc counts, phi rad,
#: i A (motor current, may be empty), V_batt V, I_batt A (may be empty), faults int bitmask.
SAMPLE_COLUMNS: tuple[str, ...] = (
    "segment",
    "step",
    "t",
    "seq",
    "u1", "u2", "u3", "u4",
    "enc1", "enc2", "enc3", "enc4",
    "phi1", "phi2", "phi3", "phi4",
    "i1", "i2", "i3", "i4",
    "V_batt",
    "I_batt",
    "faults",
)

#: A run id (and a procedure name): a letter or digit, then letters, digits and ``. _ + - @ = #``,
#: at most 200 characters, never ``..``. It names files (plots) and keys the analysis' rows.
SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+@=#-]{0,199}")

#: Largest magnitude accepted for a number the schema does not bound more tightly.
HUGE = 1e12


class RunFileError(UserError):
    """A run file holds something the reader refuses: one line naming file, line and field."""


def safe_name(text: str) -> str:
    """`text` with every character a run id may not hold replaced by ``_`` (and ``..`` broken)."""
    s = re.sub(r"[^A-Za-z0-9._+@=#-]", "_", text)[:200] or "run"
    s = s.replace("..", "._")
    return s if s[0].isalnum() else "r" + s[:199]


def is_safe_name(text: Any) -> bool:
    """True if `text` is a string usable as a run id (see SAFE_NAME)."""
    return isinstance(text, str) and SAFE_NAME.fullmatch(text) is not None and ".." not in text


# ------------------------------------------------------------------------------ field kinds
@dataclass(frozen=True)
class Num:
    """A finite number in [lo, hi] (None allowed when `null`)."""

    lo: float = -HUGE
    hi: float = HUGE
    null: bool = True
    integer: bool = False


@dataclass(frozen=True)
class Kind:
    """A JSON value of the given Python types (None allowed when `null`), optionally one of `choices`."""

    types: tuple[type, ...]
    null: bool = True
    choices: tuple[Any, ...] | None = None


STR = Kind((str,))
BOOL = Kind((bool,))
DICT = Kind((dict,))
LIST = Kind((list,))
DUTY = Num(-1.0 - 1e-9, 1.0 + 1e-9)
TIME = Num(-1e9, 1e9)
SPEED = Num(-1e4, 1e4)            # rad/s
CURRENT = Num(-1e4, 1e4)          # A
LENGTH = Num(-1e4, 1e4)           # m
ANGLE = Num(-1e6, 1e6)            # rad
COUNT = Num(0, 1e12, integer=True)

#: run.json: key -> kind. Keys not listed may hold any JSON, but no non-finite number.
RUN_FIELDS: dict[str, Num | Kind] = {
    "format": Kind((str,), null=False, choices=(FORMAT,)),
    "format_version": Num(1, FORMAT_VERSION, null=False, integer=True),
    "run_id": STR,
    "procedure": Kind((str,), null=False),
    "procedure_file": STR, "procedure_text": STR, "robot_file": STR, "port": STR,
    "tool": STR, "tool_version": STR, "started": STR, "ended": STR, "reason": STR,
    "status": Kind((str,), null=False, choices=STATUSES),
    "robot": DICT, "board": DICT, "boards": LIST, "plan": DICT, "settings": DICT, "link": DICT,
    "wiring": DICT, "provenance": DICT, "firmware_timing": DICT, "fitted_gains": DICT,
    "counts_per_rev": Num(1e-9, 1e9),
    "steps_planned": Num(0, 1e6, integer=True),
    "steps_complete": Num(0, 1e6, integer=True),
    "segments": LIST,
    "operator_answers": LIST,
    "operator": STR,
    "mode": Kind((str,), choices=("ground", "upside_down")),
    "imported": BOOL,
    "supply_voltage": Num(1e-9, 1e4),
    "duty_timing": STR,
    "conditions": DICT, "csv_layout": DICT,
}

#: steps.jsonl: key -> kind (units in docs/run-format.md). Other keys: any JSON, finite numbers.
STEP_FIELDS: dict[str, Num | Kind] = {
    "step": Num(0, 1e6, null=False, integer=True),
    "segment": Num(0, 1e6, null=False, integer=True),
    "kind": STR, "label": STR, "trajectory": STR, "trajectory_kind": STR,
    "mode": Kind((str,), choices=("ground", "upside_down")),
    "wheel_set": Kind((str, int)),
    "payload": Num(0, 1e4),
    "direction": Num(-1, 1),
    "duty": DUTY, **{f"u{j}": DUTY for j in range(1, 5)},
    "voltage": Num(-1e4, 1e4),
    **{f"wheel_mass{j}": Num(0, 1e4) for j in range(1, 5)},
    "t_start": TIME, "t_end": TIME, "t_hold": TIME, "t_rest": TIME, "t_drive_end": TIME,
    "hold_time": Num(0, 1e9), "duration": Num(0, 1e9), "average": Num(0, 1e9),
    **{f"w{j}": SPEED for j in range(1, 5)},
    **{f"w_std{j}": Num(0, 1e4) for j in range(1, 5)},
    **{f"i{j}": CURRENT for j in range(1, 5)},
    "V_batt": Num(-1e4, 1e4), "I_batt": CURRENT, "I_batt_mean": CURRENT, "I_batt_peak": CURRENT,
    **{f"dphi{j}": Num(-1e9, 1e9) for j in range(1, 5)},
    "encoder_distance": LENGTH, "kin_forward": LENGTH, "kin_left": LENGTH, "kin_yaw": ANGLE,
    "measured_distance": Num(0, 1e4), "measured_forward": LENGTH, "measured_left": LENGTH,
    "slip": LENGTH, "kin_residual": LENGTH, "no_slip_tolerance": Num(0, 1e4),
    "heading": ANGLE, "speed": Num(-1e3, 1e3), "v1": Num(-1e3, 1e3), "v2": Num(-1e3, 1e3),
    "psi_dot": Num(-1e4, 1e4),
    "energy": Num(-1e9, 1e9), "charge": Num(-1e9, 1e9),
    "steady": BOOL, "no_slip": BOOL, "has_current": BOOL, "has_samples": BOOL,
    "repetition": Num(0, 1e6, integer=True), "samples_rejected": COUNT, "n_samples": COUNT,
    "samples_used": COUNT, "current_samples": COUNT, "n_segments": COUNT, "tape_questioned": BOOL,
    "command": Num(-1e4, 1e4),
    "segments": LIST,
}

#: Step fields the analysis cannot do without, by procedure (a missing one would drop a point).
REQUIRED_STEP_FIELDS: dict[str, tuple[str, ...]] = {
    "upside_down_sweep": ("w1", "w2", "w3", "w4"),
}

#: samples.csv: column -> (lo, hi) of its numbers (empty cells are "not measured").
SAMPLE_RANGES: dict[str, tuple[float, float]] = {
    "segment": (0, 1e6), "step": (0, 1e6), "t": (-1e9, 1e9), "seq": (-1e15, 1e15),
    **{f"u{j}": (-1.0 - 1e-9, 1.0 + 1e-9) for j in range(1, 5)},
    **{f"enc{j}": (-1e15, 1e15) for j in range(1, 5)},
    **{f"phi{j}": (-1e12, 1e12) for j in range(1, 5)},
    **{f"i{j}": (-1e4, 1e4) for j in range(1, 5)},
    "V_batt": (-1e4, 1e4), "I_batt": (-1e4, 1e4), "faults": (0, 2 ** 32),
}


def _show(v: Any) -> str:
    text = json.dumps(v) if not isinstance(v, float) else repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


def check_value(value: Any, kind: Num | Kind) -> str | None:
    """Why `value` does not fit `kind` (None: it does)."""
    if value is None:
        return None if kind.null else "is missing (null)"
    if isinstance(kind, Num):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"{_show(value)} is not a number"
        if not math.isfinite(value):
            return f"{_show(value)} is not a finite number"
        if kind.integer and value != int(value):
            return f"{_show(value)} is not a whole number"
        if not kind.lo <= value <= kind.hi:
            return f"{_show(value)} is outside [{kind.lo:g}, {kind.hi:g}]"
        return None
    if not isinstance(value, kind.types) or (bool not in kind.types and isinstance(value, bool)):
        names = " or ".join({str: "a string", bool: "true/false", int: "a whole number", dict: "a table",
                             list: "a list"}[t] for t in kind.types)
        return f"{_show(value)} is not {names}"
    if kind.choices is not None and value not in kind.choices:
        return f"{_show(value)} is not one of {', '.join(map(str, kind.choices))}"
    return None


def nonfinite(value: Any, where: str = "") -> str | None:
    """The dotted path of the first non-finite or huge number inside `value` (None: none)."""
    if isinstance(value, float) and (not math.isfinite(value) or abs(value) > 1e300):
        return where or "value"
    if isinstance(value, Mapping):
        for k, v in value.items():
            p = nonfinite(v, f"{where}.{k}" if where else str(k))
            if p:
                return p
    if isinstance(value, list):
        for i, v in enumerate(value):
            p = nonfinite(v, f"{where}[{i}]")
            if p:
                return p
    return None


def _loads(text: str) -> Any:
    """json.loads (NaN/Infinity literals are read, then refused by the field checks, which name
    the field)."""
    return json.loads(text)


def _key_line(text: str, key: str) -> int:
    """Line of `"key":` in a pretty-printed JSON document (1 if not found)."""
    m = re.search(r'^\s*"' + re.escape(key) + r'"\s*:', text, flags=re.M)
    return text.count("\n", 0, m.start()) + 1 if m else 1


# ---------------------------------------------------------------------------------- RunInfo
@dataclass(frozen=True)
class RunInfo:
    """run.json, validated: the typed fields every reader uses, and `raw` (the whole document).

    Units: counts_per_rev counts per wheel revolution; times are UTC ISO-8601 strings.
    """

    path: Path
    run_id: str
    procedure: str
    status: str
    format_version: int
    counts_per_rev: float | None
    steps_planned: int | None
    steps_complete: int
    segments: tuple[int, ...]
    imported: bool
    robot: dict[str, Any] | None
    raw: dict[str, Any] = field(repr=False)
    port: str | None = None  #: the board's port (serial device, sim://...) the run was taken on
    procedure_file: str | None = None  #: the procedure file the run was expanded from
    robot_file: str | None = None  #: the robot file given (None: the shipped Omnibot)
    board: dict[str, Any] | None = None  #: the board's HELLO: board_id, firmware_version, protocol_version, ...
    mode: str | None = None  #: "ground" or "upside_down" for a trace-replay (imported) run
    source: str | None = None  #: an imported run's source file
    source_sha256: str | None = None  #: the SHA-256 of that source file (the importer's duplicate check)
    sign_map: list[int] | None = None  #: an imported run's encoder signs, +1/-1 per wheel (FL FR RL RR)
    direction: str | None = None  #: an imported ground run's driving direction, when the log says
    #: how the firmware timed its commands (runs/tfm.py: sketch, command_order, command_offset_s, ...)
    firmware_timing: dict[str, Any] | None = None
    #: when a sample's duty acted: "interval_before" (omnibench boards) or "from_sample" (2019 logs);
    #: None: not recorded (the reader's default by `imported`)
    duty_timing: str | None = None
    #: an imported run's conditions, each {value, source[, evidence]}: how it was decided (stated in
    #: the map or with an option, read off the data with its statistic, or unknown); runs/csv_import.py
    conditions: dict[str, Any] | None = None

    @property
    def complete(self) -> bool:
        return self.status == "complete"

    @property
    def file(self) -> Path:
        """The run.json this was read from (for messages naming it)."""
        return self.path / RUN_FILE


def parse_info(doc: Any, run_dir: Path, text: str = "") -> RunInfo:
    """Validate a run.json document (`text` gives line numbers); RunFileError on the first fault."""
    where = run_dir / RUN_FILE
    if not isinstance(doc, dict):
        raise RunFileError(f"{where}:1: not a run description (a JSON table is expected, found "
                           f"{type(doc).__name__})")

    def bad(key: str, why: str) -> RunFileError:
        return RunFileError(f"{where}:{_key_line(text, key)}: {key}: {why}")

    if doc.get("format") != FORMAT:
        raise bad("format", f"{_show(doc.get('format'))}: not an omnibench run (format {FORMAT!r} expected)")
    for key, kind in RUN_FIELDS.items():
        if key not in doc and key in ("procedure", "status", "format_version"):
            raise bad(key, "is missing")
        why = check_value(doc.get(key), kind)
        if why:
            raise bad(key, why)
    for key, value in doc.items():
        p = nonfinite(value, key)
        if p:
            raise bad(key, f"{p} holds a non-finite or huge number")
    rid = doc.get("run_id") if doc.get("run_id") is not None else run_dir.name
    if not is_safe_name(rid):
        raise bad("run_id" if "run_id" in doc else "format",
                  f"{_show(rid)} is not a safe run id (letters, digits, . _ + - @ = #; no path "
                  "separators, no '..')" if "run_id" in doc else
                  f"the folder name {rid!r} is no safe run id and run.json has no run_id")
    if not is_safe_name(doc["procedure"]):
        raise bad("procedure", f"{_show(doc['procedure'])} is not a procedure name")
    segments: list[int] = []
    for i, s in enumerate(doc.get("segments") or []):
        seg = s.get("segment") if isinstance(s, dict) else None
        if check_value(seg, Num(0, 1e6, null=False, integer=True)):
            raise bad("segments", f"entry {i}: segment {_show(seg)} is not a whole number >= 0")
        segments.append(int(seg))  # type: ignore[arg-type]
    for i, a in enumerate(doc.get("operator_answers") or []):
        if not isinstance(a, dict):
            raise bad("operator_answers", f"entry {i} is not a table")
    for i, b in enumerate(doc.get("boards") or []):
        if not isinstance(b, dict):
            raise bad("boards", f"entry {i} is not a table")
    if doc.get("steps_complete") is not None and doc.get("steps_planned") is not None \
            and doc["steps_complete"] > doc["steps_planned"]:
        raise bad("steps_complete", f"{doc['steps_complete']} steps complete of {doc['steps_planned']} planned")
    cpr = doc.get("counts_per_rev")
    planned = doc.get("steps_planned")
    return RunInfo(path=run_dir, run_id=str(rid), procedure=doc["procedure"], status=doc["status"],
                   format_version=int(doc["format_version"]),
                   counts_per_rev=float(cpr) if cpr is not None else None,
                   steps_planned=int(planned) if planned is not None else None,
                   steps_complete=int(doc.get("steps_complete") or 0), segments=tuple(segments),
                   imported=bool(doc.get("imported", False)), robot=doc.get("robot"), raw=doc,
                   port=doc.get("port"), procedure_file=doc.get("procedure_file"), robot_file=doc.get("robot_file"),
                   board=doc.get("board"), mode=doc.get("mode"), source=_text(doc.get("source")),
                   source_sha256=_text(doc.get("source_sha256")), sign_map=_signs(doc.get("sign_map")),
                   direction=_text(doc.get("direction")), firmware_timing=doc.get("firmware_timing"),
                   duty_timing=doc.get("duty_timing"), conditions=doc.get("conditions"))


def _text(value: Any) -> str | None:
    """A free-form run.json field (not in RUN_FIELDS) as text, None when absent or not text."""
    return value if isinstance(value, str) else None


def _signs(value: Any) -> list[int] | None:
    """`sign_map` (not in RUN_FIELDS): four +1/-1, else None."""
    if isinstance(value, list) and len(value) == 4 and all(v in (1, -1) for v in value):
        return [int(v) for v in value]
    return None


def read_info(run_dir: Path | str) -> RunInfo:
    """Read and validate `run_dir`/run.json (RunFileError naming file, line and field)."""
    run_dir = Path(run_dir)
    where = run_dir / RUN_FILE
    if not where.is_file():
        raise RunFileError(f"{run_dir}: not a run directory (no run.json)")
    try:
        text = where.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise RunFileError(f"{where}:1: not UTF-8 text") from None
    except OSError as exc:
        raise RunFileError(f"{where}: cannot read ({exc.strerror or exc})") from None
    try:
        doc = _loads(text)
    except json.JSONDecodeError as exc:
        raise RunFileError(f"{where}:{exc.lineno}: broken JSON ({exc.msg})") from None
    except (ValueError, RecursionError) as exc:
        raise RunFileError(f"{where}:1: broken JSON ({exc})") from None
    return parse_info(doc, run_dir, text)


# ------------------------------------------------------------------------------ steps.jsonl
def complete_lines(path: Path) -> str:
    """File text without a half-written last line (a crash mid-write); RunFileError if unreadable."""
    if not path.exists():
        return ""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        line = path.read_bytes()[: exc.start].count(b"\n") + 1
        raise RunFileError(f"{path}:{line}: not UTF-8 text") from None
    except OSError as exc:
        raise RunFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    return text


def read_jsonl(path: Path) -> list[tuple[int, dict[str, Any]]]:
    """(line number, object) of each complete line of a JSON-lines file; RunFileError on a line
    that is not a JSON object."""
    out = []
    for n, line in enumerate(complete_lines(path).splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = _loads(line)
        except json.JSONDecodeError as exc:
            raise RunFileError(f"{path}:{n}: not a JSON line ({exc.msg})") from None
        except (ValueError, RecursionError) as exc:
            raise RunFileError(f"{path}:{n}: not a JSON line ({exc})") from None
        if not isinstance(rec, dict):
            raise RunFileError(f"{path}:{n}: not a JSON object")
        out.append((n, rec))
    return out


def check_step(rec: dict[str, Any], where: str, info: RunInfo) -> None:
    """Validate one step record (`where` = 'file:line'); RunFileError on the first bad field."""
    if "step" not in rec:
        raise RunFileError(f"{where}: step: is missing")
    if "segment" not in rec:
        raise RunFileError(f"{where}: segment: is missing")
    for key, kind in STEP_FIELDS.items():
        if key in rec:
            why = check_value(rec[key], kind)
            if why:
                raise RunFileError(f"{where}: {key}: {why}")
    for key, value in rec.items():
        p = nonfinite(value, key)
        if p:
            raise RunFileError(f"{where}: {p}: holds a non-finite or huge number")
    for a, b in (("t_start", "t_end"), ("t_start", "t_drive_end"), ("t_drive_end", "t_end")):
        if isinstance(rec.get(a), (int, float)) and isinstance(rec.get(b), (int, float)) and rec[b] < rec[a]:
            raise RunFileError(f"{where}: {b}: {_show(rec[b])} is before {a} {_show(rec[a])}")
    if info.steps_planned is not None and rec["step"] >= info.steps_planned:
        raise RunFileError(f"{where}: step: {rec['step']} is out of range (the run plans steps 0 to "
                           f"{info.steps_planned - 1})")
    if info.segments and rec["segment"] not in info.segments:
        raise RunFileError(f"{where}: segment: {rec['segment']} is not a segment of the run "
                           f"({', '.join(map(str, info.segments))})")


def missing_for_analysis(run_dir: Path, info: RunInfo) -> str | None:
    """'file:line: field: is missing ...' for the first step record that lacks a field the
    analysis needs (REQUIRED_STEP_FIELDS; imported steps without samples excepted), else None."""
    need = REQUIRED_STEP_FIELDS.get(info.procedure, ())
    path = run_dir / "steps.jsonl"
    for n, rec in read_jsonl(path) if need else []:
        if info.imported and rec.get("has_samples") is False:
            continue
        for key in need:
            if rec.get(key) is None:
                return f"{path}:{n}: {key}: is missing (the analysis would drop the step)"
    return None


#: Columns every sample must hold a number in (motor and battery currents may be unlogged; an
#: empty `step` is a sample taken under no step's command, counted in a step's samples_rejected).
MEASURED = ("segment", "t", "u1", "u2", "u3", "u4", "phi1", "phi2", "phi3", "phi4")


def unmeasured(run_dir: Path, samples: pd.DataFrame) -> str | None:
    """'samples.csv:N: column: holds no number' for the first sample lacking a measured value
    (rows are written whole, so an empty measured cell is damage, not a crash), else None."""
    for c in MEASURED:
        bad = samples[c].isna().to_numpy()
        if bad.any():
            return f"{run_dir / 'samples.csv'}:{int(np.argmax(bad)) + 2}: {c}: holds no number"
    return None


#: A step record's duty and the duty its samples report agree within this (wire resolution ~3e-5).
DUTY_TOLERANCE = 2e-3


def duties_disagree(run_dir: Path, steps: Sequence[Mapping[str, Any]], samples: pd.DataFrame) -> str | None:
    """'steps.jsonl:N: uJ: ...' when a hold or timed step's recorded duty is not the duty its own
    samples report (the largest in magnitude over the step, in the segment that completed it):
    the record was edited or belongs to other samples, and the analysis would fit one against
    the other."""
    path = run_dir / "steps.jsonl"
    line = {int(rec["step"]): n for n, rec in read_jsonl(path)}
    for st in steps:
        if st.get("kind") not in ("hold", "timed") or not len(samples):
            continue
        k, seg = int(st["step"]), int(st["segment"])
        s = samples[(samples["step"] == k) & (samples["segment"] == seg)]
        for j in range(1, 5):
            u = st.get(f"u{j}")
            if not isinstance(u, (int, float)) or isinstance(u, bool) or not math.isfinite(u):
                continue
            col = s[f"u{j}"].to_numpy(dtype=float)
            col = col[np.isfinite(col)]
            if not len(col):
                continue
            seen = float(col[np.argmax(np.abs(col))])
            if abs(seen - u) > DUTY_TOLERANCE:
                return (f"{path}:{line.get(k, '?')}: u{j}: {u:g} is not the duty step {k}'s samples "
                        f"report in samples.csv ({seen:.4g})")
    return None


def read_steps(run_dir: Path, info: RunInfo) -> list[dict[str, Any]]:
    """The validated step records of steps.jsonl in step order; a step recorded twice is refused."""
    path = run_dir / "steps.jsonl"
    by_step: dict[int, dict[str, Any]] = {}
    for n, rec in read_jsonl(path):
        check_step(rec, f"{path}:{n}", info)
        k = int(rec["step"])
        if k in by_step:
            raise RunFileError(f"{path}:{n}: step: step {k} is recorded a second time")
        rec["step"], rec["segment"] = k, int(rec["segment"])
        by_step[k] = rec
    return [by_step[k] for k in sorted(by_step)]


# ------------------------------------------------------------------------------ samples.csv
def sample_header(path: Path) -> list[str] | None:
    """Column names of samples.csv (None: no complete header line, e.g. cut by a crash)."""
    if not path.exists():
        return None
    with open(path, "rb") as fh:
        first = fh.readline(1 << 16)
    if not first.endswith(b"\n"):
        return None
    return first.decode("utf-8", errors="replace").strip().split(",")


def check_sample_header(path: Path) -> None:
    """RunFileError unless samples.csv is empty, cut inside its header, or has every column."""
    header = sample_header(path)
    if header is None:
        return
    lacking = [c for c in SAMPLE_COLUMNS if c not in header]
    if lacking:
        raise RunFileError(f"{path}:1: header lacks column(s) {', '.join(lacking)}")
    if len(set(header)) != len(header):
        raise RunFileError(f"{path}:1: header names a column twice")


@contextlib.contextmanager
def ctrl_c_held() -> Iterator[None]:
    """Hold a Ctrl-C (SIGINT) that comes during the block and deliver it when the block ends.

    pandas' C reader turns a KeyboardInterrupt raised inside its read into a ParserError
    ("Calling read(nbytes) on source failed"): a Ctrl-C while a run was read was reported as
    a bad samples.csv and a campaign went on to its next stage. Reading takes ~0.1 s."""
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread receives signals
        return
    held: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if held:  # to whatever handles SIGINT now (KeyboardInterrupt by default); it wins over an error
            signal.raise_signal(signal.SIGINT)


def read_samples(path: Path) -> pd.DataFrame:
    """samples.csv as numbers (empty cell = NaN, "not measured"); RunFileError naming the line
    and column of any cell that is not a finite number in its column's range."""
    text = complete_lines(path)
    if not text.strip() or sample_header(path) is None:
        return pd.DataFrame({c: pd.Series(dtype=float) for c in SAMPLE_COLUMNS})
    check_sample_header(path)
    try:
        with ctrl_c_held():
            df = pd.read_csv(io.StringIO(text), keep_default_na=False, na_values=[""])
    except (pd.errors.ParserError, ValueError) as exc:
        msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        m = re.search(r"line (\d+)", msg)
        raise RunFileError(f"{path}:{m.group(1) if m else '?'}: not a CSV row ({msg})") from None
    out = {}
    for c in SAMPLE_COLUMNS:
        raw = df[c]
        if pd.api.types.is_numeric_dtype(raw) and not pd.api.types.is_bool_dtype(raw):
            num = raw.to_numpy(dtype=float)
        else:  # a column pandas could not read as numbers: find the cell
            num = pd.to_numeric(raw.astype(object).where(raw.notna(), None), errors="coerce").to_numpy(dtype=float)
        lo, hi = SAMPLE_RANGES[c]
        given = raw.notna().to_numpy()
        bad = given & ~(np.isfinite(num) & (num >= lo) & (num <= hi))
        if bad.any():
            i = int(np.argmax(bad))
            raise RunFileError(f"{path}:{i + 2}: {c}: {str(raw.iloc[i])[:40]!r} is not a number in "
                               f"[{lo:g}, {hi:g}]")
        out[c] = num
    return pd.DataFrame(out)


def check_resumable(run_dir: Path | str, procedure: str | None = None) -> tuple[RunInfo, set[int]]:
    """Validate a run for `--resume` without writing anything: (its RunInfo, the steps done).

    RunFileError naming the file, line and field of the first fault; UserError when the run is
    complete or of another procedure."""
    run_dir = Path(run_dir)
    info = read_info(run_dir)
    if procedure is not None and info.procedure != procedure:
        raise UserError(f"{run_dir}: is a {info.procedure} run; resume it with its own command")
    if info.complete:
        raise UserError(f"{run_dir}: run is already complete; nothing to resume")
    steps = read_steps(run_dir, info)
    samples = read_samples(run_dir / "samples.csv")
    read_jsonl(run_dir / "events.jsonl")
    # the steps already done are kept as they are: the analysis must accept them after the resume
    why = (missing_for_analysis(run_dir, info) or unmeasured(run_dir, samples)
           or duties_disagree(run_dir, steps, samples))
    if why:
        raise RunFileError(why)
    return info, {int(r["step"]) for r in steps}


def refuse_duplicate_ids(infos: Sequence[RunInfo]) -> None:
    """UserError if two run folders share a run id (a copy): each run must count once."""
    seen: dict[str, Path] = {}
    for info in infos:
        if info.run_id in seen:
            raise UserError(f"{info.path / 'run.json'}: run_id {info.run_id} is also the id of "
                            f"{seen[info.run_id]} (a copy?): each run counts once; give one of them")
        seen[info.run_id] = info.path
