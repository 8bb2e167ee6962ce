"""Disk full / read-only output, two --resume of one run, faults cleared only with consent (issue 12)."""

from __future__ import annotations

import errno
import json
import time
from pathlib import Path

import pytest

from omnibench import locks
from omnibench.cli import main
from omnibench.link.board import Board
from omnibench.runs import read_run
from omnibench.runs.store import RunWriter
from tests.simserver import spawn_server

PROC = Path(__file__).parent / "procedures" / "stall_sweep.toml"


def omnibench(capsys, *args: str) -> tuple[int, str, str]:
    code = 0
    try:
        main(list(args))
    except SystemExit as e:
        code = int(e.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("code, text", [(errno.ENOSPC, "No space left on device"),
                                        (errno.EROFS, "Read-only file system")])
def test_full_or_read_only_output_one_line_motors_stopped_resumable(capsys, tmp_path, monkeypatch, code, text):
    real = RunWriter.sample
    calls = [0]

    def sample(self, row):
        calls[0] += 1
        if calls[0] == 40:
            raise OSError(code, text, str(self.path / "samples.csv"))
        return real(self, row)

    monkeypatch.setattr(RunWriter, "sample", sample)
    rc, out, err = omnibench(capsys, "sweep", "--port", "sim://?seed=3", "--procedure", str(PROC),
                             "--out", str(tmp_path))
    assert rc != 0 and "Traceback" not in err and "internal error" not in err
    (run_dir,) = tmp_path.iterdir()
    assert f"cannot write {run_dir / 'samples.csv'}: {text}" in err
    assert "motors stopped" in err and f"--resume {run_dir}" in err
    assert sorted(p.name for p in run_dir.iterdir()) == ["events.jsonl", "log.txt", "procedure.toml", "robot.toml",
                                                         "run.json", "samples.csv", "steps.jsonl"]
    assert json.loads((run_dir / "run.json").read_text())["status"] == "failed"
    monkeypatch.setattr(RunWriter, "sample", real)
    rc, out, err = omnibench(capsys, "sweep", "--port", "sim://?seed=3", "--resume", str(run_dir))
    assert rc == 0, err
    assert read_run(run_dir).status == "complete"


def test_second_resume_of_one_run_is_refused_and_changes_nothing(capsys, tmp_path, monkeypatch) -> None:
    real = RunWriter.sample
    calls = [0]

    def sample(self, row):
        calls[0] += 1
        if calls[0] == 40:
            raise KeyboardInterrupt
        return real(self, row)

    monkeypatch.setattr(RunWriter, "sample", sample)
    rc, _, err = omnibench(capsys, "sweep", "--port", "sim://?seed=3", "--procedure", str(PROC), "--out", str(tmp_path))
    assert rc == 130
    monkeypatch.setattr(RunWriter, "sample", real)
    (run_dir,) = tmp_path.iterdir()
    before = {p.name: p.read_bytes() for p in run_dir.iterdir()}
    fd = locks.lock_directory(run_dir)  # "another process" resuming it now
    try:
        rc, _, err = omnibench(capsys, "sweep", "--port", "sim://?seed=3", "--resume", str(run_dir))
    finally:
        import os

        os.close(fd)
    assert rc != 0 and len(err.strip().splitlines()) == 1 and "being written by process" in err
    assert {p.name: p.read_bytes() for p in run_dir.iterdir()} == before


def test_latched_fault_is_shown_cleared_with_consent_and_logged(capsys, tmp_path) -> None:
    srv = spawn_server(tmp_path, "--clock", "fast", "--seed", "9")
    try:
        with Board.open(srv.path) as b:  # a previous session that hung: the watchdog fired
            b.configure(watchdog_s=0.05)
            b.set_duties([0.2] * 4)
            time.sleep(0.4)
        assert srv.status()["faults"] == ["WATCHDOG"]
        rc, out, err = omnibench(capsys, "sweep", "--port", srv.path, "--procedure", str(PROC),
                                 "--out", str(tmp_path / "runs"))
        assert rc == 0, err
        (run_dir,) = (tmp_path / "runs").iterdir()
        run = read_run(run_dir)
        kinds = list(run.events["kind"])
        assert kinds.index("faults_latched") < kinds.index("faults_cleared") < kinds.index("step_start")
        answers = [a for a in run.metadata["operator_answers"] if a["action"] == "clear_faults"]
        assert len(answers) == 1 and "WATCHDOG" in answers[0]["prompt"]
    finally:
        srv.stop()


def test_board_info_shows_latched_faults_and_leaves_them_latched(capsys, tmp_path) -> None:
    srv = spawn_server(tmp_path, "--clock", "fast", "--seed", "9")
    try:
        rc, out, err = omnibench(capsys, "board", "info", "--port", srv.path)
        assert rc == 0 and "faults latched: none" in out, err
        with Board.open(srv.path) as b:  # a session that hung: the watchdog fired
            b.configure(watchdog_s=0.05)
            b.set_duties([0.2] * 4)
            time.sleep(0.4)
        rc, out, err = omnibench(capsys, "board", "info", "--port", srv.path)
        assert rc == 0 and "faults latched: WATCHDOG" in out, err
        rc, out, err = omnibench(capsys, "board", "info", "--port", srv.path, "--json")
        assert json.loads(out)["faults"] == ["WATCHDOG"]
        assert srv.status()["faults"] == ["WATCHDOG"]  # shown, not cleared
    finally:
        srv.stop()
