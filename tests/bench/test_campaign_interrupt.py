"""Ctrl-C during a campaign's analysis stops the campaign (exit 130), keeps what finished, marks
where it stopped in campaign.json and report.md, and `campaign --resume` continues from there."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from tests.simserver import sigint_as_in_a_terminal

HERE = Path(__file__).parent


def _campaign(out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "omnibench", "campaign", "--port", "sim://?seed=8", "--out", str(out),
            "--procedures", str(HERE / "procedures" / "campaign"), "--candidates", "driver_deadband", *extra]


def _interrupt_at(cmd: list[str], line_start: str, limit_s: float = 600.0) -> tuple[int, str]:
    """Run `cmd`, send SIGINT (as a terminal's Ctrl-C does) when a line it prints (stdout or
    stderr) starts with `line_start`; (exit code, everything it printed)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                            preexec_fn=sigint_as_in_a_terminal)
    timer = threading.Timer(limit_s, proc.kill)  # a guard against a hang, not a timing assertion
    timer.start()
    lines = []
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if line.startswith(line_start):
                proc.send_signal(signal.SIGINT)
                break
        err, _ = proc.communicate()
    finally:
        timer.cancel()
    return proc.returncode, "".join(lines) + err


@pytest.mark.slow
def test_ctrl_c_in_fit_and_in_diagnose_exits_130_and_resume_completes(tmp_path):
    out = tmp_path / "c"
    code, err = _interrupt_at(_campaign(out), "== fit:")
    assert code == 130, err
    assert "interrupted" in err and "--resume" in err
    assert "== validate-energy" not in err  # the campaign did not go on
    state = json.loads((out / "campaign.json").read_text())
    assert state["status"] == "interrupted" and state["stopped_at"] == "fit"
    assert state["analysis"]["fit"]["status"] == "interrupted"
    assert "Interrupted (Ctrl-C) in fit" in (out / "report.md").read_text()
    assert len(list((out / "runs").iterdir())) == 4  # the runs are kept

    code, err = _interrupt_at(_campaign(out, "--resume"), "== diagnose:")
    assert code == 130, err
    assert err.count("kept (complete)") == 4  # no procedure ran again
    state = json.loads((out / "campaign.json").read_text())
    assert state["status"] == "interrupted" and state["stopped_at"] == "diagnose"
    assert state["analysis"]["fit"]["status"] == "ok" and state["analysis"]["validate-energy"]["status"] == "ok"
    fit_model = (out / "model.toml").read_bytes()

    res = subprocess.run(_campaign(out, "--resume"), capture_output=True, text=True, timeout=1800)
    assert res.returncode == 0, res.stderr
    assert "== fit: kept" in res.stdout and "== validate-energy: kept" in res.stdout
    assert (out / "model.toml").read_bytes() == fit_model  # the fit was not redone
    state = json.loads((out / "campaign.json").read_text())
    assert state["status"] == "complete"
    assert {st["status"] for st in state["analysis"].values()} == {"ok"}
    assert "Interrupted" not in (out / "report.md").read_text()


def test_ctrl_c_in_an_adaptive_campaign_stops_the_run_and_records_where(tmp_path):
    """An adaptive campaign interrupted in its first planned run: exit 130, that run aborted (the
    motors stopped), campaign.json and report.md say where it stopped, the design log is kept,
    and the message says how to go on (an adaptive campaign plans anew from its runs)."""
    out = tmp_path / "a"
    # a real-time board at 5x: the first planned run (forward runs) lasts about a second of wall
    # time, and the Ctrl-C comes as soon as the run says its folder
    cmd = [sys.executable, "-m", "omnibench", "campaign", "--adaptive", "--port", "sim://?seed=4&clock=realtime&speed=5",
           "--out", str(out), "--target-se", "a=3%,b=2%", "--procedures", str(HERE / "procedures" / "campaign"),
           "--analysis", "none"]
    code, err = _interrupt_at(cmd, "III.ii forward/backward runs: run ")
    assert code == 130, err
    assert "interrupted (Ctrl-C) in forward" in err and "--prior-runs" in err
    state = json.loads((out / "campaign.json").read_text())
    assert state["status"] == "interrupted" and state["stopped_at"] == "forward"
    assert "Interrupted (Ctrl-C) in forward" in (out / "report.md").read_text()
    (run,) = list((out / "runs").iterdir())
    assert json.loads((run / "run.json").read_text())["status"] == "aborted"
    assert json.loads((out / "design.jsonl").read_text().splitlines()[0])["kind"] == "design_round"
