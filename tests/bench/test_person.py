"""A person at the robot: every procedure driven by a scripted person over pseudo-terminals, with
pauses from 1 s to 10 minutes of board time; explicit answers; type-ahead dropped; the tape
questioned when it disagrees with the encoders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from omnibench.runs import read_run
from tests.simserver import spawn_server

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
    # the live view showed the step, duties, wheel speeds, currents, battery, faults and the ETA
    for what in ("step 1/", "duty", "speed rad/s", "current A", "battery", "faults: none", "ETA"):
        assert what in person.output, what
    assert "run complete" in (_only_run(out) / "log.txt").read_text()


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


def _host_time(e: dict) -> float:
    import datetime as dt

    return dt.datetime.fromisoformat(e["host_time"].replace("Z", "+00:00")).timestamp()


def test_explicit_answers_and_type_ahead_dropped(fast_served, tmp_path) -> None:
    """An empty answer confirms nothing (asked again); "yes" typed while the robot was still
    turning does not confirm the next prompt ("Mount wheel set 'weighted'"): only the answer the
    person gives after reading it does."""
    out = tmp_path / "runs"

    def before(person: Person, k: int, text: str) -> None:
        if k == 0:  # a bare Enter
            person.child.sendline("")
            person.child.expect("please type yes or no")
            person.child.expect(r"Type yes when done, or no to stop")
        if k == 1:  # answer, and in the same keystrokes type ahead while the standard set's step runs
            person.child.send("yes\ryes\ryes\r")  # one write: all three are in before the step starts

    person = Person(fast_served, ["sweep", "--port", fast_served.path, "--operator", "person",
                                  "--procedure", str(HERE / "sweep.toml"), "--out", str(out)],
                    pause=lambda k, text: 0.5 if k == 2 else 0.0, answers=lambda k, text: k != 1)
    # k == 1 is answered by `before`; its two extra "yes" are type-ahead
    assert person.run(before) == 0, person.output[-2000:]
    assert "Mount wheel set 'weighted'" in person.prompts[2]
    got = _check_complete(_only_run(out), STEPS["sweep"])
    ops = [e for e in got["events"] if e["kind"] == "operator"]
    weighted = next(e for e in ops if e["action"] == "wheels" and e["step"] == 1)
    assert _host_time(weighted) >= person.answered[2] - 0.05  # confirmed by the answer, not the type-ahead
    assert person.quiet[0]["telemetry_hz"] == 0  # still waiting, board quiet, after the type-ahead
    assert "Next: the wheels spin in the air" in person.prompts[2] and "+0.30" in person.prompts[2]


def test_tape_far_from_the_encoders_is_questioned_at_once(fast_served, tmp_path) -> None:
    """Typing 1.02 m after a short run: "encoders say 0.xx m, you typed 1.02 m: re-measure?".
    Re-measured on the first run (the true reading is kept), kept on the second (flagged)."""
    out = tmp_path / "runs"
    person = Person(fast_served, ["forward", "--port", fast_served.path, "--operator", "person",
                                  "--procedure", str(HERE / "forward.toml"), "--out", str(out)],
                    tape=lambda k, truth: "1.02 m",
                    remeasure=lambda k, text: "TRUTH" if k == 5 else "keep")
    assert person.run() == 0, person.output[-2000:]
    questions = [p for p in person.prompts if "re-measure" in p]
    assert len(questions) == 2
    assert all(__import__("re").search(r"encoders say 0\.\d\d m, you typed 1\.02 m: re-measure\?", q)
               for q in questions)
    st = _check_complete(_only_run(out), 2)["run"].steps
    assert st["tape_questioned"].tolist() == [False, True]
    assert abs(st["measured_distance"].iloc[0] - abs(st["encoder_distance"].iloc[0])) < 0.03
    assert st["measured_distance"].iloc[1] == pytest.approx(1.02)
    assert not st["no_slip"].iloc[1]
