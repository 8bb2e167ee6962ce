"""The floor in every direction (issue 36): floor logs in the 2019 format go through `import tfm`
with each wheel's duty from the kinematics, and a model fitted on in-air and forward runs
predicts sideways, diagonal and rotating runs on the independent physics.

The simulated logs (floorsim.py) are written as the 2019 sketches wrote theirs: square waves in
the air with the FR and BR encoders negated (square.ino), floor runs as `t`, `x`, `m`, `Ks`
with the floor sketch's corrected signs; nothing tells the importer the direction."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from floorsim import floor_logs, write_square_log

from omnibench.runs import read_run
from omnibench.runs.tfm import DIRECTIONS, direction_of, import_tfm, kinematic_pattern

ALL = ("forward", "sideways", "rotation", "diagonal")


def test_floor_directions_are_the_columns_of_the_kinematics():
    """Each direction's duty pattern is the sign of R v (design.md): a sideways run turns the
    wheels in opposite pairs (FL with RR against FR with RL), a rotation the left side against
    the right, a diagonal only FR and RL."""
    for d in ALL:
        np.testing.assert_array_equal(kinematic_pattern(d), DIRECTIONS[d])
    fl, fr, rl, rr = DIRECTIONS["sideways"]
    assert fl == rr == -fr == -rl == -1
    fl, fr, rl, rr = DIRECTIONS["rotation"]
    assert fl == rl == -fr == -rr == -1
    assert DIRECTIONS["diagonal"] == (0, 1, 1, 0)
    # read back off the data: wheels that travel with the pattern x a drive value
    x = np.array([0, 1, 1, 1, -1, -1, -1, 1, 1, 0], float)
    for d in ALL:
        counts = np.cumsum(np.outer(DIRECTIONS[d], x), axis=1)
        assert direction_of(x, counts) == d
        assert direction_of(-x, -counts) == d  # the same run logged with the drive value negated
    from omnibench.errors import UserError

    with pytest.raises(UserError, match="no floor direction"):
        direction_of(x, np.cumsum(np.outer((1, -1, 1, 1), x), axis=1))


@pytest.fixture(scope="module")
def worlds(tmp_path_factory, robot):
    """Two independent-physics robots: `same_rollers` (a, b, I_w away from the robot file,
    rollers as the file says) and `stiff_rollers` (also roller friction a_r, b_r 4 x the file's),
    each with two square waves in the air and a floor run per direction, imported."""
    out = {}
    for name, extra in (("same_rollers", {}), ("stiff_rollers", {"a_r": 4 * robot.a_r, "b_r": 4 * robot.b_r})):
        truth = robot.replace(a=1.3 * robot.a, b=0.8 * robot.b, I_w=1.25 * robot.I_w, **extra)
        folder = tmp_path_factory.mktemp(name)
        files = [write_square_log(folder / "square_big.mat", truth, 100 / 127, seed=1),
                 write_square_log(folder / "square_small.mat", truth, 30 / 127, seed=3)]
        files += list(floor_logs(folder, truth, ALL).values())
        # the floor runs say --where floor: with the wheel's inertia and lag profiled, a slow forward
        # run may read where unknown (runs/tfm.where_from_dynamics), and these tests are about directions
        out[name] = (truth, {Path(f).stem: import_tfm(f, folder / "runs",
                                                      where="floor" if "ground" in Path(f).stem else None)
                             for f in files})
    return out


def test_simulated_floor_logs_import_with_the_kinematics_signs(worlds):
    """The importer reads each floor run's direction off its wheels, gives each wheel its duty
    pattern x the drive value, and in the sideways run the measured wheels turn in opposite
    pairs; the firmware is recorded unknown."""
    _, runs = worlds["same_rollers"]
    for d in ALL:
        run = read_run(runs[f"sim_ground_{d}"])
        assert run.metadata["direction"] == d and run.metadata["direction_source"] == "read off the data"
        assert run.metadata["firmware_timing"]["sketch"] == "unknown"
        s = run.samples
        drive = s["u2"].to_numpy()  # FR's pattern entry is +1 in every direction
        for j in range(4):
            np.testing.assert_allclose(s[f"u{j + 1}"], DIRECTIONS[d][j] * drive, atol=1e-12)
            travel = float(np.diff(s[f"phi{j + 1}"].to_numpy()) @ drive[:-1])
            if DIRECTIONS[d][j] == 0:
                assert abs(travel) < 0.05 * float(np.diff(s["phi2"].to_numpy()) @ drive[:-1])
            else:
                assert np.sign(travel) == DIRECTIONS[d][j]


def test_cli_refuses_a_floor_log_against_its_declared_direction(worlds, tmp_path):
    _, runs = worlds["same_rollers"]
    src = read_run(runs["sim_ground_sideways"]).metadata["source_file"]
    exe = [sys.executable, "-m", "omnibench", "import", "tfm", src, "--out", str(tmp_path)]
    bad = subprocess.run(exe + ["--direction", "forward"], check=False, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    assert "sideways" in bad.stderr and "--direction" in bad.stderr
    ok = subprocess.run(exe + ["--direction", "sideways"], check=False, capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert "driving sideways" in ok.stdout and "firmware unknown" in ok.stdout


def _fit_and_predict(robot, runs, free, train_names):
    from omnibench.analysis.heldout_runs import PhysicsModel, fit_physics
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.predict import predict_runs

    train = Observations.from_runs([runs[n] for n in train_names], robot)
    fitted = fit_physics(PhysicsModel(robot, free=free), train)
    preds = {d: predict_runs(fitted, Observations.from_runs([runs[f"sim_ground_{d}"]], robot))[0] for d in ALL}
    return fitted, preds


IN_AIR_AND_FORWARD = ("square_big", "square_small", "sim_ground_forward")


@pytest.mark.slow
def test_floor_runs_in_every_direction_predicted_from_in_air_and_forward_runs(worlds, robot):
    """Done-means of issue 36: within 10 % wheel-speed NRMSE in every direction (measured about
    1 %, the encoder quantisation), the fitted a, b, I_w within 5 % of the truth."""
    truth, runs = worlds["same_rollers"]
    fitted, preds = _fit_and_predict(robot, runs, ["a", "b", "I_w"], IN_AIR_AND_FORWARD)
    for k in ("a", "b", "I_w"):
        assert getattr(fitted, k) == pytest.approx(getattr(truth, k), rel=0.05)
    for d, p in preds.items():
        assert p.nrmse["wheel_speed"] < 0.10, (d, p.nrmse)
    assert preds["sideways"].nrmse["wheel_speed"] < 0.03


@pytest.mark.slow
def test_roller_friction_is_what_in_air_and_forward_runs_cannot_see(worlds, robot):
    """When the rollers are not as the robot file says, in-air and forward runs cannot tell
    (no roller slip: sigma = S v = 0 for v = (v1, 0, 0)): the fit calls a_r, b_r not identifiable,
    the forward run stays predicted while sideways and diagonal runs are not (> 10 %); one
    sideways floor run in the fit identifies them and every direction is predicted again. The
    measurement that fixes it: a run with roller slip (III.iii lateral, or a sideways floor run)."""
    from omnibench.analysis.fitting import fit
    from omnibench.analysis.observations import Observations

    truth, runs = worlds["stiff_rollers"]
    train = Observations.from_runs([runs[n] for n in IN_AIR_AND_FORWARD], robot)
    verdicts = {r["name"]: r["verdict"] for r in fit(robot, train, ["a", "b", "I_w", "a_r", "b_r"],
                                                     procedures=["step_response"], max_nfev=20).summary_rows()}
    assert verdicts["a_r"] == verdicts["b_r"] == "not identifiable" and verdicts["I_w"] == "identified"
    _, preds = _fit_and_predict(robot, runs, ["a", "b", "I_w"], IN_AIR_AND_FORWARD)
    assert preds["forward"].nrmse["wheel_speed"] < 0.03
    assert preds["sideways"].nrmse["wheel_speed"] > 0.10 and preds["diagonal"].nrmse["wheel_speed"] > 0.10
    fitted, preds = _fit_and_predict(robot, runs, ["a", "b", "I_w", "a_r", "b_r"],
                                     ("square_big", "sim_ground_forward", "sim_ground_sideways"))
    assert fitted.a_r == pytest.approx(truth.a_r, rel=0.15) and fitted.b_r == pytest.approx(truth.b_r, rel=0.15)
    for d, p in preds.items():
        assert p.nrmse["wheel_speed"] < 0.05, (d, p.nrmse)


def test_a_sideways_run_replayed_with_one_duty_for_every_wheel_is_worse_than_zero(worlds):
    """Why a sideways floor run scored ~146 % before: replayed with every wheel at the drive
    value (a forward run's duties) the model turns FL and RR against the measured wheels, an
    NRMSE above 100 % (predicting zero gives 100 %); with the kinematics' pattern, about 1 %."""
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.predict import predict_runs

    truth, runs = worlds["same_rollers"]
    for d in ("sideways", "rotation"):
        obs = Observations.from_runs([runs[f"sim_ground_{d}"]], truth)
        assert predict_runs(truth, obs)[0].nrmse["wheel_speed"] < 0.03
        for tr in obs.traces.values():
            for j in range(1, 5):
                tr[f"u{j}"] = tr["u2"].to_numpy()  # FR's duty is the drive value in every direction
        assert predict_runs(truth, obs)[0].nrmse["wheel_speed"] > 1.0


@pytest.mark.skipif(not Path("/work/shared/data/omnibot-tfm/results_ground_x.mat").is_file()
                    and not (Path(__file__).resolve().parents[3] / "shared/data/omnibot-tfm").is_dir(),
                    reason="2019 TFM data not available")
def test_the_real_2019_floor_run_reads_as_forward_with_its_corrected_signs(tmp_path):
    """results_ground_x.mat: the sketch had already corrected the signs (map +1), and every wheel
    travels with the drive value: a forward run by the kinematics."""
    data = next((p / "shared/data/omnibot-tfm" for p in Path(__file__).resolve().parents
                 if (p / "shared/data/omnibot-tfm").is_dir()), Path("/work/shared/data/omnibot-tfm"))
    run = read_run(import_tfm(data / "results_ground_x.mat", tmp_path))
    assert run.metadata["direction"] == "forward" and run.metadata["sign_map"] == [1, 1, 1, 1]
    assert run.metadata["wheel_pattern"] == list(kinematic_pattern("forward"))
