"""The continuous optimal design and the exchange step (issue 15): closed forms on small problems."""

from __future__ import annotations

import numpy as np
import pytest

from omnibench.analysis.design.optimal import cheapest_weights
from omnibench.analysis.design.planner import _exchange
from omnibench.analysis.design.space import Candidate, Costs
from omnibench.procedures import World


def test_one_parameter_buys_only_the_most_information_per_second():
    # information 2 per pair at cost 1, 3 per pair at cost 2: only the first; w = (1/t^2 - M0) / 2
    w = cheapest_weights(np.array([[1e-6]]), np.array([[[2.0]], [[3.0]]]), np.array([1.0, 2.0]), np.array([0]),
                         np.array([0.01]), np.zeros(2), np.full(2, 100.0))
    assert w is not None
    assert w[0] == pytest.approx((100 - 1e-6) / 2, rel=1e-3) and w[1] == pytest.approx(0, abs=1e-3)


def test_a_step_that_informs_both_targets_beats_two_that_inform_one_each():
    infos = np.array([np.diag([1.0, 0.0]), np.diag([0.0, 1.0]), 0.9 * np.eye(2)])
    t2 = np.array([0.01, 0.01])
    w = cheapest_weights(1e-6 * np.eye(2), infos, np.ones(3), np.array([0, 1]), t2, np.zeros(3), np.full(3, 500.0))
    assert w is not None
    assert w[2] == pytest.approx(1 / (0.9 * 0.01), rel=1e-3) and w[0] + w[1] < 1e-2
    # bounds that cannot reach the target: no design
    assert cheapest_weights(1e-6 * np.eye(2), infos, np.ones(3), np.array([0, 1]), t2, np.zeros(3),
                            np.ones(3)) is None


def test_exchange_replaces_a_dear_pair_by_a_cheaper_one_that_still_meets_the_target():
    ground = World("ground", "standard", None, 0.0)
    long_run = Candidate("forward", ground, duty=0.5, duration=4.5, settle=1.0, robot_seconds=11.0, measurements=2)
    short_run = Candidate("forward", ground, duty=0.5, duration=1.5, settle=1.0, robot_seconds=5.0, measurements=2)
    infos = np.array([[[400.0]], [[150.0]]])  # target needs 1 / 0.01 = 100
    M0 = np.array([[1.0]])
    chosen, M = _exchange({0: 1}, M0 + infos[0], infos=infos, cands=[long_run, short_run], ks=np.array([0, 1]),
                          req=[], tidx=np.array([0]), t2=np.array([0.01]), costs=Costs(robot_second=3.0))
    assert chosen == {1: 1} and M[0, 0] == pytest.approx(151.0)
    # a cheaper step that does not meet the target is not taken
    weak = np.array([[[400.0]], [[50.0]]])
    chosen, _ = _exchange({0: 1}, M0 + weak[0], infos=weak, cands=[long_run, short_run], ks=np.array([0, 1]),
                          req=[], tidx=np.array([0]), t2=np.array([0.01]), costs=Costs(robot_second=3.0))
    assert chosen == {0: 1}


def test_a_dear_pair_is_replaced_by_two_cheaper_ones_together():
    # one dear step informs both targets; each cheap one informs one. No single cheaper step meets
    # both targets, so the one-pair exchange keeps the dear step; the neighbourhood search takes it
    # out and completes with both cheap ones (cost 2 x 3 s x 3 < 10 s x 3)
    from omnibench.analysis.design.planner import _improve

    ground = World("ground", "standard", None, 0.0)
    dear = Candidate("forward", ground, duty=0.5, duration=4.5, robot_seconds=10.0)
    cheap_a = Candidate("forward", ground, duty=0.3, duration=1.5, robot_seconds=3.0)
    cheap_b = Candidate("forward", ground, duty=0.7, duration=1.5, robot_seconds=3.0)
    infos = np.array([np.diag([150.0, 150.0]), np.diag([150.0, 0.0]), np.diag([0.0, 150.0])])
    M0 = 1e-3 * np.eye(2)
    tidx, t2 = np.array([0, 1]), np.array([0.01, 0.01])
    cands, costs, room = [dear, cheap_a, cheap_b], Costs(robot_second=3.0), np.full(3, 8.0)
    kept, _ = _exchange({0: 1}, M0 + infos[0], infos=infos, cands=cands, ks=np.arange(3), req=[], tidx=tidx, t2=t2,
                        costs=costs, room=room)
    assert kept == {0: 1}
    chosen, M = _improve({0: 1}, M0 + infos[0], M0=M0, infos=infos, cands=cands, ks=np.arange(3), req=[], tidx=tidx,
                         t2=t2, costs=costs, room=room, max_units=20, budget_s=np.inf, budget_a=np.inf)
    assert chosen == {1: 1, 2: 1}
    assert np.all(np.diag(np.linalg.inv(M)) <= t2)
    # a required step (the diagnostic floor) is never taken out
    chosen, _ = _improve({0: 1}, M0 + infos[0], M0=M0, infos=infos, cands=cands, ks=np.arange(3), req=[0], tidx=tidx,
                         t2=t2, costs=costs, room=room, max_units=20, budget_s=np.inf, budget_a=np.inf)
    assert chosen == {0: 1}


def test_no_pair_of_a_plan_can_be_swapped_for_a_cheaper_one_that_still_meets_every_target(omnibot):
    # the lab's whole design space at a fixed-grid fit (values, each group's noise), the diagnostic
    # floor required: no pair of the plan may be replaceable by a cheaper candidate of its world with
    # every target still met (before the planner's last exchange ran over every candidate, on this
    # seed a 4.5 s lateral pair stayed where a 3 s one did: 49.7 s against 46.7 s)
    from omnibench.analysis.design.files import diagnostic_floor, space_from_files
    from omnibench.analysis.design.information import candidate_information, prior_information
    from omnibench.analysis.design.planner import MARGIN, plan, planning_names, target_se
    from omnibench.analysis.fitting import fit
    from omnibench.analysis.least_squares import param_value
    from omnibench.analysis.simcampaign import simulated_observations
    from omnibench.campaign.run import procedure_files

    files = procedure_files(None)
    space = space_from_files(omnibot, files)
    floor = diagnostic_floor(omnibot, files, space)
    truth = omnibot.replace(a=0.02, b=0.45, c=0.015, a_r=2.5, b_r=0.8, c_r=0.02, C_r=0.03)
    res = fit(omnibot, simulated_observations(truth, seed=7004, procedures=["sweep", "forward", "lateral"]))
    targets = {p: (v, True) for p, v in dict(a=0.00181, b=0.000615, c=0.00284, C_r=0.00764, a_r=0.00422,
                                              b_r=0.00422, c_r=0.00788).items()}
    names = planning_names(res.robot)
    info = candidate_information(res.robot, space.candidates, names, group_s2=res.group_s2, group_dof=res.group_dof)
    costs = Costs(robot_second=3.0)
    d = plan(res.robot, None, targets, space, costs, required=floor, info=info)
    assert all(d.met.values())
    cands = space.candidates
    M = prior_information(None, names, info.scale) + sum(u.reps * info.info[cands.index(u.candidate)] for u in d.units)
    tabs = target_se(targets, {p: param_value(res.robot, p) for p in names})
    tidx = [names.index(p) for p in targets]
    t = np.array([MARGIN * tabs[p] / info.scale[names.index(p)] for p in targets])

    def cost(c):
        return costs.of(c.robot_seconds, {"measure": c.measurements})

    swaps = []
    for u in d.units:
        if u.candidate in floor and u.reps == 1:
            continue
        k = cands.index(u.candidate)
        for j, c in enumerate(cands):
            if c.world == u.candidate.world and info.usable[j] and cost(c) < cost(u.candidate) - 1e-9:
                v = np.diag(np.linalg.inv(M - info.info[k] + info.info[j]))[tidx]
                if np.all(v > 0) and np.all(np.sqrt(v) <= t * (1 + 1e-9)):
                    swaps.append((u.candidate.label, c.label))
    assert swaps == []
