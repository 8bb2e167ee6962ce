"""Run directories: one folder per run, written as it goes, readable after any crash.

A run directory holds (see docs/run-format.md for the full description):

- ``run.json``     metadata (procedure as run, robot, board HELLO, operator answers, tool
                   version, start/end, status and reason). Rewritten atomically (temp file +
                   ``os.replace``) so it is always a complete JSON document.
- ``samples.csv``  raw telemetry, one row per board sample, flushed at least once a second.
- ``events.jsonl`` one JSON object per line: step boundaries, operator actions, faults.
- ``steps.jsonl``  one JSON object per completed step: its parameters and its results.
- ``procedure.toml`` / ``robot.toml``: copies of the files as run (when there were files).

Why this shape: a crash or Ctrl-C can only lose the unflushed tail of ``samples.csv`` (at most
the last second); the metadata says ``running`` until the writer closes it, so a reader can
tell an interrupted run from a finished one; ``--resume`` appends a new *segment* to the same
files, and the step records say which segment completed each step.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import math
import os
import shutil
import time
import uuid
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from omnibench import __version__
from omnibench.errors import Terminated, UserError
from omnibench.runs.record import (  # noqa: F401 - the format's names, re-exported
    FORMAT,
    FORMAT_VERSION,
    RUN_FILE,
    SAMPLE_COLUMNS,
    STATUSES,
    RunInfo,
    check_resumable,
    complete_lines,
    read_info,
    read_jsonl,
    read_samples,
    read_steps,
    safe_name,
)

#: The space reserve: a file of zeros claimed before the robot moves, freed before run.json is marked.
RESERVE_NAME = "run.json.reserve"

#: The samples file is flushed to the OS at least this often (host seconds).
FLUSH_INTERVAL_S = 0.5


def utc_now() -> str:
    """ISO-8601 UTC time stamp with seconds, e.g. 2026-11-21T12:00:00Z."""
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _json_default(obj: Any) -> Any:
    """numpy scalars and arrays, Paths: JSON-able equivalents."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _clean(obj: Any) -> Any:
    """NaN/inf become None so the JSON stays standard."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if hasattr(obj, "tolist"):
        return _clean(obj.tolist())
    return obj


def json_ready(obj: Any) -> Any:
    """`obj` with numpy values as Python ones and NaN/inf as None (standard JSON)."""
    return _clean(obj)


def dumps(obj: Any) -> str:
    """One-line standard JSON (no NaN)."""
    return json.dumps(_clean(obj), default=_json_default, allow_nan=False)


def write_json_atomic(path: Path, obj: Any) -> None:
    """Write JSON to `path` so that a crash leaves either the old or the new file, never half."""
    tmp = path.with_name(path.name + ".tmp")
    text = json.dumps(_clean(obj), default=_json_default, indent=2, allow_nan=False) + "\n"
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)  # no stray temporary file (e.g. the disk is full)
        if exc.filename is None:
            exc.filename = str(path)
        raise


def _fmt(v: Any) -> str:
    """One CSV cell: empty for None/NaN, repr-precision floats."""
    if v is None:
        return ""
    if hasattr(v, "item"):  # numpy scalar (np.float64 is also a float: unwrap first)
        v = v.item()
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    return str(v)


def new_run_dir(out: Path, procedure: str) -> Path:
    """A fresh directory ``out/<procedure>-<UTC date-time>[-n]`` (created; an imported run
    passes its source file's name instead of the procedure)."""
    out = Path(out)
    with named(out):
        out.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%d-%H%M%S")
    base = out / f"{procedure}-{stamp}"
    path, n = base, 1
    while True:
        try:
            with named(path):
                path.mkdir()
            return path
        except FileExistsError:
            n += 1
            path = Path(f"{base}-{n}")


def unique_run_id(path: Path) -> str:
    """The run's id: its directory name plus 8 random hex digits, so two runs started in the
    same second in two folders never share an id (the analysis merges runs by id)."""
    return f"{safe_name(Path(path).name)[:180]}-{uuid.uuid4().hex[:8]}"


class RunWriter:
    """Writes one run directory as the run goes; every exit path leaves it readable.

    Use as a context manager: leaving the block with an exception marks the run ``failed``
    (or ``aborted`` for KeyboardInterrupt) unless `finish` was already called.
    """

    def __init__(self, path: Path, metadata: dict[str, Any], *, segment: int = 0) -> None:
        self.path = Path(path)
        self.metadata = metadata
        self.segment = segment
        self.counts_per_rev: float | None = metadata.get("counts_per_rev")
        sp = self.path / "samples.csv"
        self._samples = self._events = self._steps = None
        self._reserve: Path | None = None
        try:
            with named(sp):
                new_samples = not sp.exists() or sp.stat().st_size == 0  # none yet, or cut in the header
                self._samples = open(sp, "a", encoding="utf-8", newline="")
                if new_samples:
                    self._samples.write(",".join(SAMPLE_COLUMNS) + "\n")
            with named(self.path / "events.jsonl"):
                self._events = open(self.path / "events.jsonl", "a", encoding="utf-8")
            with named(self.path / "steps.jsonl"):
                self._steps = open(self.path / "steps.jsonl", "a", encoding="utf-8")
            self._last_flush = time.monotonic()
            self._finished = False
            self.n_samples = 0
            self.save_metadata()
            self.flush()
        except BaseException:
            self._close_files()
            raise

    # -- creation -------------------------------------------------------------------------
    @classmethod
    def create(
        cls,
        out: Path,
        procedure: str,
        *,
        run_dir: Path | None = None,
        procedure_text: str | None = None,
        procedure_file: str | None = None,
        robot: Mapping[str, Any] | None = None,
        robot_text: str | None = None,
        robot_file: str | None = None,
        board: Mapping[str, Any] | None = None,
        port: str | None = None,
        counts_per_rev: float | None = None,
        extra: Mapping[str, Any] | None = None,
        name: str | None = None,
        reserve: int | None = None,
    ) -> "RunWriter":
        """Start a new run directory (status ``running``) under `out` (or exactly `run_dir`),
        named ``<name>-<UTC date-time>`` (`name` defaults to the procedure). `reserve`: claim
        that many bytes (at least 8x run.json) for the final run.json before returning (see
        `reserve`). Any failure (e.g. a full disk) removes the half-made folder and raises."""
        made_out = not Path(out).exists()
        if run_dir is None:
            path = new_run_dir(Path(out), name or procedure)
        else:
            path = Path(run_dir)
            with named(path):
                path.mkdir(parents=True, exist_ok=True)
            if any(path.iterdir()):
                raise UserError(f"{path}: run directory is not empty")
        try:
            w = cls._start(path, procedure, procedure_text=procedure_text, procedure_file=procedure_file,
                           robot=robot, robot_text=robot_text, robot_file=robot_file, board=board, port=port,
                           counts_per_rev=counts_per_rev, extra=extra)
            if reserve:
                try:
                    w.reserve(max(reserve, 8 * len(dumps(w.metadata))))
                except BaseException:
                    w._close_files()
                    raise
            return w
        except BaseException:
            shutil.rmtree(path, ignore_errors=True)  # no half-made run folder (e.g. the disk is full)
            if made_out and run_dir is None:
                try:
                    Path(out).rmdir()  # nor the --out folder made for it, when nothing else is there
                except OSError:
                    pass
            raise

    @classmethod
    def _start(cls, path: Path, procedure: str, *, procedure_text: str | None, procedure_file: str | None,
               robot: Mapping[str, Any] | None, robot_text: str | None, robot_file: str | None,
               board: Mapping[str, Any] | None, port: str | None, counts_per_rev: float | None,
               extra: Mapping[str, Any] | None) -> "RunWriter":
        if procedure_text is not None:
            with named(path / "procedure.toml"):
                (path / "procedure.toml").write_text(procedure_text, encoding="utf-8")
        if robot_text is not None:
            with named(path / "robot.toml"):
                (path / "robot.toml").write_text(robot_text, encoding="utf-8")
        meta: dict[str, Any] = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "run_id": unique_run_id(path),
            "procedure": procedure,
            "procedure_file": procedure_file,
            "procedure_text": procedure_text,
            "robot_file": robot_file,
            "robot": dict(robot) if robot is not None else None,
            "counts_per_rev": counts_per_rev,
            "board": dict(board) if board is not None else None,
            "port": port,
            "tool": "omnibench",
            "tool_version": __version__,
            "started": utc_now(),
            "ended": None,
            "status": "running",
            "reason": None,
            "segments": [{"segment": 0, "started": utc_now(), "ended": None, "status": "running"}],
            "steps_planned": None,
            "steps_complete": 0,
            "operator_answers": [],
        }
        if extra:
            meta.update(extra)
        return cls(path, meta, segment=0)

    @classmethod
    def resume(cls, path: Path, *, board: Mapping[str, Any] | None = None,
               segment_info: Mapping[str, Any] | None = None) -> "RunWriter":
        """Reopen an interrupted run to append a new segment (status back to ``running``);
        `segment_info` (the port, the board's provenance, what changed) is kept in the segment."""
        path = Path(path)
        info, _ = check_resumable(path)  # every file validated before anything is written
        meta = info.raw
        _unlink_quietly(path / RESERVE_NAME)  # left by a killed run
        _trim_partial_line(path / "samples.csv")
        _trim_partial_line(path / "events.jsonl")
        _trim_partial_line(path / "steps.jsonl")
        segment = 1 + max((s["segment"] for s in meta.get("segments", [])), default=-1)
        meta.setdefault("segments", []).append(
            {"segment": segment, "started": utc_now(), "ended": None, "status": "running",
             "previous_status": meta.get("status"), "previous_reason": meta.get("reason"),
             **dict(segment_info or {})}
        )
        meta["status"] = "running"
        meta["reason"] = None
        meta["ended"] = None
        if board is not None:
            meta.setdefault("boards", []).append(dict(board))
        w = cls(path, meta, segment=segment)
        w.event("resume", segment=segment)
        return w

    # -- writing --------------------------------------------------------------------------
    def save_metadata(self) -> None:
        """Atomically rewrite run.json from `self.metadata`."""
        write_json_atomic(self.path / "run.json", self.metadata)

    def update(self, **fields: Any) -> None:
        """Set metadata keys and save atomically."""
        self.metadata.update(fields)
        self.save_metadata()

    def sample(self, row: Mapping[str, Any]) -> None:
        """Append one telemetry sample; keys from SAMPLE_COLUMNS (missing ones left empty).

        ``phi1..4`` are derived from ``enc1..4`` and the run's counts_per_rev when absent;
        ``segment`` defaults to the writer's current segment.
        """
        r = dict(row)
        r.setdefault("segment", self.segment)
        if self.counts_per_rev:
            k = 2.0 * math.pi / float(self.counts_per_rev)
            for j in range(1, 5):
                if r.get(f"phi{j}") is None and r.get(f"enc{j}") is not None:
                    r[f"phi{j}"] = float(r[f"enc{j}"]) * k
        with named(self.path / "samples.csv"):
            self._samples.write(",".join(_fmt(r.get(c)) for c in SAMPLE_COLUMNS) + "\n")
        self.n_samples += 1
        self._maybe_flush()

    def samples(self, rows: Iterable[Mapping[str, Any]]) -> None:
        """Append many samples."""
        for r in rows:
            self.sample(r)

    def event(self, kind: str, /, *, t: float | None = None, step: int | None = None,
              **fields: Any) -> None:
        """Append one event (flushed at once): kind, host time, board time `t` (s), step."""
        rec = {"kind": kind, "host_time": utc_now(), "t": t, "step": step,
               "segment": self.segment, **fields}
        with named(self.path / "events.jsonl"):
            self._events.write(dumps(rec) + "\n")
            self._events.flush()
        self._maybe_flush(force=True)

    def operator_answer(self, step: int | None, action: str, prompt: str, answer: Any,
                        source: str) -> None:
        """Record an operator answer in the events and in run.json (`operator_answers`)."""
        rec = {"step": step, "action": action, "prompt": prompt, "answer": answer,
               "source": source, "segment": self.segment, "host_time": utc_now()}
        self.metadata.setdefault("operator_answers", []).append(rec)
        self.event("operator", step=step, action=action, prompt=prompt, answer=answer,
                   source=source)
        self.save_metadata()

    def step_complete(self, record: Mapping[str, Any]) -> None:
        """Append a completed step's flat record (parameters and results) and count it."""
        rec = {"segment": self.segment, **record}
        if "step" not in rec:
            raise ValueError("step record needs a 'step' index")
        self.flush()
        with named(self.path / "steps.jsonl"):
            self._steps.write(dumps(rec) + "\n")
            self._steps.flush()
            os.fsync(self._steps.fileno())
        self.metadata["steps_complete"] = int(self.metadata.get("steps_complete", 0)) + 1
        self.save_metadata()

    def flush(self) -> None:
        """Push buffered samples and events to the OS."""
        with named(self.path / "samples.csv"):
            self._samples.flush()
        with named(self.path / "events.jsonl"):
            self._events.flush()
        self._last_flush = time.monotonic()

    # -- space reserve --------------------------------------------------------------------
    def reserve(self, nbytes: int) -> None:
        """Claim `nbytes` on the run's file system (RESERVE_NAME, zeros) before the robot moves,
        so that on a full disk run.json can still be marked: `finish` frees it first. A reserve
        that does not fit is removed again and the OSError names it."""
        path = self.path / RESERVE_NAME
        try:
            with named(path), open(path, "wb") as fh:
                fh.write(b"\0" * nbytes)
                fh.flush()
                os.fsync(fh.fileno())
        except BaseException:
            _unlink_quietly(path)
            raise
        self._reserve = path

    def release_reserve(self) -> None:
        """Free the space reserve (if any)."""
        if self._reserve is not None:
            _unlink_quietly(self._reserve)
            self._reserve = None

    def _close_files(self) -> None:
        for fh in (self._samples, self._events, self._steps):
            if fh is None:
                continue
            try:
                fh.flush()
                os.fsync(fh.fileno())
            except (OSError, ValueError):
                pass
            try:
                fh.close()
            except (OSError, ValueError):
                pass

    def _maybe_flush(self, force: bool = False) -> None:
        if force or time.monotonic() - self._last_flush >= FLUSH_INTERVAL_S:
            self.flush()

    def finish(self, status: str, reason: str | None = None) -> None:
        """Close the files and mark the run `status` (complete|aborted|failed) with `reason`."""
        if status not in STATUSES:
            raise ValueError(f"status {status!r} not in {STATUSES}")
        if self._finished:
            return
        self._finished = True
        self.release_reserve()  # the space run.json needs, even on a full disk
        try:
            self.event("run_end", status=status, reason=reason)
        finally:
            self._close_files()
            now = utc_now()
            self.metadata["status"] = status
            self.metadata["reason"] = reason
            self.metadata["ended"] = now
            for s in self.metadata.get("segments", []):
                if s["segment"] == self.segment:
                    s["ended"] = now
                    s["status"] = status
                    s["reason"] = reason
            self.save_metadata()

    def __enter__(self) -> "RunWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._finished:
            return
        if exc_type is None:
            self.finish("complete")
        elif issubclass(exc_type, Terminated):
            self.finish("aborted", "terminated (SIGTERM)")
        elif issubclass(exc_type, KeyboardInterrupt):
            self.finish("aborted", "interrupted by the operator (Ctrl-C)")
        else:
            self.finish("failed", f"{exc_type.__name__}: {exc}".splitlines()[0])


def append_event(run_dir: Path | str, kind: str, **fields: Any) -> None:
    """Add one event to a finished run's events.jsonl (same line format as the writer's; board
    time and step null), e.g. a design decision taken after the run."""
    path = Path(run_dir) / "events.jsonl"
    _trim_partial_line(path)
    with named(path), open(path, "a", encoding="utf-8") as fh:
        fh.write(dumps({"kind": kind, "host_time": utc_now(), "t": None, "step": None, **fields}) + "\n")


class RunLog:
    """log.txt in the run folder: what the terminal said, with UTC times (also under -q). A
    line that cannot be written (a full disk) is dropped: the log is a convenience, the run's
    record is run.json, samples.csv, events.jsonl and steps.jsonl."""

    def __init__(self, run_dir: str | Path) -> None:
        self.path = Path(run_dir) / "log.txt"

    def __call__(self, line: str) -> None:
        try:
            with open(self.path, "a", encoding="utf-8") as fh:
                fh.write(f"{utc_now()} {line}\n")
        except OSError:
            pass


@contextlib.contextmanager
def named(path: Path) -> Iterator[None]:
    """Give an OSError raised inside the block the file name `path` when it has none (a write
    that fails on a full disk names no file), so the one-line message says which file failed."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None:
            exc.filename = str(path)
        raise


def _unlink_quietly(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass


def _trim_partial_line(path: Path) -> None:
    """Cut a half-written last line (a crash mid-write) so appends start on a fresh line."""
    if not path.exists():
        return
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        cut = data.rfind(b"\n") + 1
        with named(path), open(path, "r+b") as fh:
            fh.truncate(cut)


def _read_jsonl(path: Path) -> list[dict[str, Any]]:
    """The objects of a JSON-lines file (RunFileError naming the line of a bad one)."""
    return [rec for _, rec in read_jsonl(path)]


#: no sample rows (a step without samples)
_NO_ROWS = np.zeros(0, dtype=np.intp)


@dataclass
class Run:
    """A run read back: metadata dict and pandas DataFrames.

    `samples`: every row of samples.csv (all segments, including interrupted attempts).
    `events`: events.jsonl. `steps`: one row per completed step (flat: parameters + results).
    """

    path: Path
    metadata: dict[str, Any]  #: run.json as read (prefer `info`'s typed fields)
    samples: pd.DataFrame
    events: pd.DataFrame
    steps: pd.DataFrame
    info: RunInfo  #: run.json, validated and typed
    extra: dict[str, Any] = field(default_factory=dict)
    _index: tuple | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def run_id(self) -> str:
        """The run's (validated, file-name safe) id."""
        return self.info.run_id

    @property
    def status(self) -> str:
        return self.info.status

    @property
    def procedure(self) -> str:
        return self.info.procedure

    def step_samples(self, step: int) -> pd.DataFrame:
        """Samples of `step` from the segment that completed it (an interrupted earlier
        attempt of the same step is left out); all its samples if it never completed."""
        if "step" not in self.samples or "segment" not in self.samples or (len(self.steps) and "segment" not in self.steps):
            s = self.samples[self.samples["step"] == step]  # not a run as read_run makes it: as asked
            done = self.steps[self.steps["step"] == step] if len(self.steps) else self.steps
            if len(done):
                s = s[s["segment"] == int(done["segment"].iloc[-1])]
            return s.reset_index(drop=True)
        rows, segment = self._step_index()
        pos = rows.get(step, _NO_ROWS)
        if step in segment:
            pos = pos[self.samples["segment"].to_numpy()[pos] == int(segment[step])]
        return self.samples.take(pos).reset_index(drop=True)

    def _step_index(self) -> tuple[dict[Any, np.ndarray], dict[Any, Any]]:
        """(step -> positions of its samples, step -> the segment that completed it), built once
        per samples and steps tables (the analysis asks for every step's samples, twice: a
        boolean mask over all samples each time was ~0.2 s of CPU of an `omnibench fit`)."""
        key = (len(self.samples), len(self.steps))
        if (self._index is None or self._index[0] is not self.samples or self._index[1] is not self.steps
                or self._index[2] != key):
            rows = self.samples.groupby("step", sort=False).indices if len(self.samples) else {}
            segment: dict[Any, Any] = {}
            if len(self.steps):
                for st, sg in zip(self.steps["step"].tolist(), self.steps["segment"].tolist()):
                    segment[st] = sg  # the last row of a step wins
            self._index = (self.samples, self.steps, key, rows, segment)
        return self._index[3], self._index[4]

    def clean_samples(self) -> pd.DataFrame:
        """Samples of completed steps only, each from the segment that completed it."""
        if not len(self.steps):
            return self.samples.iloc[0:0]
        keys = self.steps[["step", "segment"]].drop_duplicates()
        return self.samples.merge(keys, on=["step", "segment"], how="inner")


def read_run(path: Path | str) -> Run:
    """Read and validate a run directory (complete or not) into a `Run`.

    Tolerates a half-written last line in any file (a crash mid-write); any other fault is a
    RunFileError (a UserError) naming the file, the line and the field (omnibench.runs.record).
    """
    path = Path(path)
    info = read_info(path)
    samples = read_samples(path / "samples.csv")
    events = pd.DataFrame(_read_jsonl(path / "events.jsonl"))
    steps = pd.DataFrame(read_steps(path, info))
    if not len(steps):
        steps = pd.DataFrame(columns=["step", "segment"])
    return Run(path=path, metadata=info.raw, samples=samples, events=events, steps=steps, info=info)


def run_dirs(folder: Path | str) -> list[Path]:
    """The run directories directly in `folder` (each holds a run.json), sorted by name; [] when
    `folder` is not a directory."""
    folder = Path(folder)
    return [p.parent for p in sorted(folder.glob(f"*/{RUN_FILE}"))] if folder.is_dir() else []


def is_run_dir(path: Path | str) -> bool:
    """Whether `path` is a run directory (holds a run.json)."""
    return (Path(path) / RUN_FILE).is_file()


def find_runs(root: Path | str, procedure: str | Sequence[str] | None = None) -> list[Path]:
    """Run directories under `root` (recursively), optionally of the given procedure(s)."""
    root = Path(root)
    procs = {procedure} if isinstance(procedure, str) else set(procedure or [])
    found = []
    candidates = [root] if (root / "run.json").is_file() else sorted(root.rglob("run.json"))
    for p in candidates:
        d = p if p.is_dir() else p.parent
        if procs:
            try:
                meta = json.loads((d / "run.json").read_text(encoding="utf-8"))
            except (OSError, ValueError):
                continue
            if not isinstance(meta, dict) or meta.get("procedure") not in procs:
                continue
        found.append(d)
    return found
