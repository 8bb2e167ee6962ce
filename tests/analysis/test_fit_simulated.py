"""Fits on simulated campaigns whose world has exactly the declared effects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from omnibench.analysis.simcampaign import simulated_observations
from omnibench.analysis.fitting import error_by_procedure, fit, sweep_linear_estimate
from omnibench.analysis.validate import validate_energy

CAMPAIGN_PARAMS = ("a", "b", "c", "k_e", "R_a", "C_r", "a_r", "b_r", "c_r")


def test_campaign_fit_recovers_every_parameter_within_3_se(campaign_fit, truth):
    res = campaign_fit
    assert set(res.free) == set(CAMPAIGN_PARAMS)
    assert res.rank == len(CAMPAIGN_PARAMS)
    assert res.condition_number < 1e4
    for p in CAMPAIGN_PARAMS:
        assert res.identifiable[p].status == "identified", (p, res.identifiable[p])
        z = (res.values[p] - getattr(truth, p)) / res.se[p]
        assert abs(z) < 3.0, f"{p}: {res.values[p]:.6g} vs truth {getattr(truth, p):.6g} ({z:+.2f} SE)"
        lo, hi = res.ci95[p]
        assert lo < res.values[p] < hi
    # the start values were the robot file's placeholders, far from the truth
    assert abs(res.initial["C_r"] - truth.C_r) > 10 * res.se["C_r"]
    assert 0.3 < res.s2 < 3.0  # the reported noise explains the residual
    assert res.structure and all(abs(st["z"]) < 3 for st in res.structure.values()), res.structure
    assert not any("structure the model misses" in n for n in res.notes)
    np.testing.assert_allclose(np.diag(res.corr.to_numpy()), 1.0)
    assert set(res.runs_used) == {r for r in campaign_fit.residuals["run"].unique() if not r.startswith("sim-energy")}


def test_energy_error_below_one_percent_on_every_trajectory(campaign_fit, campaign, robot):
    val = validate_energy(campaign_fit.robot, campaign)
    assert len(val.table) == 4
    assert val.max_abs_error_pct < 1.0, val.table
    # the unfitted placeholders are far off: the check can fail
    assert validate_energy(robot, campaign).mean_abs_error_pct > 5.0


def test_held_out_error_is_smaller_with_the_fitted_model(campaign_fit, campaign, robot, truth):
    fitted = error_by_procedure(campaign_fit.robot, campaign, ["sweep", "forward", "lateral"])
    placeholder = error_by_procedure(robot, campaign, ["sweep", "forward", "lateral"])
    for p in ("sweep", "forward", "lateral"):
        assert fitted[p] < 0.2 * placeholder[p], (p, fitted[p], placeholder[p])
    z = error_by_procedure(truth, campaign, ["forward"], kind="z")["forward"]
    assert 0.3 < z < 3.0


def test_sweep_intervals_cover_the_truth_over_20_seeds(robot, truth):
    hits, zs = [], []
    for seed in range(20):
        obs = simulated_observations(truth, seed=100 + seed, procedures=["sweep"])
        res = fit(robot, obs, procedures=["sweep"])
        assert set(res.free) == {"a", "b", "c", "k_e", "R_a"}
        for p in res.free:
            lo, hi = res.ci95[p]
            hits.append(lo <= getattr(truth, p) <= hi)
            zs.append((res.values[p] - getattr(truth, p)) / res.se[p])
    coverage = float(np.mean(hits))
    assert coverage >= 0.85, coverage
    # and the intervals are not absurdly wide: the normalised errors scatter like N(0, 1)
    assert 0.5 < math.sqrt(np.mean(np.square(zs))) < 1.5


@pytest.mark.parametrize("second_load_levels", [(0.15, 0.3, 0.5, 0.8, -0.2, -0.6), (0.8, -0.8)])
def test_closed_form_sweep_estimate_matches_the_truth_on_noise_free_steady_states(robot, truth, second_load_levels):
    """III.i least squares in the torque domain, on steady states of the closed-form torque balance;
    also when the second wheel set ran at one level only (the design's diagnostic floor), where a
    linear form in (a, b, a c, b c) is rank-deficient."""
    from scipy.optimize import brentq

    rows = []
    for mass in (0.9, 1.9):
        F = mass * 9.80665
        for u in ((0.15, 0.3, 0.5, 0.8, -0.2, -0.6) if mass < 1 else second_load_levels):
            def torque(w):
                i = (u * truth.V_batt - truth.k_e * w) / truth.R_a
                return truth.eta * truth.k_t * i - (1 + truth.c * F) * (truth.a * w + truth.b * np.sign(w))
            w = brentq(torque, 1e-9 * np.sign(u), u * truth.V_batt / truth.k_e)
            i = (u * truth.V_batt - truth.k_e * w) / truth.R_a
            rows.append({"omega": w, "u": u, "F_N": F, "current": i})
    import pandas as pd

    est = sweep_linear_estimate(truth, pd.DataFrame(rows))
    assert est["a"] == pytest.approx(truth.a, rel=1e-6)
    assert est["b"] == pytest.approx(truth.b, rel=1e-6)
    assert est["c"] == pytest.approx(truth.c, rel=1e-6)


def test_each_large_groups_noise_weights_the_fit(robot, campaign, campaign_fit, monkeypatch):
    """The encoder speeds' stated errors over-state their noise (chi^2/dof 0.1-0.4 against the
    stated), the tape's do not: weighting every entry by its stated error alone is consistent but
    leaves information unused. The fit weights each group of >= REWEIGHT_MIN_DOF degrees of
    freedom by its own noise, so C_r, b and c come out with smaller (honest) SEs than the
    stated-weight fit; group_s2 is still reported against the stated errors."""
    import omnibench.analysis.fitting as fitting

    assert campaign_fit.group_s2["forward/w"] < 0.5 and campaign_fit.group_s2["sweep/omega"] < 0.6
    monkeypatch.setattr(fitting, "REWEIGHT_MIN_DOF", math.inf)
    stated = fit(robot, campaign)
    for p in ("C_r", "b", "c"):
        assert campaign_fit.se[p] < 0.97 * stated.se[p], (p, campaign_fit.se[p], stated.se[p])
    for p in CAMPAIGN_PARAMS:
        assert abs(campaign_fit.values[p] - stated.values[p]) < 3 * stated.se[p]
