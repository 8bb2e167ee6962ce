"""The runner on an in-process board: steady-state test, closed-form speeds, no-slip check,
Ctrl-C at any sample leaves the motors stopped and a resumable run."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from fakeboard import FakeBoard

from omnibench.bench.runner import steady_state
from omnibench.bench.session import _run_on_board, load_robot_file
from omnibench.model import default_robot
from omnibench.procedures import load_plan
from omnibench.runs import read_run

CPR = 980


def _quantised(t, w, rng):
    phi = np.outer(t, w) + rng.uniform(0, 2 * np.pi / CPR, size=4)
    return np.floor(phi / (2 * np.pi / CPR)) * (2 * np.pi / CPR)


def test_steady_state_accepts_constant_speed_and_rejects_a_ramp():
    rng = np.random.default_rng(0)
    t = np.arange(0, 0.5, 0.01)
    w = np.array([3.0, -5.0, 8.0, 0.5])
    kw = dict(window=0.3, confidence=0.95, noise_factor=2.0, relative_tolerance=0.01, counts_per_rev=CPR)
    assert steady_state(t, _quantised(t, w, rng), **kw).steady
    # still accelerating: speed rises 10 rad/s per second
    phi = _quantised(t, w, rng) + 0.5 * 10.0 * t[:, None] ** 2
    v = steady_state(t, phi, **kw)
    assert not v.steady and v.t_stat.max() > 5
    # an exponential approach that has not settled yet (time constant 0.3 s)
    phi = np.outer(t - 0.3 * (1 - np.exp(-t / 0.3)), w)
    assert not steady_state(t, phi, **kw).steady


def closed_form(robot, u, wheel_mass):
    """Upside-down steady speed (rad/s), docs/robot-file.md, the model with F_N = wheel weight:
    eta k_t (u V - k_e w)/R_a = (1 + c m g)(a w + b wheel_sign(w)), the model's regularised sign
    wheel_sign(w) = tanh(w / eps) (eps = sign_width_phi)."""
    from scipy.optimize import brentq

    k = robot.eta * robot.k_t / robot.R_a
    load = 1 + robot.c * wheel_mass * 9.80665
    eps = robot.sign_width_phi

    def f(w):
        return k * (abs(u) * robot.V_batt - robot.k_e * w) - load * (robot.a * w + robot.b * math.tanh(w / eps))

    return math.copysign(brentq(f, 0.0, abs(u) * robot.V_batt / robot.k_e), u)


SMALL = {"upside_down_sweep": "small_sweep.toml", "forward_runs": "small_forward.toml",
         "lateral_runs": "small_lateral.toml", "energy_trajectories": "small_energy.toml"}
HERE = Path(__file__).parent


def _run(procedure, board, tmp_path, resume=None):
    robot, text, name = load_robot_file(None)
    if resume:
        plan = load_plan(Path(resume) / "procedure.toml", robot)
    else:
        plan = load_plan(HERE / "procedures" / SMALL[procedure], robot)
    return _run_on_board(procedure, plan, robot, text, name, board, port="fake://", out=tmp_path,
                         resume=resume, answer_op=None, echo=lambda line: None, progress=False,
                         measurement_noise=None)


def test_sweep_speeds_match_closed_form(tmp_path):
    res = _run("upside_down_sweep", FakeBoard(), tmp_path)
    run = read_run(res["run"])
    robot = default_robot()
    assert run.status == "complete" and res["steady_steps"] == len(run.steps) == 12
    for _, s in run.steps.iterrows():
        expect = closed_form(robot, s["duty"], s["wheel_mass1"])
        # encoder quantisation over the 0.3 s averaging window: a few 0.01 rad/s
        for j in range(1, 5):
            assert s[f"w{j}"] == pytest.approx(expect, abs=0.03), (s["label"], j)


def test_forward_passes_and_lateral_reports_slip(tmp_path):
    fwd = _run("forward_runs", FakeBoard(), tmp_path)
    assert fwd["no_slip_passed"] == fwd["steps"] == 4
    lat = _run("lateral_runs", FakeBoard(), tmp_path)
    run = read_run(lat["run"])
    assert lat["no_slip_failed"] == list(range(8))
    # the displacement the encoders imply through pinv(R) still matches the tape
    assert run.steps["kin_residual"].max() < 0.02
    # pure lateral runs (heading 90 deg): the wheels' rolling distance is ~0, the tape says ~0.3 m
    side = run.steps[np.isclose(np.abs(run.steps["heading"]) % np.pi, np.pi / 2)]
    assert (side["encoder_distance"].abs() < 0.01).all() and (side["slip"] > 0.2).all()


def test_energy_trajectories_log_battery_energy(tmp_path):
    res = _run("energy_trajectories", FakeBoard(), tmp_path)
    run = read_run(res["run"])
    assert list(run.steps["trajectory"]) == ["square", "spin"]
    assert (run.steps["energy"] > 0).all() and run.steps["has_current"].all()
    # the energy is the integral of V*I over the step's samples
    s = run.step_samples(0)
    e = np.trapezoid(s["V_batt"] * s["I_batt"], s["t"])
    assert e == pytest.approx(run.steps["energy"].iloc[0], rel=1e-9)


@pytest.mark.parametrize("interrupt_after", [1, 37, 333, 777])
def test_ctrl_c_stops_motors_and_resume_completes_without_duplicates(tmp_path, interrupt_after):
    board = FakeBoard(interrupt_after=interrupt_after)
    with pytest.raises(KeyboardInterrupt):
        _run("upside_down_sweep", board, tmp_path)
    assert board.stops >= 1 and not board.duties.any()
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    run = read_run(run_dir)
    assert run.status == "aborted" and "Ctrl-C" in run.metadata["reason"]
    n_before = len(run.samples)
    assert n_before == interrupt_after - 1  # every sample read before the interrupt is kept
    done_before = list(run.steps["step"]) if len(run.steps) else []
    res = _run("upside_down_sweep", FakeBoard(), tmp_path, resume=run_dir)
    run = read_run(run_dir)
    assert res["status"] == run.status == "complete"
    assert list(run.steps["step"]) == list(range(12))
    assert list(run.steps["step"][: len(done_before)]) == done_before
    assert len(run.samples) > n_before
    assert [s["status"] for s in run.metadata["segments"]] == ["aborted", "complete"]


def test_operator_declining_an_action_aborts_the_run_with_motors_stopped(tmp_path, monkeypatch):
    import click

    from omnibench.bench.session import _run_on_board as run_on_board

    class Declines:
        source = "console"

        def perform(self, action, step):
            raise click.exceptions.Abort()

    robot, text, name = load_robot_file(None)
    plan = load_plan(HERE / "procedures" / SMALL["upside_down_sweep"], robot)
    board = FakeBoard()
    import omnibench.bench.session as session

    monkeypatch.setattr(session, "_choose_operator", lambda *a, **k: Declines())
    with pytest.raises(click.exceptions.Abort):
        run_on_board("upside_down_sweep", plan, robot, text, name, board, port="fake://", out=tmp_path,
                     resume=None, answer_op=None, echo=lambda line: None, progress=False,
                     measurement_noise=None)
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    run = read_run(run_dir)
    assert run.status == "aborted" and "declined" in run.metadata["reason"]
    assert board.stops >= 1 and not board.duties.any()
