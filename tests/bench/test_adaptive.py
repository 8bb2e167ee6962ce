"""`campaign --adaptive` on the simulated robot through the serial code path (issue 15)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from omnibench.cli import main
from omnibench.runs import read_run


def _events(run_dir: str) -> list[dict]:
    return [json.loads(line) for line in (Path(run_dir) / "events.jsonl").read_text().splitlines() if line.strip()]


@pytest.mark.slow
def test_adaptive_campaign_runs_planned_files_until_the_targets_are_met(capsys, tmp_path):
    out = tmp_path / "adaptive"
    try:
        # sweep-only targets, loose: met after the first round (the diagnostic floor of the sweep)
        main(["campaign", "--adaptive", "--port", "sim://?seed=4", "--out", str(out), "--target-se", "a=3%,b=2%",
              "--procedures", str(Path(__file__).parent / "procedures" / "campaign"),
              "--analysis", "none", "--json"])
    except SystemExit as exc:  # pragma: no cover - only on failure
        raise AssertionError(capsys.readouterr().err) from exc
    res = json.loads(capsys.readouterr().out)
    d = res["design"]
    assert d["met"] and d["stop_reason"] == "every target met"
    assert d["final_se"]["a"] <= d["targets"]["a"] and d["final_se"]["b"] <= d["targets"]["b"]
    # every run the design made is complete, ran a planned file unchanged and carries the decision
    planned = [r for r in res["runs"]]
    assert planned
    for run_dir in planned:
        run = read_run(run_dir)
        assert run.status == "complete"
        assert "/design/round-" in run.metadata["procedure_file"]
        ev = [e for e in _events(run_dir) if e["kind"] == "design"]
        assert ev and ev[0]["round"] >= 1 and ev[0]["runs_now"]
    log = [json.loads(x) for x in (out / "design.jsonl").read_text().splitlines()]
    assert [x["kind"] for x in log][-1] == "design_end"
    report = (out / "report.md").read_text()
    assert "## Adaptive design" in report and "ratio adaptive / fixed" in report
    assert (out / "plots" / "design_se_vs_time.png").stat().st_size > 1000


def test_target_se_without_adaptive_is_refused(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["campaign", "--port", "sim://", "--out", str(tmp_path / "x"), "--target-se", "a=2%"])
    assert exc.value.code == 2
    assert "needs --adaptive" in capsys.readouterr().err


def test_plan_bad_target_is_one_line(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["plan", "--target-se", "a=lots", "--out", str(tmp_path / "p")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("omnibench: error: --target-se") and "\n" not in err
