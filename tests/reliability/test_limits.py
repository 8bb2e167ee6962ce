"""Limits a lab can trust (issue 38): the lab's space for a ground step (`[space] max_distance`,
3 m by default) checked by the dry run and enforced from the encoders; robot-file duty limits
that are reachable and precise; SIGTERM recorded as such; two campaigns never share an --out."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import pytest

from omnibench import locks
from omnibench.errors import UserError
from omnibench.model import default_robot
from omnibench.procedures import check_limits, duty_limit, load_plan, stall_current
from omnibench.runs import read_run
from omnibench.runs.store import RunWriter
from reliability.badinput import PROC, PROCEDURES, run_cli

ROOT = Path(__file__).resolve().parents[2]


def _forward(tmp_path: Path, duration: str = "1.5 s", duty: float = 0.7, space: str | None = None) -> Path:
    text = (PROCEDURES["forward"].replace('duration = "0.5 s"', f'duration = "{duration}"')
            .replace("duties = [0.3]", f"duties = [{duty}]"))
    if space is not None:
        text += f'[space]\nmax_distance = "{space}"\n'
    p = tmp_path / "forward.toml"
    p.write_text(text)
    return p


def test_an_hour_long_forward_run_is_refused_by_the_dry_run_with_its_distance(tmp_path) -> None:
    code, err = run_cli(["forward", "--dry-run", "--procedure", str(_forward(tmp_path, "3600 s"))])
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "step 0" in err and "m from its start" in err and "max_distance 3 m" in err
    metres = float(err.split("could take the robot ")[1].split(" m")[0])
    assert 1000 < metres < 5000  # 0.7 x 24.7 V / k_e x r = 0.72 m/s for an hour: kilometres
    code, err = run_cli(["forward", "--dry-run", "--procedure", str(_forward(tmp_path, "1.5 s"))])
    assert code == 0, err


@pytest.mark.parametrize("command", ["forward", "lateral", "energy"])
def test_the_shipped_ground_procedures_fit_the_default_space(capsys, command) -> None:
    code, err = run_cli([command, "--dry-run"])
    assert code == 0, err
    from omnibench.bench.session import plan_summary

    robot = default_robot()
    plan = load_plan(ROOT / "procedures" / f"{ {'forward': 'forward_runs', 'lateral': 'lateral_runs', 'energy': 'energy_trajectories'}[command]}.toml", robot)
    s = plan_summary(plan, robot)
    assert 0 < s["max_step_distance_m"] <= 3.0 and s["limits"]["max_distance_m"] == 3.0


def test_the_runner_stops_a_robot_that_drives_past_the_space(tmp_path) -> None:
    """The dry run's bound trusts the robot file; a robot file whose k_e is 4x the simulated
    robot's predicts a quarter of the distance: the encoders catch it and stop the motors."""
    robot = tmp_path / "slow_robot.toml"
    robot.write_text((ROOT / "omnibench" / "model" / "omnibot.toml").read_text()
                     .replace("k_e = 1.6044", "k_e = 6.4176"))
    proc = _forward(tmp_path, "1.5 s", 0.6, space="0.3 m")
    out = tmp_path / "runs"
    code, err = run_cli(["forward", "--port", "sim://?seed=4", "--robot", str(robot), "--procedure", str(proc),
                         "--out", str(out)], 120)
    assert code == 2, err
    assert "past the lab's space ([space] max_distance 0.3 m); motors stopped" in err.strip().splitlines()[-1]
    (run_dir,) = out.iterdir()
    run = read_run(run_dir)
    assert run.status == "failed"
    ev = run.events
    hit = ev[ev["kind"] == "distance_limit"]
    assert len(hit) == 1 and 0.3 < float(hit["distance"].iloc[0]) < 0.35  # stopped within a sample or two
    assert list(ev["kind"]).index("distance_limit") < list(ev["kind"]).index("motors_stopped")


def test_max_duty_is_reachable_and_its_messages_precise(tmp_path) -> None:
    robot = default_robot()
    assert stall_current(robot, robot.max_duty) <= robot.max_current  # the shipped limits agree
    assert duty_limit(robot) == pytest.approx(robot.max_duty)
    plan = load_plan(_forward(tmp_path, "0.5 s", robot.max_duty), robot)  # max_duty itself runs
    check_limits(plan, robot)
    with pytest.raises(UserError, match=r"duty 0\.9700001 exceeds the robot's max_duty 0\.97\b"):
        load_plan(_forward(tmp_path, "0.5 s", 0.9700001), robot)
    loose = robot.replace(max_duty=1.0)  # a robot file whose max_duty its max_current never allows
    with pytest.raises(UserError, match=r"13\.4 A at stall, above the robot's max_current 13 A "
                                        r"\(the highest duty this robot file allows is 0\.972\)"):
        load_plan(_forward(tmp_path, "0.5 s", 1.0), loose)


def test_sigterm_is_recorded_as_sigterm(tmp_path, monkeypatch) -> None:
    real = RunWriter.sample
    calls = [0]

    def sample(self, row):
        calls[0] += 1
        if calls[0] == 40:
            os.kill(os.getpid(), signal.SIGTERM)  # the runner's handler turns it into Terminated
        return real(self, row)

    monkeypatch.setattr(RunWriter, "sample", sample)
    before = signal.getsignal(signal.SIGTERM)
    code, err = run_cli(["sweep", "--port", "sim://?seed=3", "--procedure", str(PROC), "--out", str(tmp_path)], 120)
    assert code == 143 and "terminated (SIGTERM)" in err and "Ctrl-C" not in err, err
    (run_dir,) = tmp_path.iterdir()
    meta = json.loads((run_dir / "run.json").read_text())
    assert meta["status"] == "aborted" and meta["reason"] == "terminated (SIGTERM)"
    assert signal.getsignal(signal.SIGTERM) == before  # the run's handler is gone again


def test_a_second_campaign_into_one_folder_is_refused_naming_the_first(tmp_path) -> None:
    out = tmp_path / "campaign"
    with locks.folder_lock(out, "a campaign") as lock:  # the first campaign, still writing
        assert lock.read_text().strip() == str(os.getpid())
        code, err = run_cli(["campaign", "--port", "sim://?seed=1", "--out", str(out)])
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert f"process {os.getpid()}" in err and "a campaign is writing into this folder" in err
        assert sorted(p.name for p in out.iterdir()) == [locks.LOCK_FILE]  # the second wrote nothing
        code, err = run_cli(["campaign", "--port", "sim://?seed=1", "--out", str(out), "--adaptive",
                             "--target-se", "a=5%"])
        assert code == 2 and f"process {os.getpid()}" in err, err
    assert not out.exists()  # the lock file goes with the first campaign (it made the folder)


def test_two_campaign_processes_into_one_folder_the_second_is_refused(tmp_path) -> None:
    import subprocess
    import sys
    import time

    from tests.simserver import sigint_as_in_a_terminal

    out = tmp_path / "campaign"
    procs = ROOT / "tests" / "bench" / "procedures" / "campaign"
    first = subprocess.Popen([sys.executable, "-m", "omnibench", "-q", "campaign", "--port",
                              "sim://?seed=2&clock=realtime", "--out", str(out), "--procedures", str(procs)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             preexec_fn=sigint_as_in_a_terminal)  # it is stopped with SIGINT below
    try:
        deadline = time.monotonic() + 120
        def held() -> bool:  # the PID is written once the lock is taken (the file exists a moment before)
            try:
                return (out / locks.LOCK_FILE).read_text().strip() == str(first.pid)
            except OSError:
                return False

        while not held() and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert first.poll() is None, first.stderr.read() if first.stderr else ""
        code, err = run_cli(["campaign", "--port", "sim://?seed=3", "--out", str(out), "--resume"])
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert f"process {first.pid}" in err and "a campaign is writing into this folder" in err
    finally:
        first.send_signal(signal.SIGINT)
        first.wait(300)  # a Ctrl-C during the kernel compile is handled when the compile ends (minutes on a loaded CI machine)
