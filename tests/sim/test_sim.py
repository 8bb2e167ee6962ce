"""The simulated board: world file and URL, sensor models, seeding, clocks, ammeter, CLI."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from omnibench.errors import BoardError, UserError
from omnibench.link.ammeter import open_ammeter
from omnibench.link.board import Board
from omnibench.sim import registry
from omnibench.sim.sensors import Sensors
from omnibench.sim.world import SensorConfig, load_world, world_from_url

WORLD = """
mode = "upside_down"
payload = 0.0
wheel_mass = [0.8, 0.8, 1.2, 1.2]
seed = 3
[sensors]
current_noise = 0.0
battery_current_noise = 0.0
[effects.quiescent_current]
I_q = 0.5
[faults]
drop = 0.0
"""


def test_world_file_reaches_the_model(tmp_path: Path) -> None:
    f = tmp_path / "w.toml"
    f.write_text(WORLD)
    w = load_world(f)
    sc = w.scenario()
    assert sc.mode == "upside_down" and sc.wheel_mass == (0.8, 0.8, 1.2, 1.2)
    assert dict(sc.effects) == {"quiescent_current": {"I_q": 0.5}}
    name = f"w-{uuid.uuid4().hex[:6]}"
    with Board.open(f"sim://omnibot?world={f}&name={name}") as b:
        b.configure(telemetry_hz=50)
        s = b.wait(0.2)[-1]
        # the hidden quiescent current shows in the battery current at rest
        assert s.battery_current == pytest.approx(0.5, abs=0.01)
        assert b.sim_truth().mode == "upside_down"
    assert registry.get(name).plant.scenario.mode == "upside_down"


def test_url_overrides_world_and_parses_effects() -> None:
    dev, w, extra = world_from_url("sim://?seed=9&mode=ground&effects.stribeck_friction.b_s=0.2&drop=0.01"
                                   "&sensors.current_noise=0.05&clock=realtime")
    assert dev == "omnibot" and w.seed == 9 and w.clock == "realtime"
    assert w.effects == {"stribeck_friction": {"b_s": 0.2}}
    assert w.faults.drop == 0.01 and w.sensors.current_noise == 0.05
    dev, w, extra = world_from_url("sim://ammeter?board=rig&noise=0.01")
    assert dev == "ammeter" and extra == {"board": "rig", "noise": "0.01"}


@pytest.mark.parametrize("url, match", [
    ("sim://?mode=sideways", "mode must be ground or upside_down"),
    ("sim://?drop=1.5", "probability"),
    ("sim://?colour=red", "unknown setting 'colour'"),
    ("sim://toaster", "unknown simulated device"),
    ("sim://?sensors.bogus=1", "unknown sensor setting"),
])
def test_bad_sim_url_gives_one_line_error(url: str, match: str) -> None:
    with pytest.raises(UserError, match=match) as exc:
        world_from_url(url)
    assert "\n" not in str(exc.value)
    with pytest.raises(UserError, match=match):  # a wrong URL is bad input, not a board fault
        Board.open(url)


@pytest.mark.parametrize("url, hint", [("sim://?foo=1", "known: "), ("sim://?sed=1", "did you mean 'seed'?")])
def test_a_wrong_sim_setting_is_bad_input_through_the_cli(url: str, hint: str, capsys) -> None:
    from omnibench.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["sweep", "--port", url])
    err = capsys.readouterr().err
    assert exc.value.code == 2, err
    assert repr(url.split("?")[1].split("=")[0]) in err and hint in err
    assert "omnibench ports" not in err and len(err.strip().splitlines()) == 1


def test_bad_world_file(tmp_path: Path) -> None:
    f = tmp_path / "bad.toml"
    f.write_text("payload = -1\n")
    with pytest.raises(UserError, match="payload"):
        load_world(f)
    with pytest.raises(UserError, match="not found"):
        load_world(tmp_path / "missing.toml")


def test_encoder_quantisation_and_sensor_resolution() -> None:
    s = Sensors(SensorConfig(current_noise=0.0, current_lsb=0.01), 980, np.random.default_rng(0))
    one_count = 2 * math.pi / 980
    # each code wheel has its own random phase, less than one count
    assert np.all((s.encoder_phase >= 0) & (s.encoder_phase < one_count))
    assert len(set(s.encoder_phase)) == 4
    other = Sensors(SensorConfig(), 980, np.random.default_rng(1))
    assert not np.allclose(other.encoder_phase, s.encoder_phase)
    s.encoder_phase = np.zeros(4)
    assert list(s.encoder_counts(np.array([0.0, 0.999 * one_count, one_count * 1.001, -0.5 * one_count]))) == [0, 0, 1, -1]
    assert list(s.motor_current(np.array([1.234, -0.006, 0.004, 2.0]))) == pytest.approx([1.23, -0.01, 0.0, 2.0])


def test_same_seed_same_samples() -> None:
    def run() -> list:
        with Board.open("sim://?seed=21&current_noise=0.05") as b:
            b.configure(telemetry_hz=100)
            b.set_duties([0.3, 0.2, -0.1, 0.0])
            return [(s.t, s.encoder, s.motor_current, s.battery_voltage) for s in b.wait(0.5)]

    a, c = run(), run()
    assert a == c
    assert len({x[2] for x in a}) > 10  # noise is there


def test_encoders_track_true_wheel_angle() -> None:
    name = f"e-{uuid.uuid4().hex[:6]}"
    with Board.open(f"sim://?name={name}&mode=upside_down") as b:
        b.configure(telemetry_hz=100)
        b.reset_encoders()
        sim = registry.get(name)
        phi0 = sim.plant.state.phi.copy()
        b.set_duties([0.5, 0.5, -0.5, 0.2])
        s = b.wait(0.5)[-1]
        phi = sim.plant.state.phi - phi0
        assert np.all(np.abs(np.array(s.wheel_angles(980)) - phi) <= 2 * 2 * math.pi / 980)


def test_realtime_clock_follows_wall_clock_roughly() -> None:
    """Board time advances with the wall clock (the bound is loose: no speed assertion)."""
    with Board.open("sim://?clock=realtime") as b:
        b.configure(telemetry_hz=100)
        t0, w0 = b.board_time, time.monotonic()
        b.wait(0.3)
        assert b.board_time - t0 <= (time.monotonic() - w0) + 0.05


def test_ammeter_on_its_own_port_aligned_to_board_time() -> None:
    name = f"a-{uuid.uuid4().hex[:6]}"
    with Board.open(f"sim://?name={name}&battery_current_noise=0.0") as b:
        with open_ammeter(f"sim://ammeter?board={name}&noise=0.0") as meter:
            assert meter.idn.startswith("OMNIBENCH,SIM-AMMETER")
            assert meter.query("SYST:ERR?").startswith("0,")
            b.configure(telemetry_hz=200)
            b.attach_ammeter(meter, period_s=0.05)
            b.set_duties([0.6] * 4)
            s = b.wait(1.0)
        read = [x for x in s if not math.isnan(x.ammeter_current)]
        assert 15 <= len(read) <= 25
        # aligned: the meter's reading equals the board's own (noise-free) sensor at that sample
        assert all(abs(x.ammeter_current - x.battery_current) < 2e-3 for x in read)
        assert max(x.ammeter_current for x in read) > 1.0


def test_ammeter_errors_are_one_line() -> None:
    with pytest.raises(BoardError, match="no simulated board named"):
        open_ammeter("sim://ammeter?board=nobody-here")


def _cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """Run the CLI in a subprocess (the timeout guards against a hang; a cold numba compile is slow)."""
    return subprocess.run([sys.executable, "-m", "omnibench", *args], capture_output=True, text=True, timeout=timeout)


def test_cli_board_info_json_and_bad_port() -> None:
    r = _cli("board", "info", "--port", "sim://?seed=2", "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["protocol_version"] == 2 and info["compatible"] and info["counts_per_rev"] == 980
    r = _cli("board", "info", "--port", "sim://?protocol_version=3", "--json")
    assert r.returncode == 3 and json.loads(r.stdout)["compatible"] is False and "v3" in r.stderr
    r = _cli("board", "info", "--port", "/dev/does-not-exist")
    assert r.returncode == 3 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert "omnibench ports" in r.stderr


def test_cli_board_monitor_and_ports() -> None:
    r = _cli("board", "monitor", "--port", "sim://", "--duration", "0.5", "--every", "0.1", "--json")
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert len(lines) >= 4 and all(x["faults"] == [] for x in lines)
    r = _cli("ports", "--json")
    assert r.returncode == 0 and isinstance(json.loads(r.stdout), list)


def test_cli_sim_serve_bad_input_is_one_line() -> None:
    r = _cli("sim", "serve", "--set", "mode=sideways")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "mode" in r.stderr
    r = _cli("sim", "serve", "--set", "novalue")
    assert r.returncode == 2 and "KEY=VALUE" in r.stderr


def test_driving_the_simulated_robot_leaves_the_hosts_threads_for_the_analysis() -> None:
    """The simulated plant integrates one trajectory on one thread, and sets numba's (thread-local)
    thread count for it; the thread that drove `sim://` then fits the runs. It must get every
    core back: a campaign's fit and diagnose ran on one after its procedures."""
    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba has one thread on this machine: nothing to give back")
    numba.set_num_threads(2)
    name = f"t-{uuid.uuid4().hex[:6]}"
    with Board.open(f"sim://?name={name}") as b:
        sim = registry.get(name)
        inside: list[int] = []
        advance = sim.plant.sim.advance

        def counted(*a, **k):
            inside.append(numba.get_num_threads())
            return advance(*a, **k)

        sim.plant.sim.advance = counted
        b.configure(telemetry_hz=100)
        b.set_duties([0.4, 0.4, 0.4, 0.4])
        assert b.wait(0.3)
        b.stop()
    assert inside and set(inside) == {1}  # one trajectory: no thread pool woken per telemetry period
    assert numba.get_num_threads() == 2
