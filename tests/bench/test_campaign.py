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
    res = json.loads(capsys.readouterr().out)
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
