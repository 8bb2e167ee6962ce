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


def test_the_current_pose_buys_only_what_the_measured_targets_need():
    """After a sweep, a target on C_r (no ground run yet: its value and sensitivities are the robot
    file's guesses) does not buy sweep levels: the sweep steps are re-planned for `a` alone, with the
    later ground steps counted as information to come, and still meet a's target."""
    import math

    from omnibench.analysis.design.files import space_from_files
    from omnibench.analysis.design.planner import plan
    from omnibench.analysis.design.space import Costs, Space
    from omnibench.analysis.fitting import fit
    from omnibench.analysis.simcampaign import simulated_observations
    from omnibench.bench.adaptive import _block_prediction, defer_unmeasured
    from omnibench.bench.campaign import procedure_files
    from omnibench.model import default_robot

    robot = default_robot()
    sp = space_from_files(robot, procedure_files(None))
    sp = Space([c for c in sp.candidates if c.procedure == "sweep" or (c.procedure == "forward" and c.duration == 1.5)],
               sp.sweep_rest)
    obs = simulated_observations(robot.replace(a=0.02, b=0.45, c=0.015, C_r=0.03), procedures=["sweep"], seed=3)
    res = fit(robot, obs)
    targets = {"a": (0.7 * res.se["a"] / res.values["a"], True), "C_r": (0.005, True)}
    design = plan(robot, res, targets, sp, obs=obs)
    se = {p: res.se.get(p, math.inf) for p in targets}
    units, deferred = defer_unmeasured(design.units, robot, res, targets, {}, se, sp, Costs(), current=True,
                                       start=None, floor=[], have={"sweep"}, obs=obs, budget_seconds=math.inf,
                                       budget_actions=math.inf)
    assert deferred == ["C_r"]

    def pairs(us, proc):
        return sum(u.reps for u in us if u.candidate.procedure == proc)

    assert 0 < pairs(units, "sweep") < pairs(design.units, "sweep")  # the C_r guess no longer buys sweep levels
    assert [(u.candidate, u.reps) for u in units if u.candidate.procedure != "sweep"] == [
        (u.candidate, u.reps) for u in design.units if u.candidate.procedure != "sweep"]
    # what runs now plus what is to come still meets a's target (at the plan's margin)
    assert _block_prediction(robot, res, obs, True, units)["a"] <= targets["a"][0] * res.values["a"]


def test_a_target_the_plan_thinks_met_and_the_fit_does_not_is_aimed_lower():
    """The plan's SE of the data in hand (information) can be below the fit's (its inflation): the
    loop then re-plans with that target divided by their ratio, so the plan adds steps instead of
    nothing; a target the fit meets, or the plan already sees unmet, is left as asked."""
    from types import SimpleNamespace

    from omnibench.bench.adaptive import _calibrated

    design = SimpleNamespace(se_before={"a": 1.0, "b": 1.0, "c": 3.0}, refused={})
    targets = {"a": (0.02, True), "b": (0.02, True), "c": (0.02, True)}
    fitted = {"a": 2.0, "b": 0.5, "c": 2.0}  # a: unmet by the fit, met by the plan's information
    replanned, aims = _calibrated(design, targets, fitted, {"a": 1.5, "b": 1.5, "c": 1.5}, lambda t: ("again", t))
    assert aims == {"a": (0.01, True), "b": (0.02, True), "c": (0.02, True)} and replanned == ("again", aims)
    same, aims = _calibrated(design, targets, {"a": 1.0, "b": 0.5, "c": 2.0}, {"a": 1.5, "b": 1.5, "c": 1.5},
                             lambda t: ("again", t))
    assert same is design and aims == targets
