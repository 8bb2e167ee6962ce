"""`omnibench diagnose` on the real 2019 logs, and its one-line errors on bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from omnibench.cli import main

REPO = Path(__file__).resolve().parents[2]
MODEL = REPO / "omnibench" / "model" / "omnibot.toml"


def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    try:
        main(argv)
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def tfm_runs(tmp_path_factory, tfm_data) -> Path:
    from omnibench.runs.tfm import import_tfm

    out = tmp_path_factory.mktemp("tfm_runs")
    import_tfm(tfm_data / "results_jacked.mat", out)
    import_tfm(tfm_data / "square_fast.mat", out)
    return out


def test_diagnose_real_2019_sweep_reports_before_after_and_writes_outputs(tfm_runs, tmp_path, capsys):
    ext = tmp_path / "extended.toml"
    plots = tmp_path / "plots"
    # three candidates keep this a test of the command's outputs (66 s CPU with the whole library,
    # 47 s of it round 2's pair fits); the full diagnosis of the 2019 logs is test_real_data.py's
    # and benchmarks/real_data.py's
    code, out, err = _run(["diagnose", "--model", str(MODEL), str(tfm_runs), "--procedures", "sweep",
                           "--candidates", "per_wheel_friction,quadratic_drag,asymmetric_coulomb",
                           "--out", str(ext), "--plots", str(plots), "--json"], capsys)
    assert code == 0, err
    js = json.loads(out)
    for key in ("selected", "rejected", "ambiguous", "unexplained", "before", "after"):
        assert key in js
    assert set(js["before"]) == {"sweep"} and js["before"]["sweep"]["nrmse"] > 0
    assert js["after"]["sweep"]["nrmse"] <= js["before"]["sweep"]["nrmse"] * 1.0001
    # the real wheels differ from each other: the residual's structure is located by wheel
    assert any(u["variable"].startswith("wheel") for u in js["unexplained"]) or js["selected"]
    assert {r["effect"] for r in js["rejected"]} | {s["effect"] for s in js["selected"]} == {
        "per_wheel_friction", "quadratic_drag", "asymmetric_coulomb"}  # only the candidates asked for
    # the extended model loads back as a robot file
    from omnibench.model import load_robot

    robot = load_robot(ext)
    assert set(robot.effects) == {s["effect"] for s in js["selected"]}
    assert sorted(p.name for p in plots.glob("*.png")) and (plots / "diagnose_heldout_error.png").exists()
    assert "diagnose:" in err  # progress on stderr, JSON alone on stdout


@pytest.mark.parametrize("argv, words", [
    (["--model", "nope.toml", "RUNS"], "robot file not found"),
    (["--model", str(MODEL), "no/such/run"], "no such run directory"),
    (["--model", str(MODEL), "RUNS", "--alpha", "2"], "--alpha"),
    (["--model", str(MODEL), "RUNS", "--candidates", "stribeck,quadratic_drag"], "unknown effect"),
    (["--model", str(MODEL), "RUNS", "--procedures", "sweeep"], "--procedures"),
])
def test_bad_input_is_one_line_and_nonzero(argv, words, tfm_runs, capsys):
    argv = [str(tfm_runs) if a == "RUNS" else a for a in argv]
    code, out, err = _run(["diagnose", *argv], capsys)
    assert code != 0
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and words in lines[0], err
    assert "Traceback" not in err
