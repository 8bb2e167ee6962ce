"""A person at the robot: every procedure driven by a scripted person over pseudo-terminals, with
pauses from 1 s to 10 minutes of board time; explicit answers; type-ahead dropped; the tape
questioned when it disagrees with the encoders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from omnibench.runs import read_run
from omnibench.sim.testing import spawn_server

from .person import Person

HERE = Path(__file__).parent / "person_procedures"
COMMAND = {"sweep": "upside_down_sweep", "forward": "forward_runs", "lateral": "lateral_runs",
           "energy": "energy_trajectories"}
SPEED = 200.0  # fast clock: while telemetry is off, 1 wall s is 200 board s


@pytest.fixture(scope="module")
def fast_served(tmp_path_factory):
    s = spawn_server(tmp_path_factory.mktemp("person"), "--clock", "fast", "--speed", str(SPEED), "--seed", "2")
    yield s
    s.stop()


def _only_run(out: Path) -> Path:
    runs = [p for p in out.iterdir() if (p / "run.json").is_file()]
    assert len(runs) == 1, runs
    return runs[0]


def _check_complete(run_dir: Path, n_steps: int) -> dict:
    run = read_run(run_dir)
    assert run.status == "complete"
    assert sorted(run.steps["step"].tolist()) == list(range(n_steps))  # every step exactly once
    events = [json.loads(x) for x in (run_dir / "events.jsonl").read_text().splitlines()]
    pauses = sum(1 for e in events if e.get("kind") == "pause")
    resyncs = sum(1 for e in events if e.get("kind") == "resync")
    assert pauses >= 1 and resyncs >= pauses - 1  # every pause but a final one is re-synchronised
    return {"run": run, "events": events}


STEPS = {"sweep": 2, "forward": 2, "lateral": 2, "energy": 2}
#: the prompt (0-based) between two steps where the person pauses 10 minutes of board time
LONG = {"sweep": 2, "forward": 4, "lateral": 5, "energy": 4}


@pytest.mark.parametrize("name", ["sweep", "forward", "lateral", "energy"])
def test_every_procedure_with_a_person_pausing_up_to_ten_minutes(fast_served, tmp_path, name) -> None:
    """Pauses of 1 s, 30 s and 10 min of board time (the last between two steps): the board stays quiet
    (telemetry off, motors stopped, no fault) and the run completes with every step once."""
    out = tmp_path / "runs"
    pauses = {0: 1.0 / SPEED, 1: 30.0 / SPEED, LONG[name]: 600.0 / SPEED}
    person = Person(fast_served, [name, "--port", fast_served.path, "--operator", "person",
                                  "--procedure", str(HERE / f"{name}.toml"), "--out", str(out)],
                    pause=lambda k, text: pauses.get(k, 0.0))
    code = person.run()
    assert code == 0, person.output[-2000:]
    assert len(person.quiet) == 3
    for q in person.quiet:
        assert q["telemetry_hz"] == 0 and q["motors_stopped"] and q["faults"] == [], q
    got = _check_complete(_only_run(out), STEPS[name])
    t = got["run"].samples["t"].to_numpy()
    assert (t[1:] - t[:-1]).max() >= 600.0 * 0.9  # the board clock ran on through the long pause
    assert all("Next:" in p for p in person.prompts if "Type yes" in p)  # says what moves next


def test_forward_with_a_person_on_a_realtime_board(tmp_path) -> None:
    """The failure of the issue: on a real-time board a prompt answered after 6-20 s lost the
    link. Pauses of 1 s and 8 s at the start mark and the tape, the board quiet throughout."""
    served = spawn_server(tmp_path, "--clock", "realtime", "--seed", "3")
    try:
        out = tmp_path / "runs"
        pauses = {3: 1.0, 4: 8.0}
        person = Person(served, ["forward", "--port", served.path, "--operator", "person",
                                 "--procedure", str(HERE / "forward.toml"), "--out", str(out)],
                        pause=lambda k, text: pauses.get(k, 0.0))
        assert person.run() == 0, person.output[-2000:]
    finally:
        served.stop()
    assert [q["telemetry_hz"] for q in person.quiet] == [0, 0]
    assert all(q["motors_stopped"] and q["faults"] == [] for q in person.quiet)
    got = _check_complete(_only_run(out), STEPS["forward"])
    assert got["run"].steps["no_slip"].all()  # the person read the tape right, and it agrees
