"""The whole chain: a campaign through the project's firmware in simavr, then fit, validate-energy
and diagnose, asserted on the answer; and the same campaign on `sim://` agrees with it.

The rig's plant is the model's own physics (the robot file's coefficients), so every fitted
coefficient, the motor's k_e and R_a as well as the friction, must come out within 3 SE of the
robot file's value and of the same campaign's on `sim://`, every measurement group must fit to its
noise, the energy must be predicted, and diagnosis must add nothing. The motor side needs the
firmware's analog readings unbiased to well below a code (each code reported at its centre with a
single rounding; a run's supply the mean, not the median, of its readings at rest): an error of a
few mA that depends on the code puts R_a and a 3-7 SE off and makes diagnosis pick a low-speed
term. Without the firmware's actuation replayed (duties rounded to the drivers' 127 steps, one
4.17 ms packet per wheel), this campaign fits C_r = 0 and a_r twice its value with chi2/dof in the
hundreds.
"""

from __future__ import annotations

import json
import math

import pytest

from omnibench.cli import main
from omnibench.model import default_robot
from omnibench.runs import read_run
from tests.bench.test_campaign import HERE as BENCH
from tests.simserver import spawn_server

PROCEDURES = BENCH / "procedures" / "campaign"
#: a measurement group fits to its noise (the issue's bar; the fit flags above 2 as misfit)
GROUP_CHI2_MAX = 4.0


def _campaign(capsys, port: str, out, analysis: str) -> dict:
    try:
        main(["campaign", "--port", port, "--out", str(out), "--procedures", str(PROCEDURES),
              "--analysis", analysis, "--candidates", "driver_deadband,stribeck_friction,actuator_lag", "--json"])
    except SystemExit as exc:  # pragma: no cover - only on failure
        raise AssertionError(capsys.readouterr().err[-3000:]) from exc
    return json.loads(capsys.readouterr().out)


@pytest.fixture(scope="module")
def fil_port(fil_elf, tmp_path_factory):
    srv = spawn_server(tmp_path_factory.mktemp("fil-campaign"), "--clock", "fast", "--seed", "5",
                       "--firmware", str(fil_elf), "--robot", "omnibot-2019-hall")
    yield srv
    srv.stop()


@pytest.mark.slow
def test_a_campaign_through_the_firmware_fits_the_plant_and_agrees_with_sim(capsys, tmp_path, fil_port):
    res = _campaign(capsys, fil_port.path, tmp_path / "fw", "fit,validate-energy,diagnose")
    assert fil_port.status()["motors_stopped"]
    # every run says how its duties reached the motors
    for proc, r in res["procedures"].items():
        ft = read_run(r["run"]).info.firmware_timing
        assert ft is not None and ft["driver"]["steps"] == 127, proc
        assert ft["wheel_delays_s"] == pytest.approx([4 * 10 / 9600 * k for k in (1, 2, 3, 4)])
    sweep = res["procedures"]["upside_down_sweep"]
    assert [0.3, pytest.approx(38 / 127, abs=1e-6)] in sweep["applied_duties"]["changed"]

    fit = res["analysis"]["fit"]["result"]
    robot = default_robot()
    for name, p in fit["parameters"].items():
        truth = float(getattr(robot, name))
        assert p["verdict"] == "identified", (name, p)
        assert abs(p["value"] - truth) < 3 * p["se"], (name, p["value"], p["se"], truth)
    for group, s2 in fit["group_s2"].items():
        assert s2 < GROUP_CHI2_MAX, (group, s2)
    energy = res["analysis"]["validate-energy"]["result"]
    assert energy["mean_abs_error_pct"] < 2.0, energy  # through the firmware about 0.2 %; without its actuation replayed, 8-10 %
    assert res["analysis"]["diagnose"]["result"]["selected"] == []

    # the same campaign on the simulated board (which rounds and delays as the firmware does)
    sim = _campaign(capsys, "sim://?seed=5&actuation=firmware", tmp_path / "sim", "fit")["analysis"]["fit"]["result"]["parameters"]
    for name, p in fit["parameters"].items():
        q = sim[name]
        assert abs(p["value"] - q["value"]) < 3 * math.hypot(p["se"], q["se"]), (name, p, q)
