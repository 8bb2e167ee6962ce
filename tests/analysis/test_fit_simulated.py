"""Fits on simulated campaigns whose world has exactly the declared effects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from omnibench.analysis.fitting import error_by_procedure, fit, sweep_linear_estimate
from omnibench.analysis.simcampaign import simulated_observations
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


def test_each_coefficients_variance_is_split_over_the_groups_that_determine_it(campaign_fit):
    """The share of each coefficient's variance that each measurement group carries (what decides
    a 'model inadequate' verdict) sums to 1 and follows the design: the sweep determines the
    transmission and motor terms, the lateral runs the rollers', and C_r mostly the sweep too,
    through the c b it shares its regressor with."""
    res = campaign_fit
    share = res.variance_share
    assert set(share) == set(CAMPAIGN_PARAMS)
    for p, sh in share.items():
        assert sum(sh.values()) == pytest.approx(1.0, abs=1e-9) and min(sh.values()) >= 0.0, (p, sh)

    def of(p: str, proc: str) -> float:
        return sum(v for g, v in share[p].items() if g.startswith(proc + "/"))

    for p in ("a", "k_e", "R_a"):
        assert of(p, "sweep") > 0.9, (p, share[p])
    for p in ("a_r", "b_r", "c_r"):
        assert of(p, "lateral") > 0.8, (p, share[p])
    assert of("C_r", "sweep") > 0.5 > of("C_r", "forward"), share["C_r"]
    assert res.inadequate() == [] and res.misses_something() == []


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


def test_the_encoder_speeds_stated_errors_match_their_scatter(campaign_fit):
    """Each encoder speed's stated error is the rounding error of its straight-line fit at that
    speed and window (omnibench/analysis/quantisation.py): on the simulated robot the encoder
    groups' chi^2/dof against it is about 1 (0.6-1.2 on this seed). The textbook slope error
    over-stated them 3-10 x (chi^2/dof 0.1-0.4), most at the fast wheels."""
    for g in ("sweep/omega", "forward/w", "lateral/w"):
        assert 0.4 < campaign_fit.group_s2[g] < 2.0, (g, campaign_fit.group_s2)


def test_each_large_groups_noise_weights_the_fit(robot, campaign, campaign_fit, monkeypatch):
    """A group whose stated errors over-state its noise (here the lateral runs' wheel speeds,
    stated 4 x too large) is weighted by its own noise when it has >= REWEIGHT_MIN_DOF degrees
    of freedom: the SEs come back as with honest errors, while weighting by the stated errors
    alone is consistent but leaves the group's information unused; group_s2 is still reported
    against the stated errors."""
    from dataclasses import replace

    import omnibench.analysis.fitting as fitting

    lateral = campaign.lateral.copy()
    for j in range(1, 5):
        lateral[f"w_se{j}"] *= 4.0
    loud = replace(campaign, lateral=lateral)
    weighted = fit(robot, loud)
    assert weighted.group_s2["lateral/w"] < campaign_fit.group_s2["lateral/w"] / 8
    monkeypatch.setattr(fitting, "REWEIGHT_MIN_DOF", math.inf)
    stated = fit(robot, loud)
    for p in CAMPAIGN_PARAMS:
        assert abs(weighted.se[p] / campaign_fit.se[p] - 1.0) < 0.02, (p, weighted.se[p], campaign_fit.se[p])
        assert abs(weighted.values[p] - stated.values[p]) < 3 * stated.se[p]
    for p in ("b_r", "c"):  # 16 % and 9 % larger on this seed
        assert stated.se[p] > 1.05 * weighted.se[p], (p, weighted.se[p], stated.se[p])


@pytest.mark.parametrize("sign_width_phi, fits", [(None, True), (0.1, False)])
def test_lateral_runs_of_a_world_whose_contacts_stick_fit_to_their_noise(sign_width_phi, fits, monkeypatch):
    """The lab's lateral runs simulated by the independent physics (omnibench/worlds/independent.py:
    dry friction 100 x sharper than the model's, another integrator), a clean world: no group
    misfits and the roller terms come back within 3 % (their SE is about 0.45 %). At a 60 deg
    heading two wheels turn at only 0.26-0.4 rad/s; with the former wheel sign width of 0.1 rad/s
    their dry friction was 5-14 % short of Coulomb's, the wheel speeds misfit by 26-50 sigma and
    the roller terms came back 11-30 % off (docs/robot-file.md): the second case keeps that as the
    check that this test can fail. (On this draw b_r is 1.5 % low, 3.6 SE, at every width down to
    0.001 rad/s, and within 1 SE on the next draw: a smaller difference between the two physics
    that the width does not explain, hence the bound in per cent, not in SE.)"""
    from omnibench.analysis import fitting
    from omnibench.model import default_robot

    robot = default_robot()
    if sign_width_phi is not None:  # the fit as it was: that width, and every wheel speed used
        robot = robot.replace(sign_width_phi=sign_width_phi)
        monkeypatch.setattr(fitting, "MIN_GROUND_SPEED_WIDTHS", 0.0)
    truth = robot.replace(a=0.02, b=0.45, c=0.015, a_r=2.5, b_r=0.8, c_r=0.02, C_r=0.03)
    obs = simulated_observations(truth, procedures=["lateral"], seed=7000, generator="independent")
    # a, b, c, C_r at the world's values: the lateral runs' own parameters are what is tested
    res = fit(truth.replace(a_r=2.0, b_r=1.0, c_r=0.01), obs, ["a_r", "b_r", "c_r"])
    assert (res.misses_something() == []) == fits, res.misses_something()
    off = {p: abs(res.values[p] / getattr(truth, p) - 1.0) for p in ("a_r", "b_r", "c_r")}
    assert (max(off.values()) < 0.03) == fits, off


def test_wheels_that_stick_in_a_lateral_run_are_left_out_of_the_fit_and_of_the_plan():
    """At a 45 deg heading two wheels stand still (their rollers take the motion): a real wheel
    sticks, the model's smoothed friction lets it creep. The fit leaves wheel speeds below 10 sign
    widths out and says so; the planner counts no information from them (design/information.py)."""
    import tempfile
    from pathlib import Path

    from omnibench.analysis.design.files import space_from_files, write_procedures
    from omnibench.analysis.design.information import candidate_information
    from omnibench.analysis.design.planner import Unit
    from omnibench.analysis.fitting import MIN_GROUND_SPEED_WIDTHS
    from omnibench.campaign.run import procedure_files
    from omnibench.model import default_robot

    robot = default_robot()
    truth = robot.replace(a=0.02, b=0.45, c=0.015, a_r=2.5, b_r=0.8, c_r=0.02, C_r=0.03)
    files = procedure_files(None)
    space = space_from_files(robot, files)
    pick = lambda deg: next(c for c in space.candidates if c.procedure == "lateral" and c.world.payload == 0  # noqa: E731
                            and abs(math.degrees(c.heading) - deg) < 1e-6 and c.speed == 0.3 and c.duration == 1.5)
    with tempfile.TemporaryDirectory() as tmp:
        (_, path), = write_procedures([Unit(pick(45), 1, 0)], files, Path(tmp), robot, seed=1)
        obs = simulated_observations(truth, procedures=["lateral"], files={"lateral": path}, seed=5,
                                     generator="independent")
    res = fit(truth, obs, ["a_r"])
    w = res.residuals[(res.residuals["procedure"] == "lateral") & (res.residuals["signal"] == "w")]
    slow = w["measured"].abs() < MIN_GROUND_SPEED_WIDTHS * robot.sign_width_phi
    assert slow.sum() == 4 and w["wheel"][slow].isin([1, 4]).all()  # wheels 1 and 4, both ways
    assert not w["used"][slow].any() and w["used"][~slow].all()
    assert any("4 ground-run wheel speed(s)" in n for n in res.notes), res.notes
    assert res.misses_something() == []
    # the planner: the pair at 45 deg informs a_r only through the turning wheels and the tape
    info = candidate_information(truth, [pick(45)], ["a_r", "b_r"])
    assert info.usable[0] and np.all(np.isfinite(info.info[0]))


def _sweep_residuals(levels, reps, rng, bias=0.0):
    """A sweep/omega residual frame: `reps` repeats of each level (rad/s) on one wheel, measured =
    model + unit noise (+ `bias` at the slowest level), speed = the measured value (as entered)."""
    import pandas as pd

    from omnibench.analysis.fitting import residual_structure  # noqa: F401  (the function under test)

    rows, step = [], 0
    for w in levels:
        for _ in range(reps):
            m = w + rng.normal(0.0, 0.01) + (bias if w == levels[0] else 0.0)
            rows.append({"procedure": "sweep", "signal": "omega", "unit": "rad/s", "wheel": 1, "F_N": 8.8,
                         "step": step, "speed": m, "measured": m, "predicted": w, "sigma": 0.01,
                         "residual": m - w, "normalised": (m - w) / 0.01, "used": True})
            step += 1
    return pd.DataFrame(rows)


def test_repeats_of_a_level_do_not_look_like_structure_but_a_biased_level_does():
    """Structure is judged along the model's speed: ordered by the measured speed, the repeats of
    each level lined up by their own noise (rho 0.4, z 9 on a planned sweep of 8 repeats, whose
    variance was then inflated 2.5 x and its SEs stated 30 % too large). A level whose repeats
    share a bias of 5 noise SDs still shows."""
    from omnibench.analysis.fitting import STRUCTURE_Z, residual_structure

    rng = np.random.default_rng(0)
    levels = [0.5, 1.0, 2.0, 4.0, 6.0, 8.0]
    clean = residual_structure(_sweep_residuals(levels, 8, rng))["sweep/omega"]
    assert clean["z"] < STRUCTURE_Z, clean
    biased = residual_structure(_sweep_residuals(levels, 8, rng, bias=0.05))["sweep/omega"]
    assert biased["z"] > STRUCTURE_Z, biased


def _duties_at_counts_per_reading(truth, counts, mass):
    """Duties whose steady speed upside down, on a wheel of `mass` kg, is `counts` encoder
    counts per 10 ms reading (the closed-form torque balance solved for u)."""
    F = mass * 9.80665
    per_reading = truth.counts_per_rev / (2 * math.pi) * 0.01
    out = []
    for k in counts:
        w = k / per_reading
        out.append(round((truth.k_e * w + truth.R_a * (1 + truth.c * F) * (truth.a * w + truth.b)
                          / (truth.eta * truth.k_t)) / truth.V_batt, 6))
    return out


def test_sweep_speeds_near_whole_counts_per_reading_do_not_bias_the_friction(robot, truth, tmp_path):
    """A speed read at nearly a whole number of encoder counts per reading has a rounding error
    that swings sharply with the speed: evaluated at each step's own estimate, its stated SE
    follows the estimate's own error, and weighting by it pulled the fit toward the steps whose
    rounding happened to read precise (means of (fit - truth) / SE over these 30 sweeps: b -0.86,
    c +0.83, R_a +1.10). Weighted by the error at the model's speed, they average within 0.5 of
    zero (-0.16, -0.05, +0.28) and scatter like N(0, 1)."""
    from tests.bench.test_campaign import HERE as BENCH

    text = (BENCH / "procedures" / "campaign" / "upside_down_sweep.toml").read_text()
    # the heavy wheels 0.03 count per reading below 3, 5, ... 13 (the light ones ~0.1 above)
    duties = _duties_at_counts_per_reading(truth, (2.97, 4.97, 6.97, 8.97, 10.97, 12.97), 1.9)
    path = tmp_path / "upside_down_sweep.toml"
    path.write_text(text.replace("duties = [0.1, 0.3, 0.7]", f"duties = {duties}"))
    z: dict[str, list[float]] = {"b": [], "c": [], "R_a": []}
    for seed in range(30):
        obs = simulated_observations(truth, seed=seed, procedures=["sweep"], files={"sweep": path})
        res = fit(robot, obs, procedures=["sweep"])
        for p in z:
            z[p].append((res.values[p] - getattr(truth, p)) / res.se[p])
    for p, v in z.items():
        assert abs(np.mean(v)) < 0.5, (p, np.mean(v))
        assert 0.6 < math.sqrt(np.mean(np.square(v))) < 1.5, (p, v)
