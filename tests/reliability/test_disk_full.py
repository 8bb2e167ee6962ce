"""Disk full and read-only output on real file systems (issue 38): a tmpfs of 4 KiB, 16 KiB,
200 KiB and 300 KiB (room for the space reserve, then full while sampling), and a read-only
remount (between sessions: the kernel refuses it under open files). Each: a clear error naming
the file, no half-made folder, no stray reserve or temporary file, and a run either gone or left
resumable / clearly failed, which fit refuses with one line. Needs `mount` (root); skipped with
the reason otherwise.
"""

from __future__ import annotations

import json
import subprocess
import uuid
from pathlib import Path

import pytest

from omnibench.runs.check import run_problem
from omnibench.runs.store import RESERVE_NAME, RunWriter
from reliability.badinput import PROC, SIM, run_cli


def _mount(path: Path, size: str) -> None:
    path.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({(r.stderr or r.stdout).strip() or 'mount failed'}): needs root")


@pytest.fixture
def small_disk(tmp_path):
    mounted: list[Path] = []

    def make(size: str) -> Path:
        d = tmp_path / f"disk-{uuid.uuid4().hex[:6]}"
        _mount(d, size)
        mounted.append(d)
        return d

    yield make
    for d in mounted:
        subprocess.run(["umount", "-l", str(d)], capture_output=True)


def _leftovers(root: Path) -> list[str]:
    return [str(p) for p in root.rglob("*") if p.name.endswith((".reserve", ".tmp"))]


def _check_left_state(out: Path, err: str) -> None:
    """The run folder is gone, or holds a run.json that says failed/running and fit refuses."""
    assert "Traceback" not in err and "internal error" not in err, err
    assert _leftovers(out) == []
    runs = [d for d in out.iterdir() if d.is_dir()] if out.exists() else []
    for d in runs:
        assert (d / "run.json").is_file(), f"half-made run folder {d}: {sorted(p.name for p in d.iterdir())}"
        status = json.loads((d / "run.json").read_text())["status"]
        assert status in ("failed", "running"), status
        why = run_problem(d)
        assert why is not None and "\n" not in why and "not complete" in why


@pytest.mark.parametrize("size, names", [
    ("4k", ("procedure.toml", "robot.toml", "samples.csv", "run.json", "events.jsonl", "steps.jsonl")),
    ("16k", ("procedure.toml", "robot.toml", "samples.csv", "run.json", "events.jsonl", "steps.jsonl",
             RESERVE_NAME)),
    ("200k", (RESERVE_NAME,)),
])
def test_a_disk_too_small_to_start_a_run_leaves_nothing(small_disk, size, names) -> None:
    """Creation or the space reserve fails before the robot moves: one line, no folder at all."""
    disk = small_disk(size)
    out = disk / "runs"
    code, err = run_cli(["sweep", "--port", SIM, "--procedure", str(PROC), "--out", str(out)], 120)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    line = err.strip()
    assert line.startswith(f"omnibench: error: cannot create a run under {out}: cannot write ") and \
        "No space left on device" in line, err
    assert any(f"/{n}: No space" in line for n in names), line  # names the file that failed
    if size == "200k":
        assert "claims 256 KiB before the robot moves" in line
    assert list(disk.iterdir()) == []  # no half-made run folder, no --out folder made for it


def test_a_disk_that_fills_while_driving_leaves_a_failed_resumable_run(small_disk) -> None:
    """300 KiB: the reserve fits, then the disk fills while driving (samples.csv or a run.json
    rewrite, whichever write meets it first): the motors stop, the reserve makes room to mark
    run.json failed, no reserve left, the run is resumable, every sample line written is whole,
    and fit refuses the run with one line."""
    from omnibench.runs.record import check_resumable

    disk = small_disk("300k")
    out = disk / "runs"
    code, err = run_cli(["sweep", "--port", SIM, "--procedure", str(PROC), "--out", str(out)], 120)
    assert code == 2, err
    last = err.strip().splitlines()[-1]
    (run_dir,) = out.iterdir()
    named = [f for f in ("samples.csv", "run.json", "steps.jsonl", "events.jsonl")
             if last == f"omnibench: error: cannot write {run_dir / f}: No space left on device"]
    assert named, err  # the file that met the full disk, whichever it was
    assert "motors stopped" in err
    assert f"continue once there is space with: omnibench sweep --resume {run_dir} --port {SIM}" in err
    assert json.loads((run_dir / "run.json").read_text())["status"] == "failed"
    check_resumable(run_dir, "upside_down_sweep")  # raises if it could not be resumed
    lines = (run_dir / "samples.csv").read_text().splitlines()
    assert len(lines) > 1 and len({line.count(",") for line in lines}) == 1  # header + whole rows only
    _check_left_state(out, err)


def test_read_only_remount_after_an_interrupted_run_then_resume(small_disk, monkeypatch) -> None:
    """The kernel refuses to remount a tmpfs read-only while files are open for writing (EBUSY),
    so the disk goes read-only between sessions: the run was interrupted (Ctrl-C), then a new
    run and a resume meet a read-only disk (an EROFS in mid-write is test_run_safety's case)."""
    disk = small_disk("2m")
    out = disk / "runs"
    real = RunWriter.sample
    calls = [0]

    def sample(self, row):
        calls[0] += 1
        if calls[0] == 60:
            raise KeyboardInterrupt
        return real(self, row)

    monkeypatch.setattr(RunWriter, "sample", sample)
    code, err = run_cli(["sweep", "--port", SIM, "--procedure", str(PROC), "--out", str(out)], 120)
    monkeypatch.setattr(RunWriter, "sample", real)
    assert code == 130, err
    (run_dir,) = out.iterdir()
    subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
    assert json.loads((run_dir / "run.json").read_text())["status"] == "aborted"
    code, err = run_cli(["fit", str(run_dir), "--out", str(disk.parent / "m.toml")])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "not complete" in err, err
    # a new run on the read-only disk: one line, nothing made
    code, err = run_cli(["sweep", "--port", SIM, "--procedure", str(PROC), "--out", str(out)], 120)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Read-only file system" in err, err
    assert list(out.iterdir()) == [run_dir]
    # resuming on the read-only disk: one line naming the run, nothing changed
    before = {p.name: p.read_bytes() for p in run_dir.iterdir()}
    code, err = run_cli(["sweep", "--port", SIM, "--resume", str(run_dir)], 120)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Read-only file system" in err, err
    assert str(run_dir) in err and "internal" not in err
    assert {p.name: p.read_bytes() for p in run_dir.iterdir()} == before
    # writable again: the resume completes the run and fit accepts it
    subprocess.run(["mount", "-o", "remount,rw", str(disk)], check=True)
    code, err = run_cli(["sweep", "--port", SIM, "--resume", str(run_dir)], 120)
    assert code == 0, err
    assert run_problem(run_dir) is None and _leftovers(disk) == []


class _FullFile:
    """A file whose writes fail as on a full disk (an OSError that names no file)."""

    def __init__(self, real) -> None:
        self.real = real

    def write(self, text: str) -> int:
        raise OSError(28, "No space left on device")

    def __getattr__(self, name: str):
        return getattr(self.real, name)


@pytest.mark.parametrize("point", ["steps.jsonl", "events.jsonl", "run.json"])
def test_a_full_disk_at_each_later_write_names_the_file(tmp_path, monkeypatch, point) -> None:
    """The disk fills at the first step record, an event, or a run.json rewrite in mid-run: the
    error line names that file (a full disk's OSError names none), the run is left failed or
    running (fit refuses it with one line), no reserve or temporary file is left."""
    import omnibench.runs.store as store

    real_complete, real_save = RunWriter.step_complete, RunWriter.save_metadata
    state = {"armed": False}

    def step_complete(self, record):
        if point == "steps.jsonl":
            self._steps = _FullFile(self._steps)
        if point == "events.jsonl":
            self._events = _FullFile(self._events)
        if point == "run.json":
            state["armed"] = True
        return real_complete(self, record)

    def save_metadata(self):
        if state["armed"]:
            state["armed"] = False
            raise OSError(28, "No space left on device", str(self.path / "run.json"))
        return real_save(self)

    monkeypatch.setattr(RunWriter, "step_complete", step_complete)
    monkeypatch.setattr(RunWriter, "save_metadata", save_metadata)
    out = tmp_path / "runs"
    code, err = run_cli(["sweep", "--port", SIM, "--procedure", str(PROC), "--out", str(out)], 120)
    monkeypatch.setattr(RunWriter, "step_complete", real_complete)
    monkeypatch.setattr(RunWriter, "save_metadata", real_save)
    assert code == 2, err
    (run_dir,) = out.iterdir()
    assert err.strip().splitlines()[-1] == f"omnibench: error: cannot write {run_dir / point}: No space left on device"
    assert "motors stopped" in err and "internal" not in err
    _check_left_state(out, err)
    assert store.RESERVE_NAME not in [p.name for p in run_dir.iterdir()]
