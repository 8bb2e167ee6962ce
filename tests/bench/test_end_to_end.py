"""Every procedure end to end through the real serial code path: `sim://` in process, the
pseudo-terminal of `omnibench sim serve`, Ctrl-C with resume, and bad input stopped early."""

from __future__ import annotations

import json
import math
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from omnibench.cli import main
from omnibench.model import default_robot
from omnibench.runs import read_run
from tests.simserver import sigint_as_in_a_terminal, spawn_server

HERE = Path(__file__).parent
PROC = HERE / "procedures"
FILES = {"sweep": "small_sweep.toml", "forward": "small_forward.toml",
         "lateral": "small_lateral.toml", "energy": "small_energy.toml"}


def omnibench(capsys, *args: str) -> tuple[int, str, str]:
    """Run the CLI in process; (exit code, stdout, stderr)."""
    code = 0
    try:
        main(list(args))
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def closed_form(robot, u, wheel_mass):
    """Upside-down steady wheel speed, rad/s (see tests/bench/test_runner.py)."""
    from scipy.optimize import brentq

    k = robot.eta * robot.k_t / robot.R_a
    load = 1 + robot.c * wheel_mass * 9.80665
    eps = robot.sign_width_phi

    def f(w):
        return k * (abs(u) * robot.V_batt - robot.k_e * w) - load * (robot.a * w + robot.b * w / math.sqrt(w * w + eps * eps))

    return math.copysign(brentq(f, 0.0, abs(u) * robot.V_batt / robot.k_e), u)


def check_run(command: str, run_dir: str) -> None:
    """The recorded data reproduce the simulated world."""
    run = read_run(run_dir)
    assert run.status == "complete"
    assert list(run.steps["step"]) == list(range(run.metadata["steps_planned"]))
    assert run.metadata["board"]["capabilities"] and "SIMULATOR" in run.metadata["board"]["capabilities"]
    steps = run.steps
    if command == "sweep":
        robot = default_robot()
        assert steps["steady"].all()
        for _, s in steps.iterrows():
            expect = closed_form(robot, s["duty"], s["wheel_mass1"])
            for j in range(1, 5):
                # encoder quantisation (980 counts/rev) over a 0.3 s fit: ~0.02 rad/s
                assert s[f"w{j}"] == pytest.approx(expect, abs=0.05), (s["label"], j)
        # heavier wheels load the axle more: slower at the same duty (the c term)
        std = steps[(steps.wheel_set == "standard") & (steps.duty == 0.7)]["w1"].iloc[0]
        heavy = steps[(steps.wheel_set == "weighted") & (steps.duty == 0.7)]["w1"].iloc[0]
        assert heavy < std
    elif command == "forward":
        assert steps["no_slip"].all()
        assert (abs(steps["measured_distance"] - steps["encoder_distance"].abs()) < 0.015).all()
    elif command == "lateral":
        assert not steps["no_slip"].any()  # the rollers turn: slip is reported on every run
        assert (steps["kin_residual"] < 0.02).all()  # yet pinv(R) dphi matches the tape
        assert sorted(set(steps["payload"])) == [0.0, 3.0]
    elif command == "energy":
        assert steps["has_current"].all() and (steps["energy"] > 0).all()
        s = run.step_samples(0)
        assert np.trapezoid(s["V_batt"] * s["I_batt"], s["t"]) == pytest.approx(steps["energy"].iloc[0])


@pytest.mark.parametrize("command", list(FILES))
def test_procedure_over_sim_url(capsys, tmp_path, command):
    code, out, err = omnibench(capsys, command, "--port", "sim://?seed=5", "--procedure", str(PROC / FILES[command]),
                               "--out", str(tmp_path), "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["status"] == "complete"
    check_run(command, res["run"])


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    srv = spawn_server(tmp_path_factory.mktemp("serve"), "--clock", "fast", "--seed", "3")
    yield srv
    srv.stop()


def test_all_procedures_over_sim_serve(capsys, tmp_path, served):
    for command in FILES:
        code, out, err = omnibench(capsys, command, "--port", served.path, "--procedure", str(PROC / FILES[command]),
                                   "--out", str(tmp_path), "--json")
        assert code == 0, err
        check_run(command, json.loads(out)["run"])
    st = served.status()
    assert st["duties"] == [0.0, 0.0, 0.0, 0.0]


def _wait_rows(path: Path, rows: int, proc: subprocess.Popen, limit_s: float = 300.0) -> None:
    """Wait for `rows` recorded samples (generous guard: a cold start may compile the physics kernel)."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline and proc.poll() is None:
        files = list(path.glob("*/samples.csv"))
        if files and sum(1 for _ in open(files[0])) > rows:
            return
        time.sleep(0.01)
    raise AssertionError("the sweep did not record enough samples")


@pytest.mark.slow
def test_sigint_stops_motors_marks_aborted_and_resume_completes(tmp_path):
    seed = random.randrange(1_000_000)
    rng = random.Random(seed)
    print(f"random seed {seed}")  # shown on failure
    srv = spawn_server(tmp_path, "--clock", "realtime", "--speed", "1", "--seed", str(seed))
    try:
        out = tmp_path / "runs"
        cmd = [sys.executable, "-m", "omnibench", "sweep", "--port", srv.path, "--procedure",
               str(PROC / "sigint_sweep.toml"), "--out", str(out)]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                preexec_fn=sigint_as_in_a_terminal)
        _wait_rows(out, rng.randint(3, 150), proc)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 130, err
        assert "aborted" in err and "--resume" in err
        time.sleep(0.3)
        st = srv.status()
        assert st["duties"] == [0.0, 0.0, 0.0, 0.0] and st["serving"]
        (run_dir,) = list(out.iterdir())
        run = read_run(run_dir)
        assert run.status == "aborted"
        done = list(run.steps["step"]) if len(run.steps) else []
        assert done == list(range(len(done))) and len(done) < 8
        n = len(run.samples)
        res = subprocess.run(cmd[:4] + ["--resume", str(run_dir), "--json"] + ["--port", srv.path],
                             capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        run = read_run(run_dir)
        assert run.status == "complete"
        assert list(run.steps["step"]) == list(range(8))  # none missing, none twice
        assert len(run.samples) > n
        assert [s["status"] for s in run.metadata["segments"]] == ["aborted", "complete"]
        assert srv.status()["duties"] == [0.0, 0.0, 0.0, 0.0]
    finally:
        srv.stop()


BAD_TOML = 'procedure = "upside_down_sweep"\n[sweep\nduties = [0.2]\n'
HIGH_V = 'procedure = "upside_down_sweep"\n[sweep]\nvoltages = ["6 V", "40 V"]\n'


@pytest.mark.parametrize(
    "text, args, message",
    [
        (BAD_TOML, ["--port", "/dev/omnibench-no-such-port"], "not valid TOML"),
        (HIGH_V, ["--port", "/dev/omnibench-no-such-port"], "40 V is out of range"),
        (HIGH_V.replace("40 V", "12 V"), [], "no --port given"),
        (HIGH_V.replace("40 V", "12 V"), ["--port", "/dev/omnibench-no-such-port"], "cannot open"),
    ],
)
def test_bad_input_one_line_error_before_any_motor_moves(capsys, tmp_path, text, args, message):
    p = tmp_path / "p.toml"
    p.write_text(text)
    out = tmp_path / "runs"
    code, _, err = omnibench(capsys, "sweep", "--procedure", str(p), "--out", str(out), *args)
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], err
    assert not out.exists()  # nothing was recorded: the run never started


def test_dry_run_prints_plan_and_refuses_over_limit(capsys, tmp_path):
    code, out, err = omnibench(capsys, "sweep", "--dry-run", "--procedure", str(PROC / "small_sweep.toml"))
    assert code == 0, err
    assert "12 steps" in out and "peak voltage 17.3 V" in out and "at most" in out
    code, out, _ = omnibench(capsys, "lateral", "--dry-run", "--json")
    res = json.loads(out)
    assert res["steps"] == 18 and res["peak_motor_current_A"] < res["limits"]["max_current_A"]
    robot = Path(__file__).resolve().parents[2] / "omnibench" / "model" / "omnibot.toml"
    weak = tmp_path / "weak.toml"
    weak.write_text(robot.read_text().replace("max_current = 13.0", "max_current = 5.0"))
    code, _, err = omnibench(capsys, "sweep", "--dry-run", "--robot", str(weak), "--procedure",
                             str(PROC / "small_sweep.toml"))
    assert code == 2 and "max_current 5 A" in err and len(err.strip().splitlines()) == 1


def test_answers_file_supplies_the_tape(capsys, tmp_path):
    answers = tmp_path / "answers.toml"
    answers.write_text('actions = "done"\n[distance]\n0 = "40 cm"\n1 = 0.41\n2 = "0.8 m"\n3 = "81 cm"\n')
    code, out, err = omnibench(capsys, "forward", "--port", "sim://?seed=2", "--procedure",
                               str(PROC / "small_forward.toml"), "--answers", str(answers),
                               "--out", str(tmp_path), "--json")
    assert code == 0, err
    run = read_run(json.loads(out)["run"])
    assert list(run.steps["measured_distance"]) == pytest.approx([0.40, 0.41, 0.80, 0.81])
    # the simulated operator still flips/places the robot; the tape readings came from the file
    assert run.metadata["operator"] == "simulated-operator"
    answers.write_text('[distance]\n0 = "40 cm"\n')
    code, _, err = omnibench(capsys, "forward", "--port", "sim://", "--procedure", str(PROC / "small_forward.toml"),
                             "--answers", str(answers), "--out", str(tmp_path / "x"))
    assert code == 2 and "no answer for step 1" in err
    assert not (tmp_path / "x").exists()


def test_energy_with_external_ammeter_matches_board_sensor(capsys, tmp_path):
    energies = {}
    for label, args in (("board", ["--port", "sim://?seed=2"]),
                        ("ammeter", ["--port", "sim://?name=bench-e2e&seed=2", "--ammeter", "sim://ammeter?board=bench-e2e"])):
        code, out, err = omnibench(capsys, "energy", *args, "--procedure", str(PROC / "small_energy.toml"),
                                   "--out", str(tmp_path / label), "--json")
        assert code == 0, err
        run = read_run(json.loads(out)["run"])
        energies[label] = run.steps["energy"].to_numpy()
        if label == "ammeter":
            assert run.metadata["board"]["ammeter"]["url"].startswith("sim://ammeter")
            # readings only every 50 ms of board time: fewer current samples than telemetry rows
            assert 0 < run.samples["I_batt"].notna().sum() < len(run.samples)
    np.testing.assert_allclose(energies["ammeter"], energies["board"], rtol=0.05)


def test_resume_refuses_complete_and_foreign_runs(capsys, tmp_path):
    code, out, err = omnibench(capsys, "forward", "--port", "sim://?seed=9", "--procedure",
                               str(PROC / "small_forward.toml"), "--out", str(tmp_path), "--json")
    assert code == 0, err
    run_dir = json.loads(out)["run"]
    code, _, err = omnibench(capsys, "forward", "--port", "sim://", "--resume", run_dir)
    assert code == 2 and "already complete" in err
    code, _, err = omnibench(capsys, "sweep", "--port", "sim://", "--resume", run_dir)
    assert code == 2 and "is a forward_runs run" in err
    code, _, err = omnibench(capsys, "sweep", "--port", "sim://", "--resume", str(tmp_path))
    assert code == 2 and "not a run directory" in err


@pytest.mark.slow
def test_killed_process_leaves_a_readable_incomplete_run_that_resumes(tmp_path):
    """SIGKILL (no chance to clean up): the run reads as `running`, keeps its flushed samples,
    and --resume completes it."""
    out = tmp_path / "runs"
    cmd = [sys.executable, "-m", "omnibench", "sweep", "--port", "sim://?clock=realtime&seed=4",
           "--procedure", str(PROC / "sigint_sweep.toml"), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _wait_rows(out, 60, proc)
    proc.kill()
    proc.wait(timeout=30)
    (run_dir,) = list(out.iterdir())
    run = read_run(run_dir)
    assert run.status == "running" and run.metadata["ended"] is None
    assert len(run.samples) >= 60
    n = len(run.samples)
    res = subprocess.run([sys.executable, "-m", "omnibench", "sweep", "--port", "sim://?seed=4", "--resume",
                          str(run_dir), "--json"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    run = read_run(run_dir)
    assert run.status == "complete" and list(run.steps["step"]) == list(range(8))
    assert len(run.samples) > n
    assert [s["previous_status"] for s in run.metadata["segments"][1:]] == ["running"]


def test_board_fault_mid_sweep_stops_keeps_the_data_and_exits_3(capsys, tmp_path):
    """The simulated board's overcurrent protection (4 A) trips when the sweep steps the duty
    up from rest: the run stops with the fault recorded, keeps every sample taken, reports
    one line naming the fault and the step, and exits 3; the board ends with motors off."""
    from omnibench.sim import registry

    name = f"oc-{tmp_path.name}"
    code, _, err = omnibench(capsys, "sweep", "--port", f"sim://?name={name}&overcurrent_limit=4",
                             "--procedure", str(PROC / FILES["sweep"]), "--out", str(tmp_path))
    assert code == 3
    last = err.strip().splitlines()[-1]
    assert last.startswith("omnibench: error: board reported fault OVERCURRENT during step ")
    (run_dir,) = list(tmp_path.iterdir())
    run = read_run(run_dir)
    assert run.status == "failed" and "OVERCURRENT" in run.metadata["reason"]
    assert len(run.samples) > 10 and run.samples["faults"].iloc[-1] != 0
    faults = run.events[run.events["kind"] == "fault"]
    assert len(faults) == 1 and faults["names"].iloc[0] == "OVERCURRENT"
    st = registry.get(name).status()
    assert st["duties"] == [0.0, 0.0, 0.0, 0.0] and st["faults"] == ["OVERCURRENT"]
    assert "motors stopped" in err and "NOT confirmed" not in err


def test_a_longer_speed_average_holds_each_level_longer_and_the_fit_states_its_smaller_error(capsys, tmp_path):
    """A sweep file whose steady_state.average is 0.6 s (the planner writes such files): every
    level is held at least min_hold + 0.6 s over sim://, its record says so, and the observations
    read the speed over those 0.6 s: about 60 samples, and an SE well under the 0.3 s one (a line
    through the encoder's rounding: SE ~ average^-1.5, 2.8 x smaller for twice the time)."""
    from omnibench.analysis.observations import Observations

    text = (PROC / FILES["sweep"]).read_text()
    longer = tmp_path / "sweep_06.toml"
    longer.write_text(text.replace('max_hold = "2 s"', 'max_hold = "2 s"\naverage = "0.6 s"'))
    se, n = {}, {}
    for name, path in (("0.3", PROC / FILES["sweep"]), ("0.6", longer)):
        code, out, err = omnibench(capsys, "sweep", "--port", "sim://?seed=5", "--procedure", str(path),
                                   "--out", str(tmp_path / name), "--json")
        assert code == 0, err
        run = read_run(json.loads(out)["run"])
        assert (run.steps["average"] == float(name)).all()
        assert (run.steps["hold_time"] >= 0.2 + float(name) - 0.011).all()  # min_hold + average, one sample
        obs = Observations.from_runs([run.path], default_robot())
        se[name] = float(np.median(obs.sweep["omega_se"]))
        n[name] = obs.sweep["n"].to_numpy()
    assert ((n["0.6"] >= 58) & (n["0.6"] <= 62)).all() and ((n["0.3"] >= 28) & (n["0.3"] <= 32)).all()
    assert se["0.6"] < se["0.3"] / 2
