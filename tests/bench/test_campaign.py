"""The campaign on the simulated robot: four procedures, the analysis stages that exist, one report."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from omnibench.cli import main
from omnibench.runs import read_run

HERE = Path(__file__).parent


@pytest.mark.slow
def test_campaign_on_sim_writes_report(capsys, tmp_path):
    out = tmp_path / "campaign"
    try:
        # diagnose (slow, and tested by its own suite) is left out here; fit and validate-energy run
        # when installed
        main(["campaign", "--port", "sim://?seed=8", "--out", str(out), "--procedures",
              str(HERE / "procedures" / "campaign"), "--analysis", "fit,validate-energy", "--json"])
    except SystemExit as exc:  # pragma: no cover - only on failure
        raise AssertionError(capsys.readouterr().err) from exc
    captured = capsys.readouterr()
    res = json.loads(captured.out)
    # the terminal summary: fitted values with SE, the energy error, both reports
    assert "== summary" in captured.err and "the model (declared fit; value ± SE, 95 % interval, verdict):" in captured.err
    report_head = (out / "report.md").read_text().split("## The campaign")[0]
    assert "## The answer" in report_head and "| R_a |" in report_head  # the report opens with the answer
    assert "energy: predicted vs measured, mean |error|" in captured.err and "report.html" in captured.err
    assert set(res["procedures"]) == {"upside_down_sweep", "forward_runs", "lateral_runs", "energy_trajectories"}
    for p in res["procedures"].values():
        assert read_run(p["run"]).status == "complete"
    report = (out / "report.md").read_text()
    for title in ("III.i", "III.ii", "III.iii", "IV", "## Analysis"):
        assert title in report
    # every analysis stage is accounted for: ran (ok/failed) or skipped with a reason
    for stage in ("fit", "validate-energy", "diagnose"):
        st = res["analysis"][stage]
        assert st["status"] in ("ok", "failed", "skipped")
        assert f"**{stage}: {st['status']}**" in report
    assert res["analysis"]["diagnose"] == {"status": "skipped", "why": "not asked for (--analysis)"}
    for plot in res["plots"].values():
        assert Path(plot).is_file() and Path(plot).stat().st_size > 1000
    assert (out / "campaign.json").is_file()
    assert "{'" not in report and "[{" not in report  # no raw Python structures
    assert "error by procedure (NRMSE): sweep " in report and " %" in report
    assert (out / "report.html").is_file()
    # the README's Python example, run as written on these runs
    _run_readme_python_example(out / "runs", capsys)


def _run_readme_python_example(runs: Path, capsys) -> None:
    readme = (HERE.parents[1] / "README.md").read_text()
    block = readme.split("```python\n", 1)[1].split("```", 1)[0]
    assert '"campaign/runs"' in block
    exec(compile(block.replace('"campaign/runs"', repr(str(runs))), "README.md", "exec"), {})
    table = capsys.readouterr().out
    rows = {line.split()[0]: line for line in table.splitlines() if line.strip()}
    for name in ("a", "b", "C_r", "a_r"):
        assert name in rows and rows[name].rstrip().endswith("identified"), table


def test_campaign_refuses_a_missing_procedure_file_before_moving(capsys, tmp_path):
    try:
        main(["campaign", "--port", "sim://", "--out", str(tmp_path / "c"), "--procedures", str(tmp_path)])
    except SystemExit as exc:
        assert exc.code == 2
    err = capsys.readouterr().err
    assert "no upside_down_sweep.toml" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "c").exists()


def test_campaign_rejects_unknown_stage(capsys, tmp_path):
    try:
        main(["campaign", "--port", "sim://", "--out", str(tmp_path / "c"), "--analysis", "fit,fortune"])
    except SystemExit as exc:
        assert exc.code == 2
    assert "unknown stage 'fortune'" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()


def _campaign(capsys, out, port, *extra):
    code = 0
    try:
        main(["campaign", "--port", port, "--out", str(out), "--procedures", str(HERE / "procedures" / "campaign"),
              "--analysis", "none", *extra])
    except SystemExit as exc:
        code = int(exc.code or 0)
    _, err = capsys.readouterr()
    return code, err


def test_interrupted_campaign_resumes_without_redoing_complete_runs_or_mixing_campaigns(capsys, tmp_path):
    """A motor-driver fault 10 s into each procedure's board time stops the campaign in the lateral
    runs (12 s; the sweep and forward runs end before 10 s). Running the campaign again into the
    same folder is refused (the analysis would mix two campaigns); --resume keeps the two complete
    runs untouched, resumes the lateral run where it stopped and runs the energy trajectories."""
    out = tmp_path / "c"
    code, err = _campaign(capsys, out, "sim://?seed=8&driver_fault_at=10")
    assert code == 3 and "DRIVER" in err.strip().splitlines()[-1]
    runs = {read_run(d).procedure: d for d in (out / "runs").iterdir()}
    assert set(runs) == {"upside_down_sweep", "forward_runs", "lateral_runs"}
    assert read_run(runs["lateral_runs"]).status == "failed"
    kept = {p: (runs[p] / "samples.csv").read_bytes() for p in ("upside_down_sweep", "forward_runs")}
    lateral_steps = len(read_run(runs["lateral_runs"]).steps)

    code, err = _campaign(capsys, out, "sim://?seed=8")
    assert code == 2 and "already holds runs" in err and len(err.strip().splitlines()) == 1
    assert len(list((out / "runs").iterdir())) == 3

    before = {d: (d / "run.json").read_bytes() for d in (out / "runs").iterdir()}
    code, err = _campaign(capsys, out, "sim://?seed=8&board_id=195887106", "--resume")  # another board
    assert code == 2 and "is not the board" in err and "board id 0B0B0001 -> 0BAD0002" in err, err
    assert {d: (d / "run.json").read_bytes() for d in (out / "runs").iterdir()} == before

    code, err = _campaign(capsys, out, "sim://?seed=8&name=later", "--resume")  # the same board, its name aside
    assert code == 0, err
    report = (out / "report.md").read_text()
    assert "port: `sim://?seed=8&driver_fault_at=10`" in report  # the resumed run keeps its own port
    after = {read_run(d).procedure: d for d in (out / "runs").iterdir()}
    assert set(after) == set(runs) | {"energy_trajectories"} and len(after) == 4
    for p, data in kept.items():
        assert after[p] == runs[p] and (runs[p] / "samples.csv").read_bytes() == data
    lateral = read_run(runs["lateral_runs"])
    assert lateral.status == "complete" and len(lateral.metadata["segments"]) == 2
    assert 0 < lateral_steps < len(lateral.steps) == lateral.metadata["steps_planned"]
    assert list(lateral.steps["step"]) == list(range(len(lateral.steps)))
    assert (out / "report.md").is_file()


@pytest.mark.slow
def test_deadband_campaign_answers_with_the_diagnosed_model(capsys, tmp_path):
    """The README's deadband world, in the short campaign: diagnose adds the deadband, and the
    summary and the report lead with the diagnosed model (R_a within 3 SE of the world's; the
    declared fit's R_a is far off), with the energy error of both models."""
    import tomllib

    from omnibench.campaign.answer import with_se
    from omnibench.model import default_robot, load_robot

    out = tmp_path / "campaign"
    try:
        main(["campaign", "--port", "sim://?seed=8&effects.driver_deadband.u_0=0.04", "--out", str(out),
              "--procedures", str(HERE / "procedures" / "campaign"), "--candidates", "driver_deadband,stribeck_friction",
              "--json"])
    except SystemExit as exc:  # pragma: no cover - only on failure
        raise AssertionError(capsys.readouterr().err) from exc
    captured = capsys.readouterr()
    res = json.loads(captured.out)
    diag = res["analysis"]["diagnose"]
    assert [s["effect"] for s in diag["result"]["selected"]] == ["driver_deadband"]
    world = default_robot().R_a
    ra = diag["result"]["extended_fit"]["R_a"]
    assert abs(ra["value"] - world) < 3 * ra["se"], ra
    before = res["analysis"]["fit"]["result"]["parameters"]["R_a"]
    assert abs(before["value"] - world) > 3 * before["se"]  # the declared fit is wrong: the answer must not be it
    # the diagnosed model file carries the SEs
    written = tomllib.loads((out / "model_diagnose.toml").read_text())
    assert written["fit"]["parameters"]["R_a"]["se"] == pytest.approx(ra["se"])
    assert load_robot(out / "model_diagnose.toml").R_a == pytest.approx(ra["value"])
    # energy validated on both models
    e_before = res["analysis"]["validate-energy"]["result"]["mean_abs_error_pct"]
    e_after = diag["validate_energy"]["result"]["mean_abs_error_pct"]
    assert e_after < e_before
    # the terminal summary leads with the diagnosed model
    summary = captured.err[captured.err.index("== summary"):]
    assert "the model (diagnosed: declared model + driver_deadband" in summary
    ra_line = next(line for line in summary.splitlines() if line.strip().startswith("R_a "))
    assert with_se(ra["value"], ra["se"]) in ra_line and f"before {with_se(before['value'], before['se'])}" in ra_line
    assert f"{e_before:.3g} % (declared fit) -> {e_after:.3g} % (diagnosed model)" in summary
    # and so does the report
    report = (out / "report.md").read_text()
    head = report[:report.index("## The campaign")]
    assert f"| R_a | {with_se(ra['value'], ra['se'])} |" in head
    assert "with the declared fit →" in head and "with the diagnosed model" in head
    assert "diagnose_heldout_error.png" in report
    for png in (out / "plots").rglob("*.png"):  # every plot the campaign drew is shown
        assert str(png.relative_to(out)) in report, png


def test_quiet_campaign_prints_only_the_report_path(capsys, tmp_path):
    out = tmp_path / "c"
    main(["-q", "campaign", "--port", "sim://?seed=8", "--out", str(out), "--procedures",
          str(HERE / "procedures" / "campaign"), "--analysis", "none"])
    captured = capsys.readouterr()
    assert captured.out == f"{out / 'report.md'}\n" and captured.err == ""
    assert (out / "report.md").is_file()


def test_a_failed_analysis_stage_keeps_the_runs_and_report_and_exits_4(capsys, tmp_path, monkeypatch):
    """The fit fails (here it is made to); the campaign still writes every run and its report,
    which names the failed stage, and exits 4 in one line, so that a script sees the answer is
    missing (it exited 0 before)."""
    from omnibench.campaign import stages
    from omnibench.errors import UserError

    def failing_fit(*args, **kwargs):
        raise UserError("no observations to fit (need sweep, forward or lateral runs)")

    monkeypatch.setattr(stages, "fit_runs", failing_fit)
    out = tmp_path / "c"
    code = 0
    try:
        main(["campaign", "--port", "sim://?seed=8", "--out", str(out), "--procedures",
              str(HERE / "procedures" / "campaign"), "--analysis", "fit"])
    except SystemExit as exc:
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    assert code == 4, err
    assert "analysis stage failed: fit" in err.strip().splitlines()[-1]
    assert "**fit: failed**" in (out / "report.md").read_text()
    assert {read_run(d).status for d in (out / "runs").iterdir()} == {"complete"}
    assert len(list((out / "runs").iterdir())) == 4
