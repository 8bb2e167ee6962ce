"""Verdicts that cannot contradict the data: a coefficient is not "identified" while a measurement
group that determines it misfits its stated noise, or while its 95 % interval includes zero."""

from __future__ import annotations

import math

import pytest

from omnibench.analysis.fitting import DETERMINES_SHARE, MISFIT_S2, fit, misfit_groups
from omnibench.analysis.simcampaign import simulated_observations
from omnibench.campaign.answer import campaign_answer, inadequacy
from omnibench.campaign.run import answer_lines
from omnibench.campaign.summary import campaign_summary

SWEEP_FORWARD = ("a", "b", "c", "k_e", "R_a", "C_r")


@pytest.fixture(scope="module")
def deadband_fit(robot, truth):
    """The sweep and forward runs of a world whose motor driver has a deadband (u_0 = 0.04) the
    declared model lacks."""
    obs = simulated_observations(truth, world_effects={"driver_deadband": {"u_0": 0.04}},
                                 procedures=["sweep", "forward"], seed=11)
    return fit(robot, obs)


def test_an_effect_the_model_lacks_makes_the_verdicts_model_inadequate_naming_the_group(deadband_fit, robot, truth):
    res = deadband_fit
    # the verdict is deserved: the fit is far from the truth in SE units
    z = {p: (res.values[p] - getattr(truth, p)) / res.se[p] for p in SWEEP_FORWARD}
    assert max(abs(v) for v in z.values()) > 10, z
    # the deadband is a voltage offset: the sweep's motor currents miss it by far
    assert res.group_s2["sweep/current"] > 100 * MISFIT_S2, res.group_s2
    for p in SWEEP_FORWARD:
        v = res.identifiable[p]
        assert v.status == "model inadequate", (p, v)
        assert "sweep/current: chi2/dof" in v.reason and "omnibench diagnose" in v.reason, v.reason
        assert v.ok and math.isfinite(res.se[p])  # the number stays, with its (widened) SE
        assert res.variance_share[p]["sweep/current"] >= DETERMINES_SHARE
    worst = res.inadequate()[0]
    assert worst["group"] == "sweep/current" and worst["chi2_dof"] == res.group_s2["sweep/current"]
    assert set(worst["determines"]) == set(SWEEP_FORWARD)
    assert worst["text"].startswith("sweep/current: chi2/dof ") and "of its variance" in worst["text"]
    assert "identified" not in res.table().replace("not identified", "")
    # the same runs without the deadband: every coefficient identified, no misfit group
    clean = fit(robot, simulated_observations(truth, procedures=["sweep", "forward"], seed=11))
    assert all(clean.identifiable[p].status == "identified" for p in SWEEP_FORWARD), clean.identifiable
    assert clean.inadequate() == [] and clean.misses_something() == []


def test_the_campaign_answer_says_which_group_by_how_much_and_what_diagnose_did(deadband_fit, tmp_path):
    fit_json = deadband_fit.to_json()
    skipped = {"fit": {"status": "ok", "result": fit_json},
               "diagnose": {"status": "skipped", "why": "not asked for (--analysis)"}}
    ans = campaign_answer(skipped)
    first = inadequacy(ans)
    assert first[0].startswith("MODEL INADEQUATE for these runs") and "C_r" in first[0]
    chi2 = fit_json["group_s2"]["sweep/current"]
    assert any(line.startswith(f"sweep/current: chi2/dof {chi2:.0f} ") for line in first), first
    assert "diagnose did not run" in first[-1] and "omnibench diagnose" in first[-1]
    # the terminal summary and the report open with it, before the coefficients
    summary = campaign_summary({"analysis": skipped, "report": "r.md", "report_html": "r.html"})
    assert summary[2] == first[0] and summary.index(first[0]) < next(k for k, s in enumerate(summary) if s.startswith("  C_r "))
    report = answer_lines(ans, tmp_path)
    assert report[2] == f"**{first[0]}**" and any("sweep/current: chi2/dof" in s for s in report[:8])
    assert "**Identified**" not in "\n".join(report)
    # diagnose ran and found nothing, with structure it could not place: the first screen says so
    found_nothing = {**skipped, "diagnose": {"status": "ok", "result": {
        "selected": [], "before": {}, "after": {},
        "unexplained": [{"group": "forward/w", "variable": "u", "location": "forward w: u 0.3: mean residual -0.052"}]}}}
    last = inadequacy(campaign_answer(found_nothing))[-1]
    assert last.startswith("diagnose found no candidate effect") and "forward w: u 0.3" in last


def test_a_clean_campaign_has_no_inadequacy_on_its_first_screen(campaign_fit):
    ans = campaign_answer({"fit": {"status": "ok", "result": campaign_fit.to_json()}})
    assert ans.inadequate == [] and inadequacy(ans) == []
    assert all(c.verdict == "identified" for c in ans.coefficients), [(c.name, c.verdict) for c in ans.coefficients]


def test_a_misfit_group_of_few_entries_counts_only_when_significant():
    dof = {"forward/forward": 2.0, "forward/w": 47.0}
    # two tape distances at chi2/dof 5: a chi2_2 draw above 10 one time in 150, not a verdict
    assert misfit_groups({"forward/forward": 5.0, "forward/w": 1.0}, dof, [], 1.0, 100) == {}
    # ... at 1678, the model is wrong; and a large group just above MISFIT_S2 is
    assert misfit_groups({"forward/forward": 1678.0, "forward/w": 4.5}, dof, [], 1.0, 100) == {
        "forward/forward": 1678.0, "forward/w": 4.5}
    # a group whose noise was estimated from its own residual has no chi2 test
    assert misfit_groups({"sweep/omega": 9.4}, {"sweep/omega": 25.0}, ["sweep/omega"], 1.0, 25) == {}


@pytest.mark.parametrize("seed", [3, 4])
def test_a_coefficient_zero_in_the_truth_is_consistent_with_zero_not_identified(robot, truth, seed):
    """The declared model has a direction asymmetry of the Coulomb friction (db) that the world
    has not: its interval includes zero, and the verdict says so. With db = 0.02 N m in the world,
    the same fit identifies it."""
    declared = robot.replace(effects={"asymmetric_coulomb": {"db": 0.01, "c_db": 0.0}})
    free = ["a", "b", "c", "k_e", "R_a", "asymmetric_coulomb.db"]
    p = "asymmetric_coulomb.db"
    for db, status in ((0.0, "consistent with zero"), (0.02, "identified")):
        obs = simulated_observations(truth, world_effects={"asymmetric_coulomb": {"db": db, "c_db": 0.0}},
                                     procedures=["sweep"], seed=seed)
        res = fit(declared, obs, free, procedures=["sweep"])
        lo, hi = res.ci95[p]
        assert lo < db < hi, (db, res.ci95[p])
        v = res.identifiable[p]
        assert v.status == status, (db, v)
        assert v.ok and math.isfinite(res.se[p])
        if db == 0.0:
            assert "includes zero" in v.reason and "relative standard error" in v.reason
        assert all(res.identifiable[q].status == "identified" for q in free if q != p), res.identifiable
