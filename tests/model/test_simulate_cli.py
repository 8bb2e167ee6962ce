"""`omnibench simulate` end to end, and its one-line errors with exit code 2."""

from __future__ import annotations

import subprocess
import sys

import pandas as pd
import pytest

from omnibench.model.closed_form import upside_down_steady_speed as steady_speed_closed_form
from omnibench.model.robot import DEFAULT_ROBOT_FILE


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "omnibench", *args], capture_output=True, text=True, timeout=120)


def test_simulate_upside_down_writes_documented_columns(tmp_path, omnibot):
    cmds = tmp_path / "cmds.csv"
    cmds.write_text("t,u1,u2,u3,u4\n0,0.6,-0.6,0.4,-0.4\n")
    out = tmp_path / "out.csv"
    proc = run_cli("simulate", "--commands", str(cmds), "--upside-down", "--duration", "1.5", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    df = pd.read_csv(out)
    for col in ["t", "x", "y", "psi", "v1", "v2", "psi_dot", "phi1", "phi_dot4", "i1", "i4", "V_batt", "I_batt", "E_batt"]:
        assert col in df.columns
    assert df["t"].iloc[-1] == pytest.approx(1.5)
    F_N = omnibot.wheel_mass[0] * 9.80665
    assert df["phi_dot1"].iloc[-1] == pytest.approx(steady_speed_closed_form(omnibot, 0.6, F_N), rel=1e-4)
    assert df["phi_dot2"].iloc[-1] == pytest.approx(steady_speed_closed_form(omnibot, -0.6, F_N), rel=1e-4)
    assert (df["E_batt"].diff().dropna() >= 0).all()  # driving only: energy flows out of the battery
    assert df["x"].abs().max() == 0.0  # on blocks, the robot does not move


def test_simulate_on_the_ground_with_payload_and_robot_file(tmp_path):
    cmds = tmp_path / "cmds.csv"
    cmds.write_text("t,u1,u2,u3,u4\n0,0.5,0.5,0.5,0.5\n1.0,0,0,0,0\n")
    light, heavy = tmp_path / "light.csv", tmp_path / "heavy.csv"
    assert run_cli("simulate", "--robot", str(DEFAULT_ROBOT_FILE), "--commands", str(cmds), "--out", str(light)).returncode == 0
    assert run_cli("simulate", "--commands", str(cmds), "--payload", "10", "--out", str(heavy)).returncode == 0
    x_light, x_heavy = pd.read_csv(light)["x"].iloc[-1], pd.read_csv(heavy)["x"].iloc[-1]
    assert 0 < x_heavy < x_light  # more load, more friction, shorter run


@pytest.mark.parametrize(
    "content, expect",
    [
        ("t,u1,u2,u3,u4\n0,0.5,0.5,0.5,2.0\n", "cmds.csv:2: duty out of range [-0.97, 0.97]: u4=2.0"),
        ("t,u1,u2,u3\n0,0.5,0.5,0.5\n", "cmds.csv:1: header must name t,u1,u2,u3,u4; missing u4"),
        ("t,u1,u2,u3,u4\n0,0.5,0.5,0.5,0.5\n1,a,b,c,d\n", "cmds.csv:3: expected 5 numbers"),
        ("t,u1,u2,u3,u4\n1,0,0,0,0\n0.5,0,0,0,0\n", "cmds.csv:3: time 0.5 s must be >= 0 and not before the previous row"),
        ("", "empty command file"),
    ],
)
def test_bad_command_file_is_one_line_exit_2(tmp_path, content, expect):
    cmds = tmp_path / "cmds.csv"
    cmds.write_text(content)
    out = tmp_path / "out.csv"
    proc = run_cli("simulate", "--commands", str(cmds), "--out", str(out))
    assert proc.returncode == 2
    assert expect in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert "Traceback" not in proc.stderr
    assert not out.exists()


def test_bad_robot_file_is_one_line_exit_2(tmp_path):
    robot = tmp_path / "robot.toml"
    robot.write_text(DEFAULT_ROBOT_FILE.read_text().replace("R_a = 1.8462", "R_a = -1.8462"))
    cmds = tmp_path / "cmds.csv"
    cmds.write_text("t,u1,u2,u3,u4\n0,0.5,0.5,0.5,0.5\n")
    proc = run_cli("simulate", "--robot", str(robot), "--commands", str(cmds), "--out", str(tmp_path / "o.csv"))
    assert proc.returncode == 2
    assert proc.stderr.strip().startswith("omnibench: error: ")
    assert "robot.toml:" in proc.stderr and "[motor] R_a: must be positive" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
