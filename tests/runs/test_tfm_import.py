"""Importing the real 2019 logs: the runs reproduce the files' own numbers."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from omnibench.runs import read_run
from omnibench.runs.tfm import import_tfm

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "omnibot-tfm"
if not DATA.is_dir():
    DATA = Path("/work/shared/data/omnibot-tfm")
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason="2019 TFM data not available")


def _mat(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return scipy.io.loadmat(str(DATA / name))


def test_jacked_sweep_steady_speeds_equal_ws(tmp_path):
    run = read_run(import_tfm(DATA / "results_jacked.mat", tmp_path))
    ws = _mat("results_jacked.mat")["ws"]
    cols = np.where(~np.isnan(ws[0]))[0]
    assert run.procedure == "upside_down_sweep" and run.status == "complete"
    assert len(run.steps) == 27 == len(cols)
    np.testing.assert_array_equal(run.steps["command"].to_numpy(), cols + 1)
    for j in range(4):
        np.testing.assert_array_equal(run.steps[f"w{j + 1}"].to_numpy(), ws[j, cols])
    # the raw samples of the last step (amplitude 112) give the same steady speed
    last = run.step_samples(int(run.steps["step"].iloc[-1]))
    assert len(last) == 132
    np.testing.assert_allclose(last["u1"], 112 / 127)
    tail = last.iloc[-40:]
    for j in range(4):
        speed = np.polyfit(tail["t"], tail[f"phi{j + 1}"], 1)[0]
        assert speed == pytest.approx(ws[j, 111], rel=0.01)


@pytest.mark.parametrize("name", ["square_fast.mat", "square_small.mat"])
def test_square_wave_speeds_match_direct_computation(tmp_path, name):
    run = read_run(import_tfm(DATA / name, tmp_path))
    d = _mat(name)["data"].astype(float)
    assert run.procedure == "step_response"
    assert run.metadata["sign_map"] == [1, -1, 1, -1]
    s = run.samples
    assert len(s) == d.shape[1]
    np.testing.assert_allclose(s["t"], d[1] / 1000.0)
    np.testing.assert_allclose(s["u3"], d[0] / 127.0)
    signs = [1, -1, 1, -1]
    for j in range(4):
        direct = signs[j] * np.diff(d[3 + j]) * 2 * math.pi / 980 / (np.diff(d[1]) / 1000.0)
        from_run = np.diff(s[f"phi{j + 1}"]) / np.diff(s["t"])
        np.testing.assert_allclose(from_run, direct, rtol=1e-9, atol=1e-9)
    # with the sign map every wheel turns the way its duty says (summed over the steps)
    for j in range(4):
        agree = 0.0
        for k in run.steps["step"]:
            st = run.step_samples(int(k))
            agree += np.sign(st["u1"].iloc[0]) * (st[f"phi{j + 1}"].iloc[-1] - st[f"phi{j + 1}"].iloc[0])
        assert agree > 0
    # steps are the constant-command segments, and they tile the samples
    assert run.steps["n_samples"].sum() == d.shape[1]
    assert set(np.sign(run.steps["command"])) == {-1, 1}


def test_cli_import_with_sign_option_and_bad_input(tmp_path):
    exe = [sys.executable, "-m", "omnibench"]
    out = subprocess.run(exe + ["import", "tfm", str(DATA / "square_fast.mat"), "--signs", "+1,+1,+1,+1",
                                "--out", str(tmp_path), "--json"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    run = read_run(res[0]["run"])
    assert run.metadata["sign_map"] == [1, 1, 1, 1]
    d = _mat("square_fast.mat")["data"]
    np.testing.assert_array_equal(run.samples["enc2"], d[4])
    bad = subprocess.run(exe + ["import", "tfm", str(DATA / "square_fast.mat"), "--signs", "1,2",
                                "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and "--signs" in bad.stderr
    junk = tmp_path / "junk.mat"
    junk.write_text("not a mat file")
    bad = subprocess.run(exe + ["import", "tfm", str(junk), "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1


def _agree(run, j):
    """Sum over steps of duty sign x wheel j's angle change: > 0 when the wheel follows its duty."""
    out = 0.0
    for k in run.steps["step"]:
        st = run.step_samples(int(k))
        out += np.sign(st["u1"].iloc[0]) * (st[f"phi{j + 1}"].iloc[-1] - st[f"phi{j + 1}"].iloc[0])
    return out


def test_the_real_floor_run_reads_where_unknown_with_the_wheel_profiled(tmp_path):
    """results_ground_x.mat with no --where: against the file's own wheel it reads as the floor
    (ratio above 2), but a heavier in-air wheel with an actuator lag replays it about as well:
    with the wheel profiled neither mode wins by the margin, so where stays unknown."""
    from omnibench.model import default_robot
    from omnibench.runs.tfm import WHERE_MARGIN

    run = read_run(import_tfm(DATA / "results_ground_x.mat", tmp_path))
    w = run.metadata["conditions"]["where"]
    st = w["statistic"]
    assert w["value"] == "unknown" and run.metadata["mode"] is None
    assert max(st["nrmse_air"], st["nrmse_floor"]) < WHERE_MARGIN * min(st["nrmse_air"], st["nrmse_floor"])
    assert st["nrmse_air_file"] >= WHERE_MARGIN * st["nrmse_floor_file"]
    # the in-air wheel that comes close is heavier than the file's, as the real one is
    assert st["best_air"]["I_w"] > default_robot().I_w


def test_floor_runs_import_as_ground_step_responses_with_their_fitted_gains(tmp_path):
    run = read_run(import_tfm(DATA / "results_ground_x.mat", tmp_path, where="floor"))
    g = _mat("results_ground_x.mat")
    assert run.procedure == "step_response" and run.metadata["mode"] == "ground"
    assert run.metadata["conditions"]["where"]["decided"] == "stated by the user"
    assert len(run.samples) == g["t"].size == 143
    np.testing.assert_allclose(run.samples["t"], g["t"].ravel())
    np.testing.assert_allclose(run.samples["u2"], np.round(g["x"].ravel() * 127) / 127)
    np.testing.assert_allclose(run.samples["phi3"], np.round(g["m"][2] * 980) * 2 * math.pi / 980)
    assert all(_agree(run, j) > 0 for j in range(4))
    ks = np.asarray(run.metadata["fitted_gains"]["Ks"], dtype=float)
    np.testing.assert_array_equal(ks, g["Ks"])
    ft = run.metadata["firmware_timing"]
    assert ft["command_order"] == [1, 2, 3, 4] and ft["command_offset_s"] == 0.0
    assert ft["packet_s"] == pytest.approx(4 * 10 / 9600)


def test_floor_run_timing_is_marked_assumed_and_a_known_sketch_can_be_given(tmp_path):
    """The data README names no sketch for results_ground_x.mat: its timing is the square-wave
    sketch's, marked assumed; `--sketch rc` records the RC sketch's instead, and the analysis
    reads that (commands 4 packets before the time stamp, in the RC sketch's order)."""
    ft = read_run(import_tfm(DATA / "results_ground_x.mat", tmp_path / "a")).metadata["firmware_timing"]
    assert ft["source"].startswith("assumed") and ft["command_offset_s"] == 0.0
    assert "source" not in read_run(import_tfm(DATA / "square_fast.mat", tmp_path / "b")).metadata["firmware_timing"]
    exe = [sys.executable, "-m", "omnibench", "import", "tfm", str(DATA / "results_ground_x.mat")]
    out = subprocess.run(exe + ["--sketch", "rc", "--out", str(tmp_path / "c"), "--json"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    run = read_run(json.loads(out.stdout)[0]["run"])
    ft = run.metadata["firmware_timing"]
    assert ft["source"] == "given at import" and ft["command_order"] == [1, 2, 4, 3]
    assert ft["command_offset_s"] == pytest.approx(-4 * 4 * 10 / 9600)
    from omnibench.analysis.observations import Observations

    obs = Observations.from_runs([run.path])
    info = obs.runs[obs.run_ids[0]]
    assert info["command_offset"] == pytest.approx(-4 * 4 * 10 / 9600) and info["command_order"] == (1, 2, 4, 3)
    bad = subprocess.run(exe + ["--sketch", "arduino", "--out", str(tmp_path / "d")],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--sketch" in bad.stderr and "Traceback" not in bad.stderr


def test_rc_log_imports_as_random_duty_with_signs_read_off_the_data(tmp_path):
    run = read_run(import_tfm(DATA / "inputs.mat", tmp_path))
    d = _mat("inputs.mat")["data"]
    assert run.procedure == "random_duty" and run.metadata["mode"] == "upside_down"
    assert set(run.steps["kind"]) == {"duty_hold"}  # hand-held command levels, not a square wave
    assert run.metadata["sign_map"] == [-1, 1, -1, 1]
    assert "read off the data" in run.metadata["sign_map_source"]
    np.testing.assert_allclose(run.samples["u4"], np.trunc(127 * d[1]) / 127)
    np.testing.assert_allclose(run.samples["t"], d[0] / 1000.0)
    assert all(_agree(run, j) > 0 for j in range(4))
    ft = run.metadata["firmware_timing"]
    assert ft["command_order"] == [1, 2, 4, 3]  # ardu.ino.ino: FL, FR, BR, BL
    assert ft["command_offset_s"] == pytest.approx(-4 * 4 * 10 / 9600)  # sent before the encoder read
    # the analysis reads it as a trace replayed whole, with its firmware timing
    from omnibench.analysis.observations import Observations

    obs = Observations.from_runs([run.path])
    info = obs.runs[obs.run_ids[0]]
    assert len(obs.step_response) == len(run.steps) and info["command_order"] == (1, 2, 4, 3)


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_second_import_of_the_same_file_changes_nothing_and_q_prints_the_run(tmp_path, capsys):
    from omnibench.cli import main

    def omnibench(*args: str) -> tuple[int, str, str]:
        try:
            main(list(args))
            code = 0
        except SystemExit as exc:
            code = int(exc.code or 0)
        out, err = capsys.readouterr()
        return code, out, err

    out = tmp_path / "tfm"
    code, first, err = omnibench("-q", "import", "tfm", str(DATA / "square_fast.mat"), "--out", str(out))
    assert code == 0, err
    (run_dir,) = list(out.iterdir())
    assert first == f"{run_dir}\n" and err == ""  # -q: the one line a script needs
    before = _tree(out)
    # the same file again, also by another path (a copy): nothing imported, the run named
    copy = tmp_path / "elsewhere" / "square_fast.mat"
    copy.parent.mkdir()
    copy.write_bytes((DATA / "square_fast.mat").read_bytes())
    for f in (DATA / "square_fast.mat", copy):
        code, again, err = omnibench("import", "tfm", str(f), "--out", str(out))
        assert code == 0, err
        assert again.strip() == f"{f}: already imported as {run_dir} (same file): nothing changed"
        assert _tree(out) == before
    # with another sign map it would be another reading of the same log: refused in one line
    code, _, err = omnibench("import", "tfm", str(DATA / "square_fast.mat"), "--signs", "+1,+1,+1,+1",
                             "--out", str(out))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "already imported" in err
    assert _tree(out) == before
