"""`omnibench import csv`: logs written by hand in odd but legal shapes import to the same run as
the plain form; what a map leaves out is read off the data or recorded unknown; contradictions and
bad input are refused in one line; a fit on an imported simulated log recovers its coefficients.

The logs are square waves in the air simulated on the independent physics
(omnibench/worlds/independent.py, through tests/analysis/floorsim.py) and sampled irregularly, as
an Arduino loop samples (28-42 ms apart), then written by the test in each shape."""

from __future__ import annotations

import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "analysis"))
from floorsim import sample_times, simulate_counts, square_wave

from omnibench.cli import main
from omnibench.runs import read_run
from omnibench.runs.csv_import import load_map, shipped_maps

COUNTS = 980
DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "omnibot-tfm"
if not DATA.is_dir():
    DATA = Path("/work/shared/data/omnibot-tfm")

PLAIN_MAP = """
[map]
name = "plain"
[run]
procedure = "step_response"
where = "air"
counts_per_rev = 980
[columns]
time = { column = "t", unit = "s" }
duty = { columns = ["u1", "u2", "u3", "u4"], unit = "1" }
encoder = { columns = ["enc1", "enc2", "enc3", "enc4"], unit = "counts" }
"""


def omnibench(capsys, *args: str) -> tuple[int, str, str]:
    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def _num(v: float, decimal: str = ".") -> str:
    text = repr(float(v))
    return text.replace(".", ",") if decimal == "," else text


@pytest.fixture(scope="module")
def logs(omnibot):
    """Two square waves (100/127 and 30/127 of full duty) on a robot whose a, b and I_w are not
    the robot file's; duties on the 1/127 grid, time stamps in whole milliseconds."""
    robot = omnibot
    truth = robot.replace(a=1.3 * robot.a, b=0.8 * robot.b, I_w=1.25 * robot.I_w)
    out = {}
    for name, amp, seed in (("big", 100 / 127, 1), ("small", 30 / 127, 3)):
        t = sample_times(6.0, seed)
        x = square_wave(t, amp, 1.6)
        counts = simulate_counts(truth, "upside_down", t, np.repeat(x[None, :, None], 4, axis=2))[0].T
        out[name] = (t, x, counts.astype(np.int64))
    return truth, out


def write_plain(path: Path, t, x, counts) -> Path:
    lines = ["t,u1,u2,u3,u4,enc1,enc2,enc3,enc4"]
    for k in range(t.size):
        lines.append(",".join([_num(t[k])] + [_num(x[k])] * 4 + [str(c) for c in counts[k]]))
    path.write_text("\n".join(lines) + "\n")
    return path


def _cli_import(capsys, tmp_path, files, map_text, *extra, out="runs"):
    m = tmp_path / f"map{len(list(tmp_path.glob('map*')))}.toml"
    m.write_text(map_text)
    code, out, err = omnibench(capsys, "import", "csv", *files, "--map", m, "--out", tmp_path / out, "--json",
                               *extra)
    assert code == 0, err
    return [read_run(r["run"]) for r in json.loads(out)]


SAMPLE_COLS = ["step", "t", "u1", "u2", "u3", "u4", "enc1", "enc2", "enc3", "enc4", "phi1", "phi2", "phi3", "phi4"]
STEP_COLS = ["step", "duty", "u1", "u2", "u3", "u4", "t_start", "t_end", "n_samples"]


def assert_same_run(a, b):
    for cols, ta, tb in ((SAMPLE_COLS, a.samples, b.samples), (STEP_COLS, a.steps, b.steps)):
        assert len(ta) == len(tb)
        np.testing.assert_allclose(ta[cols].to_numpy(float), tb[cols].to_numpy(float), rtol=1e-12, atol=1e-9)
    for k in ("mode", "sign_map", "counts_per_rev"):
        assert a.metadata[k] == b.metadata[k], k
    assert a.info.duty_timing == b.info.duty_timing or b.info.duty_timing is None  # import tfm: the reader's default


def test_odd_shapes_import_to_the_plain_forms_run(logs, tmp_path, capsys):
    _, d = logs
    t, x, counts = d["big"]
    (plain,) = _cli_import(capsys, tmp_path, [write_plain(tmp_path / "plain.csv", t, x, counts)], PLAIN_MAP)
    assert plain.procedure == "step_response" and plain.status == "complete"
    np.testing.assert_allclose(plain.samples["t"], t)
    np.testing.assert_array_equal(plain.samples["enc3"], counts[:, 2])
    np.testing.assert_allclose(plain.samples["phi3"], counts[:, 2] * 2 * math.pi / COUNTS)
    assert plain.steps["n_samples"].sum() == t.size  # one step per constant-duty segment, tiling the samples
    assert len(plain.steps) == 1 + np.count_nonzero(np.diff(x)) == 9
    assert plain.metadata["mode"] == "upside_down"
    cond = plain.metadata["conditions"]
    assert cond["where"] == {"value": "air", "source": "stated in the map"}
    # what the map leaves out is read off the data, with its statistic
    assert cond["signs"]["value"] == [1, 1, 1, 1] and cond["signs"]["source"].startswith("inferred from the data")
    assert cond["duty_timing"]["value"] == "from_sample" and "isolated duty changes" in cond["duty_timing"]["source"]
    assert cond["firmware_timing"]["value"] == "unknown"
    assert plain.metadata["csv_layout"]["separator"]["value"] == ","

    # semicolons, decimal commas, a units row; the map states no unit
    rows = ["time;duty_fl;duty_fr;duty_rl;duty_rr;e1;e2;e3;e4", "[ms];[%];[%];[%];[%];[counts];[counts];[counts];[counts]"]
    for k in range(t.size):
        rows.append(";".join([_num(1000 * t[k], ",")] + [_num(100 * x[k], ",")] * 4 + [str(c) for c in counts[k]]))
    (tmp_path / "semicolons.csv").write_text("\n".join(rows) + "\n")
    semi_map = PLAIN_MAP.replace('{ column = "t", unit = "s" }', '{ column = "time" }').replace(
        '{ columns = ["u1", "u2", "u3", "u4"], unit = "1" }', '{ columns = ["duty_fl", "duty_fr", "duty_rl", "duty_rr"] }'
    ).replace('{ columns = ["enc1", "enc2", "enc3", "enc4"], unit = "counts" }', '{ columns = ["e1", "e2", "e3", "e4"] }')
    # another column order, revolutions, a PWM command in one column, CRLF line ends, a comment
    rows = ["# logged by hand", "rev_rr,rev_fl,cmd,rev_rl,ms,rev_fr"]
    for k in range(t.size):
        c = counts[k] / COUNTS
        rows.append(",".join([_num(c[3]), _num(c[0]), str(int(round(127 * x[k]))), _num(c[2]), _num(1000 * t[k]),
                              _num(c[1])]))
    (tmp_path / "reordered.csv").write_text("\r\n".join(rows) + "\r\n")
    order_map = PLAIN_MAP.replace('{ column = "t", unit = "s" }', '{ column = "ms", unit = "ms" }').replace(
        '{ columns = ["u1", "u2", "u3", "u4"], unit = "1" }', '{ column = "cmd", unit = "pwm", range = [-127, 127] }'
    ).replace('{ columns = ["enc1", "enc2", "enc3", "enc4"], unit = "counts" }',
              '{ columns = ["rev_fl", "rev_fr", "rev_rl", "rev_rr"], unit = "rev" }')
    # tab-separated, no names row: columns by position
    rows = ["\t".join([_num(t[k])] + [str(c) for c in counts[k]] + [_num(x[k])] * 4) for k in range(t.size)]
    (tmp_path / "tabs.txt").write_text("\n".join(rows) + "\n")
    tab_map = PLAIN_MAP.replace('{ column = "t", unit = "s" }', '{ column = 1, unit = "s" }').replace(
        '["u1", "u2", "u3", "u4"]', "[6, 7, 8, 9]").replace('["enc1", "enc2", "enc3", "enc4"]', "[2, 3, 4, 5]")

    (semi,) = _cli_import(capsys, tmp_path, [tmp_path / "semicolons.csv"], semi_map)
    (order,) = _cli_import(capsys, tmp_path, [tmp_path / "reordered.csv"], order_map)
    (tabs,) = _cli_import(capsys, tmp_path, [tmp_path / "tabs.txt"], tab_map)
    lay = semi.metadata["csv_layout"]
    assert lay["separator"]["value"] == ";" and lay["decimal"]["value"] == ","
    assert lay["units_row"]["value"] is True and lay["units_row"]["source"] == "read off the file"
    assert lay["columns"]["time"][0] == {"column": "time", "unit": "ms", "source": "stated in the file's units row"}
    assert tabs.metadata["csv_layout"]["separator"]["value"] == "\t"
    assert tabs.metadata["csv_layout"]["header"]["value"] is False
    assert_same_run(semi, plain)
    assert_same_run(tabs, plain)
    # positions given in revolutions: the same angles, no counts
    assert order.samples["enc1"].isna().all()
    order.samples[["enc1", "enc2", "enc3", "enc4"]] = plain.samples[["enc1", "enc2", "enc3", "enc4"]]
    assert_same_run(order, plain)
    assert order.steps["command"].abs().max() == 100


def test_irregular_sampling_is_kept_as_logged(logs, tmp_path, capsys):
    """Rows dropped at random (gaps of up to ~0.3 s between samples): the run keeps every logged
    time stamp, and the steps still tile the samples."""
    _, d = logs
    t, x, counts = d["big"]
    keep = np.random.default_rng(5).random(t.size) > 0.6
    keep[:3] = True
    f = write_plain(tmp_path / "gappy.csv", t[keep], x[keep], counts[keep])
    (run,) = _cli_import(capsys, tmp_path, [f], PLAIN_MAP)
    np.testing.assert_allclose(run.samples["t"], t[keep])
    assert np.diff(t[keep]).max() > 0.2
    assert run.steps["n_samples"].sum() == keep.sum()
    np.testing.assert_array_equal(run.samples["enc2"], counts[keep, 1])


def test_a_fit_on_imported_logs_recovers_the_coefficients(logs, tmp_path, capsys):
    truth, d = logs
    files = [write_plain(tmp_path / f"square_{n}.csv", *d[n]) for n in ("big", "small")]
    runs = _cli_import(capsys, tmp_path, files, PLAIN_MAP)
    model = tmp_path / "model.toml"
    code, out, err = omnibench(capsys, "fit", *[r.path for r in runs], "--procedures", "step_response",
                               "--free", "a,b,I_w", "--no-per-wheel", "--out", model, "--json")
    assert code == 0, err
    res = json.loads(out)["parameters"]
    for p in ("a", "b", "I_w"):
        start = getattr(truth, p) / {"a": 1.3, "b": 0.8, "I_w": 1.25}[p]  # the shipped robot file's
        assert res[p]["value"] == pytest.approx(getattr(truth, p), rel=0.03), (p, res[p])
        assert abs(res[p]["value"] - getattr(truth, p)) < 4 * res[p]["se"], (p, res[p])
        assert abs(start - getattr(truth, p)) > 0.15 * getattr(truth, p)  # the start was far off


def _refused(capsys, tmp_path, file, map_text, *extra, out=None):
    m = tmp_path / "bad_map.toml"
    m.write_text(map_text)
    out = out or tmp_path / "refused"
    code, stdout, err = omnibench(capsys, "import", "csv", *([file] if not isinstance(file, list) else file),
                                  "--map", m, "--out", out, *extra)
    assert code == 2, (stdout, err)
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not list(Path(out).glob("*/run.json")), "nothing is written for a refused import"
    return err


def test_bad_input_and_contradictions_are_refused_in_one_line(logs, tmp_path, capsys):
    _, d = logs
    t, x, counts = d["big"]
    plain = write_plain(tmp_path / "plain.csv", t, x, counts)
    lines = plain.read_text().splitlines()
    assert "no column 'enc5'" in _refused(capsys, tmp_path, plain, PLAIN_MAP.replace('"enc4"]', '"enc5"]'))
    assert "unknown unit 'furlong'" in _refused(capsys, tmp_path, plain, PLAIN_MAP.replace('unit = "s"', 'unit = "furlong"'))
    (tmp_path / "empty.csv").write_text("")
    assert "empty" in _refused(capsys, tmp_path, tmp_path / "empty.csv", PLAIN_MAP)
    swapped = lines[:5] + [lines[6], lines[5]] + lines[7:]
    (tmp_path / "swapped.csv").write_text("\n".join(swapped) + "\n")
    err = _refused(capsys, tmp_path, tmp_path / "swapped.csv", PLAIN_MAP)
    assert "swapped.csv:7:" in err and "must increase" in err
    # a units row that says ms where the map says s
    (tmp_path / "units.csv").write_text("\n".join([lines[0], "ms,1,1,1,1,counts,counts,counts,counts"] + lines[1:]) + "\n")
    assert "disagree" in _refused(capsys, tmp_path, tmp_path / "units.csv", PLAIN_MAP)
    # a separator the map states and the file does not use
    assert "separator ';'" in _refused(capsys, tmp_path, plain, PLAIN_MAP + '[file]\nseparator = ";"\n')
    # percentages read as fractions
    rows = [lines[0]] + [",".join([r.split(",")[0]] + [repr(100 * float(v)) for v in r.split(",")[1:5]]
                                  + r.split(",")[5:]) for r in lines[1:]]
    (tmp_path / "percent.csv").write_text("\n".join(rows) + "\n")
    assert "outside [-1, 1]" in _refused(capsys, tmp_path, tmp_path / "percent.csv", PLAIN_MAP)
    # statements that disagree: the map and --where, the file name and the map
    err = _refused(capsys, tmp_path, plain, PLAIN_MAP, "--where", "floor")
    assert "on the floor (given with --where) but in the air (stated in the map)" in err
    floor_named = tmp_path / "square_floor.csv"
    floor_named.write_text(plain.read_text())
    assert "file name" in _refused(capsys, tmp_path, floor_named, PLAIN_MAP)
    # statements the data contradict: a sign map, a duty timing
    err = _refused(capsys, tmp_path, plain, PLAIN_MAP.replace("counts_per_rev = 980", "counts_per_rev = 980\nsigns = [1, -1, 1, 1]"))
    assert "wheel 2" in err and "the data say +1" in err
    err = _refused(capsys, tmp_path, plain, PLAIN_MAP.replace("counts_per_rev = 980",
                                                              'counts_per_rev = 980\nduty_timing = "interval_before"'))
    assert "the data say from_sample" in err
    # counts without a resolution
    assert "counts per wheel revolution" in _refused(capsys, tmp_path, plain, PLAIN_MAP.replace("counts_per_rev = 980", ""))
    # one bad file among good ones: nothing is written
    _refused(capsys, tmp_path, [plain, tmp_path / "swapped.csv"], PLAIN_MAP)


def test_nothing_the_tool_did_not_write_is_overwritten(logs, tmp_path, capsys):
    _, d = logs
    plain = write_plain(tmp_path / "plain.csv", *d["big"])
    (run,) = _cli_import(capsys, tmp_path, [plain], PLAIN_MAP)
    # an --out inside a run directory is refused; a folder with other files keeps them
    err = _refused(capsys, tmp_path, plain, PLAIN_MAP, out=run.path / "more")
    assert "inside the run directory" in err
    mine = tmp_path / "runs" / "notes.txt"
    mine.write_text("mine")
    before = sorted(p.name for p in (tmp_path / "runs").iterdir())
    # the same file again: nothing changes; with another reading of it: refused
    m = tmp_path / "map0.toml"
    code, out, err = omnibench(capsys, "import", "csv", plain, "--map", m, "--out", tmp_path / "runs")
    assert code == 0 and "already imported" in out, err
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == before and mine.read_text() == "mine"
    m2 = tmp_path / "other.toml"
    m2.write_text(PLAIN_MAP.replace('name = "plain"', 'name = "other"'))
    code, out, err = omnibench(capsys, "import", "csv", plain, "--map", m2, "--out", tmp_path / "runs")
    assert code == 2 and "already imported" in err and "another map" in err


def test_where_is_stated_inferred_or_unknown(logs, omnibot, tmp_path, capsys):
    _, d = logs
    t, x, counts = d["big"]
    no_where = PLAIN_MAP.replace('where = "air"\n', "")
    (unknown,) = _cli_import(capsys, tmp_path, [write_plain(tmp_path / "plain.csv", t, x, counts)], no_where)
    assert unknown.metadata["mode"] is None
    assert unknown.metadata["conditions"]["where"]["value"] == "unknown"
    assert "the data show neither" in unknown.metadata["conditions"]["where"]["source"]
    (named,) = _cli_import(capsys, tmp_path, [write_plain(tmp_path / "square_jacked.csv", t, x, counts)], no_where,
                           out="named")
    assert named.metadata["mode"] == "upside_down"
    assert named.metadata["conditions"]["where"]["source"] == "stated in the file name (the word 'jacked')"
    # a pose that does not move while the wheels turn: in the air
    rows = ["t,u1,u2,u3,u4,enc1,enc2,enc3,enc4,x_mm,y_mm,yaw_deg"]
    noise = np.random.default_rng(2).normal(0, 0.5, (t.size, 3))
    for k in range(t.size):
        rows.append(",".join([_num(t[k])] + [_num(x[k])] * 4 + [str(c) for c in counts[k]]
                             + [_num(v) for v in noise[k]]))
    (tmp_path / "posed.csv").write_text("\n".join(rows) + "\n")
    posed_map = no_where.replace("[columns]", '[columns]\npose = { columns = ["x_mm", "y_mm", "yaw_deg"], '
                                 'units = ["mm", "mm", "deg"] }')
    (posed,) = _cli_import(capsys, tmp_path, [tmp_path / "posed.csv"], posed_map, out="posed")
    where = posed.metadata["conditions"]["where"]
    assert where["value"] == "air" and where["source"].startswith("inferred from the data: the logged pose")
    assert (posed.path / "pose.csv").is_file()
    err = _refused(capsys, tmp_path, tmp_path / "posed.csv", posed_map, "--where", "floor")
    assert "on the floor (given with --where) but the data say in the air" in err and "pose" in err


def test_the_floor_kinematics_tell_air_from_floor_and_a_floor_direction(omnibot, tmp_path, capsys):
    """Duties the floor kinematics cannot follow (front wheels only): in the air only the driven
    wheels turn, on the floor all four turn as R v. A floor run driven by one value in a
    direction: the direction is read off the wheels."""
    from omnibench.runs.tfm import DIRECTIONS

    t = sample_times(4.0, 7)
    x = square_wave(t, 80 / 127, 1.6)
    front = np.array([1.0, 1.0, 0.0, 0.0])
    air = simulate_counts(omnibot, "upside_down", t, (front[None, :] * x[:, None])[None])[0].T
    U = np.stack([front[None, :] * x[:, None], np.asarray(DIRECTIONS["sideways"], float)[None, :] * x[:, None]])
    floor, sideways = (c.T for c in simulate_counts(omnibot, "ground", t, U))
    no_where = PLAIN_MAP.replace('where = "air"\n', "").replace("counts_per_rev = 980",
                                                                  "counts_per_rev = 980\nsigns = [1, 1, 1, 1]")
    files = []
    for name, c in (("front_a", air), ("front_b", floor)):
        rows = ["t,u1,u2,u3,u4,enc1,enc2,enc3,enc4"]
        for k in range(t.size):
            rows.append(",".join([_num(t[k])] + [_num(v) for v in front * x[k]] + [str(int(v)) for v in c[k]]))
        (tmp_path / f"{name}.csv").write_text("\n".join(rows) + "\n")
        files.append(tmp_path / f"{name}.csv")
    a, b = _cli_import(capsys, tmp_path, files, no_where)
    assert a.metadata["conditions"]["where"]["value"] == "air" and a.metadata["mode"] == "upside_down"
    assert b.metadata["conditions"]["where"]["value"] == "floor" and b.metadata["mode"] == "ground"
    assert "floor kinematics" in b.metadata["conditions"]["where"]["source"]
    # one drive value, each wheel its sign in the direction's kinematics
    rows = ["ms;drive;fl;fr;rl;rr"] + [";".join([str(int(round(1000 * t[k]))), _num(x[k], ",")]
                                                 + [str(int(v)) for v in sideways[k]]) for k in range(t.size)]
    (tmp_path / "floor_drive.csv").write_text("\n".join(rows) + "\n")
    drive_map = """
[run]
procedure = "step_response"
counts_per_rev = 980
signs = [1, 1, 1, 1]
[columns]
time = { column = "ms", unit = "ms" }
duty = { column = "drive", unit = "1", pattern = "direction" }
encoder = { columns = ["fl", "fr", "rl", "rr"], unit = "counts" }
"""
    (run,) = _cli_import(capsys, tmp_path, [tmp_path / "floor_drive.csv"], drive_map)
    assert run.metadata["direction"] == "sideways" and run.metadata["mode"] == "ground"
    assert run.metadata["conditions"]["direction"]["source"].startswith("inferred from the data")
    np.testing.assert_allclose(run.samples["u1"], -run.samples["u2"])
    err = _refused(capsys, tmp_path, tmp_path / "floor_drive.csv",
                   drive_map.replace("signs = [1, 1, 1, 1]", 'signs = [1, 1, 1, 1]\ndirection = "forward"'))
    assert "sideways" in err


def test_signs_are_read_off_the_data(logs, tmp_path, capsys):
    _, d = logs
    t, x, counts = d["big"]
    (run,) = _cli_import(capsys, tmp_path, [write_plain(tmp_path / "raw.csv", t, x, counts * [1, -1, 1, -1])],
                         PLAIN_MAP)
    assert run.metadata["sign_map"] == [1, -1, 1, -1]
    np.testing.assert_array_equal(run.samples["enc2"], counts[:, 1])


def test_every_shipped_map_loads():
    names = shipped_maps()
    assert {"omnibench-samples", "tfm-square-serial", "example"} <= set(names)
    for n in names:
        from omnibench.runs.csv_import import shipped_map

        assert load_map(shipped_map(n)).quantities["time"]


@pytest.mark.skipif(not DATA.is_dir(), reason="2019 TFM data not available")
@pytest.mark.parametrize("name", ["square_fast", "square_small"])
def test_the_2019_serial_capture_imports_as_its_mat_file(name, tmp_path, capsys):
    """square.ino printed `command millis 0 enc1..4`, tab-separated; the same samples as the .mat
    file give the run `import tfm` gives."""
    import scipy.io

    from omnibench.runs.tfm import import_tfm

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = scipy.io.loadmat(str(DATA / f"{name}.mat"))["data"].astype(np.int64)
    f = tmp_path / f"{name}.txt"
    f.write_text("".join("\t".join(str(v) for v in data[:, k]) + "\n" for k in range(data.shape[1])))
    code, out, err = omnibench(capsys, "import", "csv", f, "--map", "tfm-square-serial", "--out", tmp_path / "csv",
                               "--json")
    assert code == 0, err
    run = read_run(json.loads(out)[0]["run"])
    tfm = read_run(import_tfm(DATA / f"{name}.mat", tmp_path / "tfm"))
    assert_same_run(run, tfm)
    assert run.metadata["firmware_timing"] == {**tfm.metadata["firmware_timing"], "source": "stated in the map"}
    assert "the data agree" in run.metadata["conditions"]["duty_timing"]["evidence"]


def test_omnibench_samples_of_a_simulated_board_run(tmp_path, capsys):
    """A run's own samples.csv through the shipped map: the same samples; the board's duty timing
    (each duty reported for the interval before its sample) is what the data show."""
    code, out, err = omnibench(capsys, "-q", "sweep", "--port", "sim://", "--out", tmp_path / "board")
    assert code == 0, err
    (board_dir,) = [p.parent for p in (tmp_path / "board").glob("*/run.json")]
    code, out, err = omnibench(capsys, "import", "csv", board_dir / "samples.csv", "--map", "omnibench-samples",
                               "--procedure", "step_response", "--where", "air", "--robot", board_dir / "robot.toml",
                               "--out", tmp_path / "csv", "--json")
    assert code == 0, err
    run, board = read_run(json.loads(out)[0]["run"]), read_run(board_dir)
    cols = ["t", "u1", "u2", "u3", "u4", "enc1", "enc2", "enc3", "enc4", "phi1", "phi2", "phi3", "phi4",
            "i1", "i2", "i3", "i4", "V_batt", "I_batt"]
    np.testing.assert_allclose(run.samples[cols].to_numpy(float), board.samples[cols].to_numpy(float), rtol=1e-12)
    cond = run.metadata["conditions"]
    assert run.metadata["duty_timing"] == "interval_before" and "the data agree" in cond["duty_timing"]["evidence"]
    assert cond["supply_voltage"]["source"].startswith("read off the data")
    assert cond["where"]["source"] == "given with --where"


def _doc_block(text: str, marker: str) -> str:
    after = text.split(f"<!-- {marker} -->", 1)[1]
    return after.split("```", 2)[1].split("\n", 1)[1]


def test_the_example_in_the_run_format_docs_imports_as_it_says(tmp_path, capsys):
    doc = (Path(__file__).resolve().parents[2] / "docs" / "run-format.md").read_text()
    (tmp_path / "bench.csv").write_text(_doc_block(doc, "csv-example-log"))
    (tmp_path / "bench.toml").write_text(_doc_block(doc, "csv-example-map"))
    code, out, err = omnibench(capsys, "import", "csv", tmp_path / "bench.csv", "--map", tmp_path / "bench.toml",
                               "--out", tmp_path / "runs")
    assert code == 0, err
    assert "signs: [1, -1, 1, -1] (inferred from the data" in out and "duty_timing: unknown" in out
    (run_dir,) = [p.parent for p in (tmp_path / "runs").glob("*/run.json")]
    run = read_run(run_dir)
    lay = run.metadata["csv_layout"]
    assert (lay["separator"]["value"], lay["decimal"]["value"], lay["units_row"]["value"]) == (";", ",", True)
    assert run.metadata["conditions"]["firmware_timing"]["value"] == "unknown"
    assert run.metadata["supply_voltage"] == pytest.approx(12.04)
    np.testing.assert_allclose(run.samples["u1"].iloc[1], 180 / 255)
    np.testing.assert_allclose(run.samples["phi2"].iloc[2], 34 * 2 * math.pi / 1024)
    np.testing.assert_allclose(run.samples["t"].iloc[-1], 0.187)
