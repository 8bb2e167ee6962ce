"""Provenance: runs record what produced them, and analyses refuse runs of different robots,
boards or worlds (simulated vs real, two simulated worlds) unless --allow-mixed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from omnibench.cli import main
from omnibench.runs import run_dirs
from omnibench.runs.provenance import mixed_runs

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "omnibot-tfm"


def _omnibench(*args: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    with pytest.raises(SystemExit) as exc:
        main(list(args))
        raise SystemExit(0)
    got = capsys.readouterr()
    return int(exc.value.code or 0), got.out + got.err


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim")
    with pytest.raises(SystemExit) as exc:
        main(["forward", "--port", "sim://", "--out", str(out), "--json"])
        raise SystemExit(0)
    assert exc.value.code == 0
    return out


def test_a_run_on_the_simulator_records_its_provenance(sim_run):
    prov = json.loads((run_dirs(sim_run)[0] / "run.json").read_text())["provenance"]
    assert prov["simulated"] is True and prov["world"] == ""
    assert prov["board_id"] and prov["boot_id"] and prov["firmware_version"]
    assert len(prov["robot_file_sha256"]) == 64 and prov["wiring_file"] is None


def test_fit_refuses_the_2019_logs_with_a_simulated_run(sim_run, tmp_path, capsys):
    if not (DATA / "results_ground_x.mat").exists():
        pytest.skip("shared/data/omnibot-tfm is not available")
    code, text = _omnibench("import", "tfm", str(DATA / "results_ground_x.mat"), "--out", str(tmp_path / "tfm"), capsys=capsys)
    assert code == 0, text
    prov = json.loads((run_dirs(tmp_path / "tfm")[0] / "run.json").read_text())["provenance"]
    assert prov["simulated"] is False and len(prov["source_sha256"]) == 64
    code, text = _omnibench("fit", str(tmp_path / "tfm"), str(sim_run), "--out", str(tmp_path / "m.toml"), capsys=capsys)
    assert code == 2, text
    line = text.strip().splitlines()[-1]
    assert "simulated vs real" in line and "results_ground_x" in line and "forward_runs" in line
    assert "--allow-mixed" in line and "Traceback" not in text
    assert not (tmp_path / "m.toml").exists()


def test_two_simulated_worlds_are_a_mix_but_one_world_is_not():
    sim = {"port": "sim://", "counts_per_rev": 980, "provenance": {"simulated": True, "world": ""}}
    other = {"port": "sim://?plant=independent", "counts_per_rev": 980,
             "provenance": {"simulated": True, "world": "plant=independent"}}
    found = mixed_runs([("a", sim), ("b", other)])
    assert found is not None and found[0] == "world" and "plant=independent" in found[3]
    assert mixed_runs([("a", sim), ("b", dict(sim))]) is None
    old = {"port": None, "counts_per_rev": None}  # an old run folder: unknown agrees with anything
    assert mixed_runs([("a", sim), ("b", old)]) is None
    tfm = {"imported": True, "counts_per_rev": 980}
    assert mixed_runs([("a", tfm), ("b", {"imported": True, "counts_per_rev": 980, "source": "other"})]) is None
    assert mixed_runs([("a", tfm), ("b", {"imported": True, "counts_per_rev": 2048})])[0] == "counts_per_rev"


def test_runs_of_another_geometry_are_a_mix():
    """The run.json `robot` table keeps the geometry in its own section: a wheel radius that
    differs is another robot."""
    def run(r: float) -> dict:
        return {"port": "sim://", "counts_per_rev": 980, "provenance": {"simulated": True, "world": ""},
                "robot": {"geometry": {"L": 0.2096, "l": 0.2096, "r": r, "alpha": [0.785, -0.785, -0.785, 0.785]}}}

    assert mixed_runs([("a", run(0.0667)), ("b", run(0.0667))]) is None
    found = mixed_runs([("a", run(0.0667)), ("b", run(0.05))])
    assert found is not None and found[0] == "geometry" and "r=0.05" in found[3]


@pytest.mark.parametrize("command", ["predict", "validate-energy", "diagnose"])
def test_a_model_of_another_robot_is_refused(sim_run, tmp_path, capsys, command):
    """A model with 2048 counts per revolution against runs recorded at 980: one line, exit 2,
    naming the model and the run; the robot's own file is accepted."""
    shipped = Path(__file__).resolve().parents[2] / "omnibench" / "model" / "omnibot.toml"
    other = tmp_path / "other.toml"
    other.write_text(shipped.read_text().replace("counts_per_rev = 980", "counts_per_rev = 2048"))
    code, text = _omnibench(command, "--model", str(other), str(sim_run), capsys=capsys)
    assert code == 2, text
    line = text.strip().splitlines()[-1]
    assert "the model" in line and "other.toml" in line and "forward_runs" in line, line
    assert "980" in line and "2048" in line and "Traceback" not in text
    if command == "predict":
        code, text = _omnibench(command, "--model", str(shipped), str(sim_run), capsys=capsys)
        assert code == 0, text


def test_every_simulator_setting_is_either_physics_or_conduct():
    """A setting the simulator learns must be classed: physics makes another world, conduct (seed,
    clock, link faults, sensor noise, board id) does not."""
    from dataclasses import fields

    from omnibench.runs.provenance import CONDUCT_SETTINGS, PHYSICS_SETTINGS
    from omnibench.sim.world import World

    url_names = {"robot" if f.name == "robot_file" else f.name for f in fields(World)} | {"world"}
    url_names.discard("effects")  # written effects.NAME.PARAM: physics by prefix
    assert url_names <= PHYSICS_SETTINGS | CONDUCT_SETTINGS
    assert not PHYSICS_SETTINGS & CONDUCT_SETTINGS


def test_one_world_whatever_its_seed_faults_or_order_of_settings():
    from omnibench.runs.provenance import world_of

    assert world_of("sim://?seed=8") == world_of("sim://?seed=9&drop=0.01&clock=realtime&name=x") == ""
    assert world_of("sim://?payload=2&seed=1") == world_of("sim://?seed=2&payload=2.0") == "payload=2"
    assert world_of("sim://?effects.stribeck_friction.v_s=0.1&payload=1") == \
        world_of("sim://?payload=1&effects.stribeck_friction.v_s=0.1")
    assert world_of("sim://?payload=1") != world_of("sim://?payload=2")
    assert world_of("/dev/ttyACM0") is None


def test_a_setting_at_its_default_names_the_default_world():
    """`sim://?actuation=firmware` is the board `sim://` is; `actuation=ideal` another world, and
    the defaults written here are the simulator's own."""
    from omnibench.runs.provenance import PHYSICS_DEFAULTS, world_of
    from omnibench.sim.world import World

    assert world_of("sim://?actuation=firmware&seed=3") == world_of("sim://") == ""
    assert world_of("sim://?actuation=ideal") == "actuation=ideal"
    for name, value in PHYSICS_DEFAULTS.items():
        assert str(getattr(World(), name)) == value, name
