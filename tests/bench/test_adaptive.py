"""`campaign --adaptive` on the simulated robot through the serial code path (issue 15)."""

from __future__ import annotations

import json
import re
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
    from omnibench.campaign.adaptive import _block_prediction, defer_unmeasured
    from omnibench.campaign.run import procedure_files
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

    from omnibench.campaign.adaptive import _calibrated

    design = SimpleNamespace(se_before={"a": 1.0, "b": 1.0, "c": 3.0}, refused={})
    targets = {"a": (0.02, True), "b": (0.02, True), "c": (0.02, True)}
    fitted = {"a": 2.0, "b": 0.5, "c": 2.0}  # a: unmet by the fit, met by the plan's information
    replanned, aims = _calibrated(design, targets, fitted, {"a": 1.5, "b": 1.5, "c": 1.5}, lambda t: ("again", t))
    assert aims == {"a": (0.01, True), "b": (0.02, True), "c": (0.02, True)} and replanned == ("again", aims)
    same, aims = _calibrated(design, targets, {"a": 1.0, "b": 0.5, "c": 2.0}, {"a": 1.5, "b": 1.5, "c": 1.5},
                             lambda t: ("again", t))
    assert same is design and aims == targets


def test_the_forward_floor_pair_runs_first_where_the_robot_starts(tmp_path):
    """The robot starts on the ground: round 1 runs the diagnostic floor's forward pair there, then
    flips for the sweep's floor, so the first fit measures C_r (and the ground noise) together with
    a, b, c and the sweep is topped up for C_r at its measured value, not at the robot file's."""
    import math

    from omnibench.analysis.observations import Observations
    from omnibench.analysis.simcampaign import simulated_observations
    from omnibench.campaign.adaptive import adaptive_loop
    from omnibench.campaign.run import procedure_files
    from omnibench.model import default_robot

    robot = default_robot()
    truth = robot.replace(a=0.02, b=0.45, c=0.015, C_r=0.03)
    table = {"upside_down_sweep": "sweep", "forward_runs": "forward", "lateral_runs": "lateral"}
    seen: list[list[str]] = []

    def execute(written, r):
        seen.append([proc for proc, _ in written])
        return Observations.concat([
            simulated_observations(truth, procedures=[table[p]], files={table[p]: path}, seed=10 * r + n,
                                   run_prefix=f"r{r}-{n}") for n, (p, path) in enumerate(written)])

    res = adaptive_loop(robot, {"a": (0.01, True), "C_r": (0.01, True)}, procedure_files(None), execute, tmp_path,
                        max_rounds=1)
    assert seen[0][0] == "forward_runs" and "upside_down_sweep" in seen[0][1:]
    # one flip to the sweep and one back to the rest state (no flip before the forward pair)
    assert res.rounds[0].actions["flip"] == 2 and res.rounds[0].actions["measure"] == 2
    assert math.isfinite(res.fit.se["C_r"]) and abs(res.fit.values["C_r"] - 0.03) < 5 * res.fit.se["C_r"]


def test_the_lateral_runs_first_visit_is_the_plan_for_half_the_information():
    """Until the lateral runs have data, the roller terms are planned at the robot file's values: the
    first lateral block is the plan for every target at sqrt(2) x its value, in the current pose
    only (a single pair would not separate a_r from b_r); the rest is planned from its fit."""
    import math
    from types import SimpleNamespace

    from omnibench.analysis.design.planner import Unit
    from omnibench.analysis.design.space import Candidate
    from omnibench.campaign.adaptive import half_information_pilot
    from omnibench.errors import UserError
    from omnibench.procedures import World

    ground, loaded = World("ground", "standard", None, 0.0), World("ground", "standard", None, 4.0)
    up = World("upside_down", "standard", (0.9,) * 4, 0.0)
    lat = Candidate("lateral", ground, heading=0.5, speed=0.3, duration=3.0, robot_seconds=8.0, measurements=2)
    lat4 = Candidate("lateral", loaded, heading=0.5, speed=0.2, duration=3.0, robot_seconds=8.0, measurements=2)
    sweep = Candidate("sweep", up, duty=0.1, robot_seconds=1.1)
    asked = []

    def replan(t):
        asked.append(t)
        return SimpleNamespace(units=[Unit(lat, 1, 0), Unit(lat4, 1, 1), Unit(sweep, 2, 2)])

    block = [Unit(lat, 2, 0), Unit(lat4, 2, 1)]
    out = half_information_pilot(block, replan, {"a_r": (0.01, True), "b": (0.002, False)})
    assert asked == [{"a_r": (pytest.approx(0.01 * math.sqrt(2)), True), "b": (pytest.approx(0.002 * math.sqrt(2)), False)}]
    assert [(u.candidate, u.reps) for u in out] == [(lat, 1), (lat4, 1)]  # this pose only, half the pairs
    # a half plan without lateral runs, or no plan at all, leaves the block as it was
    assert half_information_pilot(block, lambda t: SimpleNamespace(units=[Unit(sweep, 1, 0)]), {"a": (0.1, True)}) == block

    def refuse(t):
        raise UserError("no step fits the budget")

    assert half_information_pilot(block, refuse, {"a": (0.1, True)}) == block


def test_the_lateral_pilot_is_chosen_over_the_prior_points_not_at_the_robot_files_guess(monkeypatch):
    """The pilot is planned at each prior point of the unmeasured roller terms; the one with the least
    cost x expected repetitions over all points runs, not the one planned at the file's guess."""
    from types import SimpleNamespace

    import omnibench.analysis.design.robust as robust
    from omnibench.analysis.design.planner import Unit
    from omnibench.analysis.design.space import Candidate
    from omnibench.campaign.adaptive import pilot_over_prior
    from omnibench.model import default_robot
    from omnibench.procedures import World

    ground = World("ground", "standard", None, 0.0)
    cheap = Candidate("lateral", ground, heading=1.5708, speed=0.3, duration=1.5, robot_seconds=5.0, measurements=2)
    good = Candidate("lateral", ground, heading=0.5236, speed=0.3, duration=3.0, robot_seconds=8.0, measurements=2)
    res = SimpleNamespace(robot=default_robot())
    monkeypatch.setattr(robust, "at_point", lambda r, pt: SimpleNamespace(robot=r.robot.replace(**pt)))
    asked = []

    def replan_at(r, t):  # the file's guess (a_r 2.0) plans the cheap pair, any other point the good one
        asked.append(r.robot.a_r)
        return SimpleNamespace(units=[Unit(cheap if r.robot.a_r == 2.0 else good, 1, 0)])

    repeats = {cheap: 3.0, good: 1.0}  # the cheap pair would have to run 3 x over the prior, the good one once
    monkeypatch.setattr(robust, "expected_repeats_of",
                        lambda r, o, designs, *a, **k: [repeats[d[0].candidate] for d in designs])
    cost = lambda b: sum(u.candidate.robot_seconds * u.reps for u in b)  # noqa: E731
    out = pilot_over_prior([Unit(good, 2, 0)], res, None, {"a_r": (0.01, True)}, ["a_r"], replan_at, cost)
    assert sorted(asked) == [1.0, 2.0, 4.0]  # the file's value, times and divided by 2
    assert [(u.candidate, u.reps) for u in out] == [(good, 1)]  # 8 s x 1 < 5 s x 3
    repeats[cheap] = 1.5  # 7.5 < 8: now the cheap one is worth it
    assert [(u.candidate, u.reps) for u in pilot_over_prior([Unit(good, 2, 0)], res, None, {"a_r": (0.01, True)},
                                                            ["a_r"], replan_at, cost)] == [(cheap, 1)]


def test_expected_repetitions_halve_when_a_lateral_design_is_doubled():
    """With no data on the roller terms their information is the design's alone: twice the pairs,
    half the (SE / target)^2 at every prior point (to the weak prior's share)."""
    import math

    from omnibench.analysis.design.files import space_from_files
    from omnibench.analysis.design.planner import Unit
    from omnibench.analysis.design.robust import expected_repeats, expected_repeats_of, prior_points
    from omnibench.analysis.fitting import fit
    from omnibench.analysis.simcampaign import simulated_observations
    from omnibench.campaign.run import procedure_files
    from omnibench.model import default_robot

    robot = default_robot()
    files = procedure_files(None)
    space = space_from_files(robot, files)
    obs = simulated_observations(robot, seed=3, procedures=["sweep", "forward"])  # a, b, c measured, as when the lateral pilot is planned
    res = fit(robot, obs)
    lat = [c for c in space.candidates if c.procedure == "lateral" and c.duration == 1.5 and abs(c.speed - 0.3) < 1e-9]
    pick = lambda h, p: next(c for c in lat if round(math.degrees(c.heading)) == h and c.world.payload == p)  # noqa: E731
    design = [pick(90, 0.0), pick(30, 0.0), pick(30, 4.0)]
    roller = ["a_r", "b_r", "c_r"]
    points = prior_points(res.robot, roller)
    assert len(points) == 7 and points[0]["a_r"] == res.robot.a_r and {pt["c_r"] for pt in points} == {
        res.robot.c_r, 2 * res.robot.c_r, res.robot.c_r / 2}
    targets = {p: (0.005, True) for p in roller}
    once = expected_repeats(res, obs, [Unit(c, 1, 0) for c in design], targets, roller, points)
    twice = expected_repeats(res, obs, [Unit(c, 2, 0) for c in design], targets, roller, points)
    assert math.isfinite(once) and once > 1.0
    assert twice == pytest.approx(once / 2, rel=0.03)
    # judged together (each candidate's information computed once per point), each design as alone
    other = [Unit(pick(60, 0.0), 1, 0), Unit(pick(90, 4.0), 2, 0), Unit(pick(30, 4.0), 1, 0)]
    alone = expected_repeats(res, obs, other, targets, roller, points)
    together = expected_repeats_of(res, obs, [[Unit(c, 1, 0) for c in design], other], targets, roller, points)
    assert together == pytest.approx([once, alone], rel=1e-9)
    assert alone != pytest.approx(once, rel=0.01)


@pytest.mark.slow
def test_a_model_that_misses_something_on_the_floor_gets_the_lab_grid_not_a_plan(tmp_path):
    """On a world with an undeclared driver deadband the diagnostic floor's fit flags the misfit
    (chi^2/dof, residual structure); planning from the declared model's information would pile
    up levels to chase targets it cannot meet (the budget, 377 s, and data diagnose then misread),
    so the rest of the lab's own grid runs, once, and the campaign stops saying why. On a clean
    world the floor's fit flags nothing."""
    from omnibench.analysis.design.files import fixed_grid_units
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.simcampaign import simulated_observations
    from omnibench.campaign.adaptive import adaptive_loop
    from omnibench.campaign.run import procedure_files
    from omnibench.effects import EFFECTS
    from omnibench.model import default_robot

    robot = default_robot()
    truth = robot.replace(a=0.02, b=0.45, c=0.015, a_r=2.5, b_r=0.8, c_r=0.02, C_r=0.03)
    table = {"upside_down_sweep": "sweep", "forward_runs": "forward", "lateral_runs": "lateral"}
    files = procedure_files(None)
    fits = {}

    def run(world, folder, max_rounds):
        def execute(written, r):
            return Observations.concat([
                simulated_observations(truth, world_effects=world, procedures=[table[p]], files={table[p]: path},
                                       seed=100 * r + n, run_prefix=f"r{r}-{n}") for n, (p, path) in enumerate(written)])
        return adaptive_loop(robot, {"a": (0.001, True), "C_r": (0.001, True)}, files, execute, folder,
                             max_rounds=max_rounds, log=lambda kind, rec: fits.setdefault(kind, []).append(rec))

    res = run(EFFECTS["driver_deadband"].world(), tmp_path / "deadband", 10)
    assert not res.met and res.stop_reason.startswith("the declared model misses something")
    # judged against the stated noise group by group (the overall chi^2/dof is ~1 once the large
    # groups are weighted by their own noise)
    assert "sweep/current: chi2/dof" in res.stop_reason and "against its stated noise" in res.stop_reason
    assert len(res.rounds) == 2 and fits["design_misfit"][0]["round"] == 2
    grid = fixed_grid_units(robot, files)
    ran: dict = {}

    def step(label):  # a sweep level is the same step at either averaging time (the floor's is longer)
        return re.sub(r" over [0-9.]+ s,", ",", label)

    for rd in res.rounds:
        for label in rd.ran:
            name, reps = label.rsplit(" x", 1)
            ran[step(name)] = ran.get(step(name), 0) + int(reps)
    assert all(ran.get(step(u.candidate.label), 0) >= u.reps for u in grid)  # every step of the lab's grid ran
    assert sum(ran.values()) == sum(u.reps for u in grid)  # and nothing more (the floor is part of it)
    clean = run({}, tmp_path / "clean", 1)
    assert clean.fit is not None and clean.fit.misses_something() == []


def test_a_previous_campaign_plans_the_whole_upside_down_part_in_round_one(tmp_path):
    """With the fit of the robot's previous campaign (`--prior-runs`) the noise and values are known:
    round 1 runs the floor's forward pair and the plan's whole upside-down part (the sweep topped up
    at once), where without it round 1 is the diagnostic floor alone (a pilot that measures the noise)."""
    from omnibench.analysis.fitting import fit
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.simcampaign import simulated_observations
    from omnibench.campaign.adaptive import adaptive_loop
    from omnibench.campaign.run import procedure_files
    from omnibench.model import default_robot

    robot = default_robot()
    truth = robot.replace(a=0.02, b=0.45, c=0.015, C_r=0.03)
    table = {"upside_down_sweep": "sweep", "forward_runs": "forward", "lateral_runs": "lateral"}
    previous = fit(robot, simulated_observations(truth, seed=7, procedures=["sweep", "forward", "lateral"]))
    targets = {"a": (0.002, True), "c": (0.003, True)}

    def sweep_pairs(prior) -> int:
        def execute(written, r):
            return Observations.concat([
                simulated_observations(truth, procedures=[table[p]], files={table[p]: path}, seed=10 * r + n,
                                       run_prefix=f"r{r}-{n}") for n, (p, path) in enumerate(written)])

        res = adaptive_loop(robot, targets, procedure_files(None), execute, tmp_path / str(prior is not None),
                            max_rounds=1, prior=prior)
        assert res.rounds[0].ran[0].startswith("forward/backward")  # the floor's forward pair first
        return sum(int(x.rsplit(" x", 1)[1]) for x in res.rounds[0].ran if x.startswith("sweep"))

    floor_only = sweep_pairs(None)
    assert floor_only == 8  # the lab's usable levels on the standard set and one on the weighted set
    assert sweep_pairs(previous) > floor_only


def test_prior_runs_without_adaptive_is_refused_in_one_line(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["campaign", "--port", "sim://", "--out", str(tmp_path / "x"), "--prior-runs", str(tmp_path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "--prior-runs needs --adaptive" in err and "\n" not in err


@pytest.mark.slow
def test_an_adaptive_campaign_from_a_previous_one_over_the_serial_path_says_so(capsys, tmp_path):
    procs = str(Path(__file__).parent / "procedures" / "campaign")
    main(["campaign", "--port", "sim://?seed=4", "--out", str(tmp_path / "before"), "--procedures", procs,
          "--analysis", "none", "--json"])
    capsys.readouterr()
    out = tmp_path / "after"
    main(["campaign", "--adaptive", "--port", "sim://?seed=5", "--out", str(out), "--target-se", "a=3%,b=2%",
          "--procedures", procs, "--analysis", "none", "--prior-runs", str(tmp_path / "before" / "runs"), "--json"])
    res = json.loads(capsys.readouterr().out)
    assert res["design"]["met"] and res["design"]["prior_runs"] == [str(tmp_path / "before" / "runs")]
    log = [json.loads(x) for x in (out / "design.jsonl").read_text().splitlines()]
    assert "previous campaign" in log[0]["why"]
    assert "planned from the previous campaign's values and noise" in (out / "report.md").read_text()


def test_the_labs_grid_after_the_floor_leaves_out_the_levels_the_floor_ran_at_its_longer_average():
    """When the model misses something the campaign runs the rest of the lab's grid; the diagnostic
    floor held its sweep levels at twice the file's averaging time, and those levels are not run
    again at the file's (the same duty, wheel set and direction pair)."""
    from omnibench.analysis.design.files import diagnostic_floor, fixed_grid_units, space_from_files
    from omnibench.campaign.adaptive import rest_of_lab_grid
    from omnibench.campaign.run import procedure_files
    from omnibench.model import default_robot

    robot = default_robot()
    files = procedure_files(None)
    space = space_from_files(robot, files)
    floor = diagnostic_floor(robot, files, space)
    grid = fixed_grid_units(robot, files)
    sweeps = [c for c in floor if c.procedure == "sweep"]
    assert sweeps and all(c.duration == pytest.approx(0.6) for c in sweeps)
    assert all(u.candidate.duration == pytest.approx(0.3) for u in grid if u.candidate.procedure == "sweep")
    left = rest_of_lab_grid(grid, {c: 1 for c in floor}, None)
    ran = {(c.world, c.duty) for c in sweeps}
    left_sweeps = {(u.candidate.world, u.candidate.duty) for u in left if u.candidate.procedure == "sweep"}
    grid_sweeps = {(u.candidate.world, u.candidate.duty) for u in grid if u.candidate.procedure == "sweep"}
    assert left_sweeps == grid_sweeps - ran and left_sweeps  # the other wheel set's levels remain
    assert sum(u.reps for u in left) == sum(u.reps for u in grid) - len(floor)
