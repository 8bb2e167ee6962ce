"""The continuous optimal design and the exchange step (issue 15): closed forms on small problems."""

from __future__ import annotations

import numpy as np
import pytest

from omnibench.analysis.design.optimal import cheapest_weights
from omnibench.analysis.design.planner import _exchange
from omnibench.analysis.design.space import Candidate, Costs
from omnibench.bench.procedure import World


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
