"""Logs in the 2019 layouts whose conditions the layout does not give away, written from the
independent physics (omnibench/worlds/independent.py): `import tfm` with no options reads each
condition off the data (or keeps it unknown), records the evidence, refuses an option the data
contradict, and a model fitted on other logs predicts each as imported no worse than with the
right options declared; fit and diagnose profile a run of unknown mode instead of refusing it.

The cases: an RC-timed log (44 ms loop, the RC sketch's send order, offset and signs) in the
square-wave layout; an in-air square wave saved in the floor-run layout; a floor run in the
floor-run layout; a square-wave log with a loop between the two sketches' (37 ms); and an
in-air log in the floor-run layout from a robot whose wheels are three times heavier than the
robot file says. Where the robot was is read off a floor-run layout only with the wheel's
inertia and an actuator lag profiled (runs/tfm.where_from_dynamics): the heavy wheels must not
pass for the floor, and a floor run that a lighter, lagging wheel in the air would replay
almost as well stays unknown."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io

sys.path.insert(0, str(Path(__file__).parent))
from floorsim import sample_times, square_wave, write_square_log

from omnibench.model import Scenario
from omnibench.runs import read_run
from omnibench.runs.tfm import COUNTS_PER_REV, PACKET_S, WHERE_MARGIN, import_tfm
from omnibench.worlds.independent import simulate_batch

RC_SIGNS = (-1, 1, -1, 1)  # what the RC sketch logged for a positive command (inputs.mat)


def _counts(robot, scenario: Scenario, t: np.ndarray, x: np.ndarray, pattern=(1, 1, 1, 1),
            offset: float = 0.0) -> np.ndarray:
    """Encoder counts (4, N) at the sample times t of the drive value x (each wheel its
    `pattern` entry x x), every command acting from `offset` s after its sample on."""
    U = np.asarray(pattern, dtype=float)[None, :] * x[:, None]
    shift = max(0.0, -offset)
    res = simulate_batch(robot, [scenario], t + offset + shift, U[None], float(t[-1]) + shift + 0.01, dt=1e-3)
    phi = np.stack([np.interp(t + shift, res.t, res.signal(f"phi{j + 1}")[0]) for j in range(4)])
    return np.round(phi / (2 * math.pi) * COUNTS_PER_REV)


def write_rc_timed_square_log(path: Path, robot, seed: int = 4) -> Path:
    """The RC sketch's timing in the square-wave layout: a 44 ms loop, each line's commands sent
    four packets before its time stamp in the order FL, FR, BR, BL (a packet apart), the
    encoders logged with the RC sketch's signs."""
    t = sample_times(6.0, seed, 0.043, 0.045)
    x = square_wave(t, 80 / 127, 1.6)
    scen = Scenario(mode="upside_down", command_order=(1, 2, 4, 3),
                    effects={"serial_command_latency": {"tau": 0.0, "tau_packet": PACKET_S}})
    counts = _counts(robot, scen, t, x, offset=-4 * PACKET_S) * np.asarray(RC_SIGNS)[:, None]
    scipy.io.savemat(str(path), {"data": np.vstack([np.round(x * 127), np.round(t * 1000), np.zeros_like(t), counts])})
    return path


def write_floor_layout(path: Path, robot, mode: str, t: np.ndarray, amplitude: float = 0.5,
                       period: float = 2.0) -> Path:
    """A square wave of the drive value on every wheel in the floor-run layout (`t`, `x`, `m`,
    `Ks`), the robot in `mode`."""
    x = square_wave(t, amplitude, period)
    counts = _counts(robot, Scenario(mode=mode), t, x)
    scipy.io.savemat(str(path), {"t": t[None], "x": x[None], "m": counts / COUNTS_PER_REV,
                                 "Ks": np.full((4, 127), np.nan), "fits": np.full((4, 127), np.nan)})
    return path


#: case -> the options that state its truth (what a user who knew would give)
DECLARED = {
    "rc_timed_square": {"sketch": "rc", "where": "air"},
    "air_in_floor_layout": {"sketch": "square", "where": "air"},
    "floor_run": {"sketch": "square", "where": "floor", "direction": "forward"},
    "between_loop": {"sketch": "square", "where": "air"},
    "unplaceable": {"sketch": "square", "where": "air"},
}


@pytest.fixture(scope="module")
def cases(tmp_path_factory, robot):
    """Each hard case's log, imported with no options and with the declared ones, and the two
    in-air square waves of the same world that the model is fitted on."""
    truth = robot.replace(a=1.3 * robot.a, b=0.8 * robot.b, I_w=1.25 * robot.I_w)
    folder = tmp_path_factory.mktemp("unseen")
    files = {
        "rc_timed_square": write_rc_timed_square_log(folder / "log_a.mat", truth),
        "air_in_floor_layout": write_floor_layout(folder / "log_b.mat", truth, "upside_down",
                                                  sample_times(6.0, 5, 0.026, 0.034)),
        "floor_run": write_floor_layout(folder / "log_c.mat", truth, "ground", sample_times(6.0, 6, 0.030, 0.040)),
        "between_loop": write_square_log(folder / "log_d.mat", truth, 60 / 127, seed=7),
        "unplaceable": write_floor_layout(folder / "log_e.mat", truth.replace(I_w=3 * robot.I_w), "upside_down",
                                          sample_times(6.0, 8, 0.026, 0.034), amplitude=60 / 127, period=1.6),
    }
    # the in-between loop: resample log_d's clock at 34-40 ms (median 37 ms)
    t = sample_times(6.0, 7, 0.034, 0.040)
    x = square_wave(t, 60 / 127, 1.6)
    counts = _counts(truth, Scenario(mode="upside_down"), t, x) * np.asarray((1, -1, 1, -1))[:, None]
    scipy.io.savemat(str(files["between_loop"]), {"data": np.vstack([np.round(x * 127), np.round(t * 1000),
                                                                      np.zeros_like(t), counts])})
    train = [import_tfm(write_square_log(folder / f"train_{a}.mat", truth, a / 127, seed=s), folder / "train")
             for a, s in ((100, 1), (30, 3))]
    plain = {k: import_tfm(f, folder / "plain") for k, f in files.items()}
    declared = {k: import_tfm(f, folder / "declared", **DECLARED[k]) for k, f in files.items()}
    return {"files": files, "plain": plain, "declared": declared, "train": train}


def _conditions(path):
    run = read_run(path)
    return run, run.metadata["conditions"]


def test_an_rc_timed_log_in_the_square_wave_layout_reads_as_the_rc_sketch(cases):
    run, c = _conditions(cases["plain"]["rc_timed_square"])
    assert c["sketch"]["value"] == "rc" and c["sketch"]["decided"] == "inferred from the data"
    assert c["sketch"]["statistic"]["loop_median_s"] == pytest.approx(0.044, abs=0.001)
    ft = run.metadata["firmware_timing"]
    assert ft["command_order"] == [1, 2, 4, 3] and ft["command_offset_s"] == pytest.approx(-4 * PACKET_S)
    assert ft["source"].startswith("read off the data")
    # the RC sketch's signs, read off the data (the square-wave sketch's would turn every wheel back)
    assert c["signs"]["value"] == list(RC_SIGNS) and c["signs"]["decided"] == "inferred from the data"
    assert run.metadata["sign_map"] == list(RC_SIGNS)
    assert c["where"]["value"] == "air" and c["where"]["decided"] == "stated in the file"


def test_an_in_air_square_wave_in_the_floor_layout_reads_as_in_the_air(cases):
    run, c = _conditions(cases["plain"]["air_in_floor_layout"])
    w = c["where"]
    assert w["value"] == "air" and w["decided"] == "inferred from the data" and w["margin"] == WHERE_MARGIN
    assert w["statistic"]["nrmse_floor"] >= WHERE_MARGIN * w["statistic"]["nrmse_air"]
    assert run.metadata["mode"] == "upside_down"
    assert c["sketch"]["value"] == "square" and c["sketch"]["decided"] == "inferred from the data"


def test_a_floor_run_in_the_floor_layout_is_never_read_as_in_the_air(cases):
    """With the wheel's nuisance profiled, a light wheel behind a lagging driver in the air
    replays this floor run within the margin of the floor's fit: it reads floor or unknown,
    never air, and its direction is still read off the data."""
    run, c = _conditions(cases["plain"]["floor_run"])
    w = c["where"]
    assert w["value"] in ("floor", "unknown")
    st = w["statistic"]
    assert st["nrmse_floor"] <= st["nrmse_air"]
    if w["value"] == "unknown":
        assert st["nrmse_air"] < WHERE_MARGIN * st["nrmse_floor"] and run.metadata["mode"] is None
    else:
        assert st["nrmse_air"] >= WHERE_MARGIN * st["nrmse_floor"] and run.metadata["mode"] == "ground"
    # the file's own wheel in the air misses the floor run by far: only the profiled one comes close
    assert st["nrmse_air_file"] >= WHERE_MARGIN * st["nrmse_floor"]
    assert c["direction"]["value"] == "forward" and c["direction"]["decided"] == "inferred from the data"
    # a 30-40 ms clock (median 35 ms): neither sketch's loop
    assert c["sketch"]["value"] == "unknown" and run.metadata["firmware_timing"]["sketch"] == "unknown"


def test_a_loop_between_the_two_sketches_keeps_the_sketch_unknown(cases):
    run, c = _conditions(cases["plain"]["between_loop"])
    s = c["sketch"]
    assert s["value"] == "unknown" and s["decided"] == "unknown"
    assert 0.034 < s["statistic"]["loop_median_s"] < 0.040
    ft = run.metadata["firmware_timing"]
    assert ft["sketch"] == "unknown" and len(ft["profiled_over"]) == 2 and ft["source"].startswith("assumed")
    # the user may say which: nothing in the data contradicts it
    run, c = _conditions(cases["declared"]["between_loop"])
    assert c["sketch"]["value"] == "square" and c["sketch"]["decided"] == "stated by the user"
    assert run.metadata["firmware_timing"]["sketch"] == "arduino/square/square.ino"


def test_wheels_three_times_heavier_than_the_file_says_are_not_read_as_the_floor(cases, robot):
    """Against the file's own wheel an in-air log of wheels three times heavier settles like the
    floor's; with I_w profiled it reads in the air (or unknown), the best inertia near the true."""
    run, c = _conditions(cases["plain"]["unplaceable"])
    w, st = c["where"], c["where"]["statistic"]
    assert w["value"] in ("air", "unknown") and st["nrmse_air"] < st["nrmse_floor"]
    if w["value"] == "air":
        assert w["decided"] == "inferred from the data" and run.metadata["mode"] == "upside_down"
        assert st["nrmse_floor"] >= WHERE_MARGIN * st["nrmse_air"]
    else:
        assert run.metadata["mode"] is None
    # the file's wheel fits it worse than the profiled one, whose inertia is the grid's nearest to 3 x
    assert st["nrmse_air_file"] > 1.5 * st["nrmse_air"]
    assert 2.0 * robot.I_w <= st["best_air"]["I_w"] <= 3.5 * robot.I_w + 1e-12


def _cli(capsys, *args):
    from omnibench.cli import main

    try:
        main(["import", "tfm", *map(str, args)])
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_options_the_data_contradict_are_refused_in_one_line(cases, tmp_path, capsys):
    files = cases["files"]
    for name, opts, words in (("rc_timed_square", ["--sketch", "square"], ("--sketch square", "44.0 ms")),
                              ("air_in_floor_layout", ["--where", "floor"], ("--where floor", "in the air")),
                              ("unplaceable", ["--where", "floor"], ("--where floor", "in the air"))):
        code, _, err = _cli(capsys, files[name], *opts, "--out", tmp_path / name)
        assert code == 2 and len(err.strip().splitlines()) == 1, (name, err)
        assert all(w in err for w in words) and "--force" in err, (name, err)
        assert not (tmp_path / name).exists() or not any((tmp_path / name).iterdir())
    # a user who insists: the option wins, and the run records what it overrode
    code, out, err = _cli(capsys, files["air_in_floor_layout"], "--where", "floor", "--force", "--out", tmp_path / "f")
    assert code == 0, err
    (path,) = list((tmp_path / "f").iterdir())
    run, c = _conditions(path)
    assert run.metadata["mode"] == "ground" and c["where"]["decided"] == "stated by the user"
    assert "the data say in the air" in c["where"]["overrides"]
    # where the data cannot tell (the floor run, unknown with the wheel profiled), the user's word stands
    if read_run(cases["plain"]["floor_run"]).metadata["mode"] is None:
        code, out, err = _cli(capsys, files["floor_run"], "--where", "floor", "--out", tmp_path / "g")
        assert code == 0, err
        (path,) = list((tmp_path / "g").iterdir())
        run, c = _conditions(path)
        assert run.metadata["mode"] == "ground" and c["where"]["decided"] == "stated by the user"
        assert "overrides" not in c["where"] and "profiled" in c["where"]["evidence"]


def _unknown_mode_run(cases):
    path = cases["plain"]["floor_run"]
    if read_run(path).metadata["mode"] is not None:
        pytest.skip("the floor run was placed at import: no run of unknown mode to profile")
    return path


def test_fit_profiles_a_run_of_unknown_mode_and_keeps_the_true_mode(cases, capsys):
    """fit with a run of unknown mode: both modes fitted, the floor (the truth) kept, the
    output and the JSON name the mode given and the alternative's cost."""
    import json

    from omnibench.cli import main

    unknown = _unknown_mode_run(cases)
    model = Path(__file__).resolve().parents[2] / "omnibench" / "model" / "omnibot.toml"
    out = Path(cases["train"][0]).parent / "m.toml"
    main(["fit", str(unknown), str(cases["train"][0]), "--procedures", "step_response", "--free", "a",
          "--no-per-wheel", "--out", str(out), "--robot", str(model), "--json"])
    captured = capsys.readouterr()
    prof = json.loads(captured.out)["mode_profile"]
    (name,) = prof["chosen"]
    assert name == read_run(unknown).info.run_id
    assert prof["chosen"][name] == "ground"
    costs = {t["modes"][name]: t["cost"] for t in prof["tried"]}
    assert set(costs) == {"ground", "upside_down"} and costs["ground"] < costs["upside_down"]
    assert "assignment 2 of 2" in captured.err
    main(["fit", str(unknown), str(cases["train"][0]), "--procedures", "step_response", "--free", "a",
          "--no-per-wheel", "--out", str(out), "--robot", str(model)])
    text = capsys.readouterr().out
    assert "where unknown, profiled over 2 assignments of modes: kept" in text and "on the floor" in text


def test_more_unknown_mode_runs_than_profiled_are_refused_in_one_line():
    from omnibench.analysis.modes import MAX_UNKNOWN_MODES, assignments
    from omnibench.errors import UserError

    assert len(assignments([f"r{k}" for k in range(MAX_UNKNOWN_MODES)])) == 2 ** MAX_UNKNOWN_MODES
    with pytest.raises(UserError) as exc:
        assignments([f"r{k}" for k in range(MAX_UNKNOWN_MODES + 1)])
    assert "--where" in str(exc.value) and "\n" not in str(exc.value)


def test_diagnose_profiles_a_run_of_unknown_mode_at_its_declared_fit(cases, capsys):
    """diagnose with a run of unknown mode: the declared fit in both modes, the floor kept and
    said so, and the rest of the diagnosis replays the run on the floor."""
    import json

    from omnibench.cli import main

    unknown = _unknown_mode_run(cases)
    model = Path(__file__).resolve().parents[2] / "omnibench" / "model" / "omnibot.toml"
    main(["diagnose", "--model", str(model), str(unknown), str(cases["train"][0]), "--candidates", "actuator_lag",
          "--max-effects", "1", "--json"])
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    prof = data["mode_profile"]
    (name,) = prof["chosen"]
    assert prof["chosen"][name] == "ground" and len(prof["tried"]) == 2
    assert any("the diagnosis keeps these modes" in n for n in data["notes"])


def test_each_log_as_imported_is_predicted_no_worse_than_with_the_right_options(cases, robot):
    """The model fitted on the two in-air square waves (a, b, I_w) predicts each hard case as
    imported with no options (an unknown sketch or mode profiled over its alternatives) no
    worse than as imported with the options that state its truth."""
    from omnibench.analysis.heldout_runs import PhysicsModel, fit_physics
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.predict import predict_runs

    fitted = fit_physics(PhysicsModel(robot, free=["a", "b", "I_w"]),
                         Observations.from_runs(cases["train"], robot), max_nfev=20)

    def nrmse(path):
        p = predict_runs(fitted, Observations.from_runs([path], robot), profile_timing=True)[0]
        return p, p.nrmse["wheel_speed"]

    for name in DECLARED:
        p, plain = nrmse(cases["plain"][name])
        _, declared = nrmse(cases["declared"][name])
        assert plain <= declared + 1e-9, (name, plain, declared)
        assert math.isfinite(plain) and plain < 1.0, (name, plain)
        print(f"{name}: wheel-speed NRMSE as imported {100 * plain:.2f} %, declared {100 * declared:.2f} %"
              + (f"; {p.mode_text()}" if p.mode_profiled else "") + (f"; {p.firmware_text()}" if p.firmware else ""))
    # the floor run, where unknown at import: replayed both ways, the floor kept
    p, _ = nrmse(_unknown_mode_run(cases))
    assert set(p.mode_profiled) == {"upside_down", "ground"} and p.mode == "ground"
    assert p.mode_profiled["ground"] < p.mode_profiled["upside_down"] and "where unknown" in p.mode_text()
