"""Progress on the terminal: the procedure's ETA leaves out time a person spent at a prompt, a
stage's spinner counts its way through the work, and a stage's own lines reach the terminal."""

from __future__ import annotations

import io
from types import SimpleNamespace

import pytest

from omnibench.bench import live
from omnibench.progress import StageStatus, TeeStream


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _sample(t: float) -> SimpleNamespace:
    return SimpleNamespace(t=t, encoder=[0, 0, 0, 0], duty=[0.0] * 4, motor_current=None,
                           battery_voltage=None, battery_current=None, faults=0)


def test_eta_leaves_out_the_time_at_a_prompt(monkeypatch) -> None:
    """The issue's case: 100 s at a prompt, then 40 s of motion left. Without the pause the ETA
    would count the 100 s as the procedure's pace."""
    clock = Clock()
    monkeypatch.setattr(live.time, "monotonic", clock)
    view = live.LiveView("sweep", total=45.0, n_steps=3, counts_per_rev=980, stream=io.StringIO())
    view._draw = lambda: None  # no terminal here
    clock.t = 2.0
    view.advance(3.0)  # 3 s of board time in 2 s of wall time
    view.sample(None, _sample(3.0))
    view.pause()  # a prompt
    clock.t = 102.0  # a person took 100 s
    assert view.eta() == pytest.approx(42.0 * 2.0 / 3.0)  # still at the prompt: the pace it had
    view.sample(None, _sample(3.1))  # answered: the robot moves again
    clock.t = 104.0
    view.advance(3.0)
    assert view.eta() == pytest.approx(39.0 * 4.0 / 6.0)  # 4 s of motion for 6 s of board time
    assert "ETA 26 s" in view.table().caption


def test_stage_status_counts_its_way_to_an_eta() -> None:
    clock = Clock()
    st = StageStatus("diagnose running", clock=clock)
    st.update("round 1: screening 12 candidate effects")
    assert st.eta() is None and "round 1: screening" in st.text()
    st.update("round 1: fitting stribeck_friction (1/4)")
    clock.t = 30.0
    st.update("round 1: fitting driver_deadband (3/4)")  # 2 candidates in 30 s: 15 s each, 2 left
    assert st.eta() == pytest.approx(30.0)
    clock.t = 40.0
    assert st.eta() == pytest.approx(20.0)
    assert st.text() == "diagnose running, 40 s: round 1: fitting driver_deadband (3/4), ETA 20 s"
    st.update("round 2: fitting cogging (1/3)")  # a new round starts its own count
    assert st.eta() is None
    clock.t = 50.0
    st.update("round 2: fitting stribeck_friction (candidate 2 of 3) [00:50]")  # diagnose's own wording
    assert st.eta() == pytest.approx(20.0)


def test_tee_passes_lines_on_and_keeps_them() -> None:
    term, seen = io.StringIO(), []
    tee = TeeStream(term, seen.append)
    tee.write("diagnose: fitting the declared")
    tee.write(" model\ndiagnose: round 1\n")
    assert term.getvalue() == tee.getvalue() == "diagnose: fitting the declared model\ndiagnose: round 1\n"
    assert seen == ["diagnose: fitting the declared model", "diagnose: round 1"]
    with pytest.raises(TypeError):
        tee.write(b"")  # click sees a text stream, not a binary one
    quiet = TeeStream(None)
    quiet.write("kept\n")
    assert quiet.getvalue() == "kept\n" and not quiet.isatty()


@pytest.mark.slow
def test_stage_progress_reaches_the_terminal_and_ctrl_c_there_stops_the_campaign(tmp_path) -> None:
    """A person at a terminal (a pseudo-terminal here) sees the fit's spinner and diagnose's own
    lines while the stages run, and Ctrl-C typed there stops the campaign with exit 130, marked
    as stopped in diagnose."""
    import os
    import sys
    from pathlib import Path

    from tests.simserver import sigint_as_in_a_terminal

    pexpect = pytest.importorskip("pexpect")
    here = Path(__file__).parent
    env = dict(os.environ, COLUMNS="160", LINES="50", TERM="xterm")
    child = pexpect.spawn(sys.executable, ["-m", "omnibench", "campaign", "--port",
                                           "sim://?seed=8&effects.driver_deadband.u_0=0.04",
                                           "--out", str(tmp_path / "c"), "--procedures",
                                           str(here / "procedures" / "campaign"), "--analysis", "fit,diagnose"],
                          env=env, encoding="utf-8", timeout=600, dimensions=(50, 160),
                          preexec_fn=sigint_as_in_a_terminal)  # a suite run as `cmd &` ignores SIGINT
    try:
        child.expect("== fit: omnibench fit")
        child.expect(r"fit running, \d+ s")  # the spinner with the elapsed time
        child.expect("== diagnose: omnibench diagnose")
        # the stage's own lines, as they come; the Ctrl-C goes in at its first one (with this short
        # campaign the whole diagnosis takes seconds)
        child.expect("diagnose: fitting the declared model")
        child.sendintr()  # Ctrl-C
        child.expect("campaign interrupted \\(Ctrl-C\\) in diagnose")
        child.expect(pexpect.EOF)
    finally:
        child.close()
    assert child.exitstatus == 130
    import json

    state = json.loads((tmp_path / "c" / "campaign.json").read_text())
    assert state["status"] == "interrupted" and state["stopped_at"] == "diagnose"
