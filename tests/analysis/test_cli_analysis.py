"""omnibench fit / validate-energy / predict: JSON keys, files written, one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from omnibench.cli import main

from .test_observations_and_model import _write_energy_run


def _run(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
        raise SystemExit(0)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_fit_json_on_the_real_sweep_writes_model_and_plots(real_runs, tmp_path, capsys):
    model = tmp_path / "m.toml"
    code, out, err = _run(["fit", str(real_runs["results_jacked"]), "--out", str(model), "--plots",
                           str(tmp_path / "fig"), "--json"], capsys)
    assert code == 0, err
    data = json.loads(out)
    p = data["parameters"]
    assert set(p) == {"a", "b", "c"}
    for name in ("a", "b"):
        assert p[name]["se"] > 0 and p[name]["ci95"][0] < p[name]["value"] < p[name]["ci95"][1]
        assert p[name]["identifiable"] is True
    assert p["c"]["identifiable"] is False and p["c"]["se"] is None
    assert set(data["per_wheel"]) == {"1", "2", "3", "4"}
    assert data["per_wheel"]["1"]["b"]["se"] > 0
    assert model.exists() and all((tmp_path / "fig" / f).exists() for f in ("sweep_fit.png", "residuals.png"))
    # the model file feeds predict
    code, out, err = _run(["predict", "--model", str(model), str(real_runs["square_fast"]), "--json"], capsys)
    assert code == 0, err
    data = json.loads(out)
    assert 0 < data["nrmse"]["wheel_speed"] < 1 and "position" in data["nrmse"]


def test_validate_energy_json(tmp_path, truth, capsys):
    import tomli_w

    from omnibench.analysis.model_file import write_model  # noqa: F401 (model = a plain robot file here)

    _write_energy_run(tmp_path / "runs", truth)
    model = tmp_path / "truth.toml"
    model.write_text(tomli_w.dumps(truth.to_toml_dict()))
    code, out, err = _run(["validate-energy", "--model", str(model), str(tmp_path / "runs"), "--json",
                           "--plots", str(tmp_path / "fig")], capsys)
    assert code == 0, err
    data = json.loads(out)
    assert len(data["runs"]) == 1
    r = data["runs"][0]
    assert {"run", "measured_J", "predicted_J", "error_pct"} <= set(r)
    assert abs(r["error_pct"]) < 1 and data["mean_abs_error_pct"] == pytest.approx(abs(r["error_pct"]))
    assert (tmp_path / "fig" / "energy_current.png").exists()


def test_bad_input_is_one_line_and_nonzero(tmp_path, real_runs, capsys):
    cases = [
        (["fit", str(tmp_path / "missing")], "no such run directory"),
        (["validate-energy", "--model", str(tmp_path / "none.toml"), str(real_runs["results_jacked"])],
         "model file not found"),
        (["fit", str(real_runs["square_fast"]), "--out", str(tmp_path / "m.toml")], "nothing to fit"),
        (["fit", str(real_runs["results_jacked"]), "--free", "a,zeta", "--out", str(tmp_path / "m.toml")],
         "cannot fit 'zeta'"),
        (["validate-energy", "--model", str(real_runs["results_jacked"] / "run.json"), str(real_runs["results_jacked"])],
         "not valid TOML"),
    ]
    for args, message in cases:
        code, out, err = _run(args, capsys)
        assert code != 0, args
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("omnibench: error:") and message in lines[0], err
    # and end to end in a fresh process: no traceback
    p = subprocess.run([sys.executable, "-m", "omnibench", *cases[0][0]], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "Traceback" not in p.stderr


def test_energy_runs_of_the_simulated_board_match_the_model(tmp_path, robot, capsys):
    """End to end: omnibench energy on sim:// (the board's timing, sensors and protocol), then
    validate-energy with the robot the simulated board carries."""
    code, out, err = _run(["energy", "--port", "sim://", "--out", str(tmp_path / "runs"), "--json"], capsys)
    assert code == 0, err
    model = tmp_path / "omnibot.toml"
    from omnibench.model.robot import DEFAULT_ROBOT_FILE

    model.write_text(DEFAULT_ROBOT_FILE.read_text())
    code, out, err = _run(["validate-energy", "--model", str(model), str(tmp_path / "runs"), "--json"], capsys)
    assert code == 0, err
    data = json.loads(out)
    assert len(data["runs"]) == 4
    assert data["max_abs_error_pct"] < 0.5, data
    # a wrong model is caught
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(DEFAULT_ROBOT_FILE.read_text().replace("b = 0.5 ", "b = 0.8 "))
    code, out, err = _run(["validate-energy", "--model", str(wrong), str(tmp_path / "runs"), "--json"], capsys)
    assert json.loads(out)["mean_abs_error_pct"] > 3
