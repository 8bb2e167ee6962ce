"""Procedure files: the shipped ones expand into sane plans; bad ones fail in one line."""

from __future__ import annotations

import math

import numpy as np
import pytest

from omnibench.errors import UserError
from omnibench.model import default_robot
from omnibench.procedures import (
    PROCEDURES,
    body_velocity_duties,
    default_procedure_path,
    load_plan,
)


@pytest.fixture(scope="module")
def robot():
    return default_robot()


@pytest.mark.parametrize("name", PROCEDURES)
def test_shipped_files_expand_within_limits(robot, name):
    plan = load_plan(default_procedure_path(name), robot, expect=name)
    assert plan.procedure == name
    assert plan.steps and [s.index for s in plan.steps] == list(range(len(plan.steps)))
    assert 0 < plan.peak_duty <= robot.max_duty
    assert plan.max_duration > 0


def test_sweep_covers_both_directions_and_wheel_sets(robot):
    plan = load_plan(default_procedure_path("upside_down_sweep"), robot)
    duties = [s.params["duty"] for s in plan.steps]
    assert min(duties) < 0 < max(duties)
    assert {s.world.wheel_set for s in plan.steps} == {"standard", "weighted"}
    assert all(s.world.mode == "upside_down" for s in plan.steps)
    heavy = [s for s in plan.steps if s.world.wheel_set == "weighted"][0]
    assert heavy.params["wheel_mass1"] == pytest.approx(1.9)


def test_lateral_duties_follow_inverse_kinematics(robot):
    # pure lateral motion to the left: FL and RR backwards, FR and RL forwards (docs/robot-file.md, the model)
    u = body_velocity_duties(robot, np.array([0.0, 0.3, 0.0]))
    assert u[0] < 0 and u[3] < 0 and u[1] > 0 and u[2] > 0
    np.testing.assert_allclose(abs(u), robot.k_e * 0.3 / robot.r / robot.V_batt)
    plan = load_plan(default_procedure_path("lateral_runs"), robot)
    assert sorted({s.world.payload for s in plan.steps}) == [0.0, 2.0, 4.0]


def test_energy_square_returns_to_start(robot):
    plan = load_plan(default_procedure_path("energy_trajectories"), robot)
    sq = next(s for s in plan.steps if s.params["trajectory"] == "square")
    segs = np.array(sq.params["segments"])
    disp = (segs[:, :1] * segs[:, 1:3]).sum(axis=0)
    np.testing.assert_allclose(disp, 0.0, atol=1e-12)
    assert len(sq.schedule) == 4


def _write(tmp_path, text):
    p = tmp_path / "p.toml"
    p.write_text(text)
    return p


SWEEP = """procedure = "upside_down_sweep"
[sweep]
{levels}
[steady_state]
max_hold = "3 s"
"""


@pytest.mark.parametrize(
    "text, message",
    [
        (SWEEP.format(levels='voltages = ["5 V", "30 V"]'), r"p.toml:3: \[sweep\] voltages: 30 V is out of range"),
        (SWEEP.format(levels="duties = [0.5, 1.5]"), r"p.toml:3: \[sweep\] duties: duty 1.5 exceeds"),
        (SWEEP.format(levels='duties = ["0.5 kg"]'), r"\[sweep\] duties: .*not in units compatible"),
        (SWEEP.format(levels="dutys = [0.5]"), r"\[sweep\] dutys: unknown key \(did you mean duties\?\)"),
        (SWEEP.format(levels="duties = [0.5]").replace('"3 s"', '"3 kg"'), r"p.toml:5: \[steady_state\] max_hold"),
        ('procedure = "sweep"\n', r"p.toml:1: procedure: expected one of"),
        ("procedure = [\n", r"p.toml: not valid TOML"),
    ],
)
def test_bad_files_give_one_line_errors(tmp_path, robot, text, message):
    with pytest.raises(UserError, match=message) as exc:
        load_plan(_write(tmp_path, text), robot)
    assert "\n" not in str(exc.value)


def test_wrong_procedure_for_command_and_current_limit(tmp_path, robot):
    p = _write(tmp_path, SWEEP.format(levels="duties = [0.5]"))
    with pytest.raises(UserError, match="runs forward_runs"):
        load_plan(p, robot, expect="forward_runs")
    weak = robot.replace(max_current=3.0)  # 0.5 * 24.7 V / 1.85 ohm = 6.7 A at stall
    with pytest.raises(UserError, match="max_current 3 A"):
        load_plan(p, weak)
    with pytest.raises(UserError, match="procedure file not found"):
        load_plan(tmp_path / "missing.toml", robot)


def test_voltages_convert_with_battery_voltage(tmp_path, robot):
    plan = load_plan(_write(tmp_path, SWEEP.format(levels='voltages = ["12.35 V", 6.175]')), robot)
    assert sorted({abs(s.params["duty"]) for s in plan.steps}) == pytest.approx([0.25, 0.5])
    assert math.isclose(plan.steps[0].params["voltage"], 6.175)


def test_kinematic_duties_beyond_the_limit_are_refused(tmp_path, robot):
    text = """procedure = "energy_trajectories"
[[trajectories]]
name = "dash"
kind = "square"
side = "1 m"
speed = "2.5 m/s"
"""
    # 2.5 m/s forward needs k_e * 2.5 / r / V_batt = 2.4 > max_duty 1
    with pytest.raises(UserError, match=r"step 0 \(dash .*needs duty 2\.4"):
        load_plan(_write(tmp_path, text), robot)


def test_lateral_and_energy_validation_messages(tmp_path, robot):
    lat = 'procedure = "lateral_runs"\n[runs]\nduration = "1 s"\n[[directions]]\nheading = "30 deg"\nspeed = "-1 m/s"\n'
    with pytest.raises(UserError, match=r"p.toml:6: \[directions\] speed: must be > 0"):
        load_plan(_write(tmp_path, lat), robot)
    en = 'procedure = "energy_trajectories"\n[[trajectories]]\nname = "x"\nkind = "zigzag"\n'
    with pytest.raises(UserError, match=r"p.toml:4: \[trajectories\] kind: expected one of square"):
        load_plan(_write(tmp_path, en), robot)
