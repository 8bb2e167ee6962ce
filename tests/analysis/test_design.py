"""The experiment-design planner (issue 15): predictions that come true, refusals, costs, limits."""

from __future__ import annotations

import pytest

from omnibench.analysis.design.files import space_from_files, write_procedures
from omnibench.analysis.design.information import candidate_information
from omnibench.analysis.design.planner import parse_targets, plan, planning_names
from omnibench.analysis.design.space import Costs, Limits, Space, build_space
from omnibench.analysis.fitting import fit
from omnibench.analysis.observations import Observations
from omnibench.analysis.simcampaign import simulated_observations
from omnibench.campaign.run import procedure_files
from omnibench.errors import UserError
from omnibench.model import default_robot
from omnibench.procedures import load_plan

STEADY = {"min_hold": 0.2, "window": 0.3, "average": 0.3}
TRUTH = dict(a=0.02, b=0.45, c=0.015)
LIMITS = Limits(max_duty=0.8)  # the shipped files' highest level, as space_from_files caps it


def _sweep_space(robot, wheel_sets=(("standard", (0.9,) * 4), ("weighted", (1.9,) * 4))) -> Space:
    sp = build_space(robot, wheel_sets=list(wheel_sets), payloads=[0.0], steady=STEADY, limits=LIMITS)
    return Space([c for c in sp.candidates if c.procedure == "sweep"], sp.sweep_rest)


def test_planned_se_is_the_se_the_fit_then_reports(tmp_path):
    """Plan from a first sweep, run the plan on the simulated robot, fit: the SE the plan
    predicted is the SE obtained (within 30 %: the fit's noise scale is itself estimated)."""
    robot = default_robot()
    truth = robot.replace(**TRUTH)
    files = procedure_files(None)
    obs = simulated_observations(truth, procedures=["sweep"], seed=3)  # the shipped sweep: both wheel sets
    res = fit(robot, obs)
    targets = {"a": (0.5 * res.se["a"] / res.values["a"], True), "c": (0.5 * res.se["c"] / res.values["c"], True)}
    design = plan(robot, res, targets, _sweep_space(robot), obs=obs)
    assert design.units and all(design.met.values())
    written = write_procedures(design.units, files, tmp_path / "next", robot)
    more = [simulated_observations(truth, procedures=["sweep"], files={"sweep": p}, seed=11 + n, run_prefix=f"next{n}")
            for n, (_, p) in enumerate(written)]
    after = fit(robot, Observations.concat([obs, *more]))
    for p in targets:
        assert after.se[p] == pytest.approx(design.se_after[p], rel=0.3), p
        assert after.se[p] < 0.6 * res.se[p]  # the plan did shrink it


def test_a_parameter_the_candidates_cannot_separate_is_refused_with_the_experiment_that_would():
    robot = default_robot()
    one_set = _sweep_space(robot, wheel_sets=(("standard", (0.9,) * 4),))
    # one wheel load: only a (1 + c F_N) and b (1 + c F_N) are seen
    design = plan(robot, None, {"a": (0.05, True), "c": (0.05, True), "k_e": (0.05, True)}, one_set)
    assert set(design.refused) == {"a", "c"}
    assert all("second wheel set" in why for why in design.refused.values())
    assert design.met["k_e"] and all(u.candidate.world.wheel_set == "standard" for u in design.units)
    # with a second wheel set the same targets are planned
    two = plan(robot, None, {"a": (0.05, True), "c": (0.05, True)}, _sweep_space(robot))
    assert not two.refused and all(two.met.values())
    assert {u.candidate.world.wheel_set for u in two.units} == {"standard", "weighted"}


def test_budgets_and_costs_are_respected():
    robot = default_robot()
    sp = space_from_files(robot, procedure_files(None))
    sp = Space([c for c in sp.candidates if c.procedure != "lateral" or c.duration == 1.5], sp.sweep_rest)
    targets = parse_targets("a=0.5%,b_r=0.5%,c_r=1%", robot)
    info = candidate_information(robot, sp.candidates, planning_names(robot))
    free = plan(robot, None, targets, sp, info=info)
    tight = plan(robot, None, targets, sp, budget_actions=8, budget_seconds=30, info=info)
    assert tight.operator_actions <= 8 and tight.robot_seconds <= 30 + 1e-9
    assert free.operator_actions > 8  # the budget did bind
    # a dearer tape measurement buys fewer of them
    dear = plan(robot, None, targets, sp, costs=Costs(actions={"flip": 60, "wheels": 180, "payload": 20,
                                                               "measure": 600}), info=info)
    assert dear.actions["measure"] <= free.actions["measure"]
    assert dear.cost == pytest.approx(Costs(actions={"flip": 60, "wheels": 180, "payload": 20, "measure": 600}).of(
        dear.robot_seconds, dear.actions))


def test_safety_limits_bound_every_candidate_and_every_written_file(tmp_path):
    robot = default_robot()
    sp = space_from_files(robot, procedure_files(None), Limits(floor_length=1.0, max_duty=0.5))
    assert sp.candidates
    for c in sp.candidates:
        peak = max(max(abs(x) for x in u) for u in c.duties(robot))
        assert peak <= 0.5 + 1e-12
        if c.procedure == "lateral":
            assert c.speed * c.duration <= 1.0
        if c.procedure == "forward":
            assert c.duty * robot.V_batt / robot.k_e * robot.r * c.duration <= 1.0
    sp = Space([c for c in sp.candidates if c.procedure != "lateral" or c.world.payload in (0, 4)], sp.sweep_rest)
    design = plan(robot, None, parse_targets("a=1%,C_r=5%,a_r=5%", robot), sp)
    for proc, path in write_procedures(design.units, procedure_files(None), tmp_path, robot):
        load_plan(path, robot, expect=proc)  # the runner's own checks (max_duty, stall current)


def test_lateral_speeds_stay_within_the_span_of_the_labs_file(tmp_path):
    """The planner's lateral runs go no faster and no slower than the lab's file: on the independent
    physics a plan's 0.2 m/s pair (the file's 0.3) put the roller terms 3-4 SE off on every noise
    draw (docs/design.md). A file that spans more speeds opens the menu's speeds in between."""
    robot = default_robot()
    files = dict(procedure_files(None))
    shipped = {c.speed for c in space_from_files(robot, files).candidates if c.procedure == "lateral"}
    assert shipped == {0.3}
    text = files["lateral_runs"].read_text(encoding="utf-8")
    assert text.count('speed = "0.3 m/s"') == 3
    text = text.replace('speed = "0.3 m/s"', 'speed = "0.2 m/s"', 1)
    head, _, tail = text.rpartition('speed = "0.3 m/s"')
    (tmp_path / "lateral.toml").write_text(head + 'speed = "0.45 m/s"' + tail, encoding="utf-8")
    files["lateral_runs"] = tmp_path / "lateral.toml"
    wide = {c.speed for c in space_from_files(robot, files).candidates if c.procedure == "lateral"}
    assert min(wide) == 0.2 and 0.3 in wide and max(wide) <= 0.45


def test_target_syntax_errors_are_one_line_user_errors():
    robot = default_robot()
    assert parse_targets("a=2%, b=0.01", robot) == {"a": (0.02, True), "b": (0.01, False)}
    for bad in ("a=two", "a=-1%", "zz=1%", ""):
        with pytest.raises(UserError):
            parse_targets(bad, robot)


def test_the_repetition_cap_counts_the_pairs_the_data_already_hold():
    """MAX_REPS bounds the pairs of one step over the whole campaign, not per plan: rounds of the
    adaptive campaign must not pile repetitions of one level up past it (the fit reads many
    identical levels as structure and widens the intervals)."""
    from omnibench.analysis.design.planner import MAX_REPS

    robot = default_robot()
    sp = _sweep_space(robot)
    targets = {"a": (0.0025, True), "c": (0.005, True)}
    info = candidate_information(robot, sp.candidates, planning_names(robot))
    first = plan(robot, None, targets, sp, info=info)
    top = max(first.units, key=lambda u: u.reps)
    assert top.reps >= 2  # the cap will bind
    done = {top.candidate: MAX_REPS - 1}
    again = plan(robot, None, targets, sp, info=info, done=done)
    assert again.units
    for u in again.units:
        assert u.reps + done.get(u.candidate, 0) <= MAX_REPS, u.candidate.label
    used = {u.candidate for u in first.units}
    full = plan(robot, None, targets, sp, info=info, done={c: MAX_REPS for c in used})
    assert full.units and not any(u.candidate in used for u in full.units)


def test_only_a_group_with_enough_degrees_of_freedom_lends_its_noise_to_another():
    """A group without data is planned at the noise of the same estimator elsewhere, but only a
    group whose chi^2/dof is worth something lends it: one forward pair's tape distances (about
    one degree of freedom) are a chi^2_1 draw (0.004-4), and a lateral design planned on a lucky
    0.13 is then a third of what the lateral runs need."""
    from omnibench.analysis.design.information import expected_s2
    from omnibench.analysis.fitting import REWEIGHT_MIN_DOF

    s2 = {"forward/forward": 0.13, "forward/w": 0.15, "sweep/omega": 0.4}
    dof = {"forward/forward": 1.0, "forward/w": 6.0, "sweep/omega": 10.0 * REWEIGHT_MIN_DOF}
    out = expected_s2(s2, dof)
    assert out["forward/forward"] == 0.13 and out["forward/w"] == 0.15  # a group's own figure is its own
    assert "lateral/forward" not in out and "lateral/left" not in out  # the stated tape noise (s^2 = 1)
    assert out["lateral/w"] == 0.4  # the sweep's encoder speeds: the same estimator, enough dof
    # without degrees of freedom every group lends (the largest of the same estimator)
    assert expected_s2(s2)["lateral/forward"] == 0.13 and expected_s2(s2)["lateral/w"] == 0.4
    # a fit reports the degrees of freedom of each group
    robot = default_robot()
    obs = simulated_observations(robot.replace(**TRUTH), seed=3, procedures=["sweep", "forward"])
    res = fit(robot, obs)
    assert set(res.group_dof) == set(res.group_s2)
    n_fwd = int(obs.forward.shape[0])
    assert 0 < res.group_dof["forward/forward"] < n_fwd


def test_a_floor_level_the_model_predicts_stuck_is_priced_at_nothing_and_not_planned():
    # the lab's ±0.06 sweep level: at the robot file's friction the wheel does not turn faster than
    # the fit's 0.3 rad/s (fitting.MIN_SWEEP_SPEED), so it informs nothing; every other floor level is planned
    from omnibench.analysis.design.files import diagnostic_floor

    robot = default_robot()
    files = procedure_files(None)
    space = space_from_files(robot, files)
    floor = diagnostic_floor(robot, files, space)
    info = candidate_information(robot, space.candidates, planning_names(robot))
    stuck = [c for c in floor if not info.usable[space.candidates.index(c)]]
    assert [(c.procedure, c.world.wheel_set, c.duty) for c in stuck] == [("sweep", "standard", 0.06)]
    assert not info.info[space.candidates.index(stuck[0])].any()
    d = plan(robot, None, {"a": (0.05, True), "b": (0.05, True)}, space, required=floor, info=info)
    planned = {u.candidate for u in d.units}
    assert stuck[0] not in planned and all(c in planned for c in floor if c is not stuck[0])


def test_candidate_information_is_simulated_once_per_robot_and_reweighted_per_call(monkeypatch):
    """An adaptive round asks for the same candidates' information at the same fit up to three
    times with other noise scales: the Jacobian is simulated once, each group's scale applied per
    call (a group at s^2 = 4 carries a quarter of the information), and a robot with other values
    is simulated again."""
    import numpy as np

    import omnibench.analysis.design.information as information

    robot = default_robot().replace(**TRUTH)
    sp = _sweep_space(robot)
    names = planning_names(robot)
    plain = candidate_information(robot, sp.candidates, names)
    assert plain.usable.any()

    def no_simulation(*args, **kwargs):
        raise AssertionError("simulated again for the same robot and candidates")

    monkeypatch.setattr(information, "_simulate_sensitivity", no_simulation)
    again = candidate_information(robot, sp.candidates, names)
    assert np.array_equal(again.info, plain.info) and np.array_equal(again.usable, plain.usable)
    noisy = candidate_information(robot, sp.candidates, names, group_s2={"sweep/omega": 4.0, "sweep/current": 4.0})
    assert np.allclose(noisy.info, plain.info / 4.0, rtol=1e-12, atol=0.0)
    with pytest.raises(AssertionError, match="simulated again"):
        candidate_information(robot.replace(a=0.03), sp.candidates, names)


def test_a_sweep_level_averaged_twice_as_long_is_worth_more_than_its_longer_hold(tmp_path):
    """Each sweep level is offered at the file's averaging time and at twice it. A line through
    n equally spaced readings has slope variance 12 s^2 / (n^3 - n) / dt^2: 60 readings instead of
    30 give 8.0 x the information for a hold of min_hold + average (0.85 s instead of 0.55). The
    planner prices it so (the rounding error is not white: 6-13 x at the sweep's speeds), and a world's levels at two averaging times are two files, each resting
    before its directions: the design's robot time counts both rests."""
    import math

    from omnibench.analysis.design.information import slope_se
    from omnibench.analysis.design.space import sweep_hold

    assert (slope_se(0.3, 1.0) / slope_se(0.6, 1.0)) ** 2 == pytest.approx((60 ** 3 - 60) / (30 ** 3 - 30))
    robot = default_robot().replace(**TRUTH)
    sp = _sweep_space(robot)
    short = {(c.world, c.duty): c for c in sp.candidates if c.duration == 0.3}
    long = {(c.world, c.duty): c for c in sp.candidates if c.duration == 0.6}
    assert short.keys() == long.keys() and len(short) + len(long) == len(sp.candidates)
    assert sweep_hold(STEADY, 0.6) == pytest.approx(0.85) and sweep_hold(STEADY, 0.3) == pytest.approx(0.55)
    names = planning_names(robot)
    keys = list(short)
    # the speeds alone (the currents' information grows only as the average: white noise per sample)
    info = candidate_information(robot, [short[k] for k in keys] + [long[k] for k in keys], names, current=False)
    ib = names.index("b")
    for i, k in enumerate(keys):
        if not info.usable[i]:
            continue
        gain = info.info[len(keys) + i][ib, ib] / info.info[i][ib, ib]
        assert gain > 2 * long[k].robot_seconds / short[k].robot_seconds, (k, gain)
    # a plan that must hold one level at the file's averaging time (a diagnostic floor) and tops up
    # the same world at twice it
    floor = next(short[k] for k in keys if k[1] == 0.3)
    design = plan(robot, None, {"a": (0.0025, True), "c": (0.005, True)}, sp, required=[floor])
    assert floor in {u.candidate for u in design.units}
    files = {(u.candidate.world, u.candidate.duration) for u in design.units}
    assert len(files) > len({u.candidate.world for u in design.units}), "no world with both averaging times"
    assert design.robot_seconds == pytest.approx(sum(u.candidate.robot_seconds * u.reps for u in design.units)
                                                 + 2 * sp.sweep_rest * len(files))
    written = write_procedures(design.units, procedure_files(None), tmp_path, robot)
    assert len(written) == len(files)
    for _, path in written:
        p = load_plan(path, robot, expect="upside_down_sweep")
        assert any(math.isclose(p.settings["steady_state"]["average"], d) for _, d in files)


def test_timed_runs_split_by_end_time_give_the_merged_groups_numbers_bit_for_bit(monkeypatch):
    """The planner's sensitivities simulate each end time of the forward and lateral candidates as
    a group of its own (a group runs to its latest end: merged, the 1.5 s runs rested 3 s at full
    sub-steps, 95 % of a plan's simulation); the Jacobian, the rows used and their groups are the
    merged computation's, bit for bit, at the file's values and at others."""
    import numpy as np

    import omnibench.analysis.design.information as information
    from omnibench.analysis.least_squares import param_scale

    robot = default_robot()
    sp = build_space(robot, wheel_sets=[("standard", (0.9,) * 4)], payloads=[2.0], steady=STEADY, limits=LIMITS,
                     durations=(1.0, 2.0), forward_duties=(0.3,), headings_deg=(60,), speeds=(0.3,),
                     sweep_duties=(0.2,))
    cands = sp.candidates
    assert {c.duration for c in cands if c.procedure != "sweep"} == {1.0, 2.0}
    for model in (robot, robot.replace(a=0.02, b=0.45, c=0.015, a_r=2.5, b_r=0.8, c_r=0.02, C_r=0.03)):
        names = planning_names(model)
        scale = np.array([param_scale(model, p) for p in names])
        split = information._simulate_sensitivity(model, cands, names, scale, True)
        with monkeypatch.context() as m:
            m.setattr(information, "split_by_end", lambda pred: pred)
            merged = information._simulate_sensitivity(model, cands, names, scale, True)
        assert np.array_equal(split.J, merged.J)
        assert np.array_equal(split.cand_of, merged.cand_of) and np.array_equal(split.groups, merged.groups)
        assert set(split.cand_of) >= {k for k, c in enumerate(cands) if c.procedure != "sweep"}
