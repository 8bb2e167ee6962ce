"""The diagnosis engine: one measurement vector, profile-likelihood fits, screening, held-out errors.

Data. `Problem` is the analysis's one least-squares problem (`least_squares.Problem`, the
engine `omnibench fit` uses too) over every observation entry of some procedures (a steady wheel
speed, a mean current, a drive speed, a distance, an energy, a step-response speed sample) with
its metadata (procedure, run, step, wheel, speed, F_N, direction, time, current, duty), its noise
groups' floors and the profile deviance. Parameter vectors, predictions and forward-difference
stencils are the engine's (`least_squares.Parameters`, `Problem.stencil`, `fd_steps`).

Noise model. Entries fall in groups (procedure/signal; entries without a standard error form
their own group). Within a group the entry's own standard error sigma_k sets the relative
weight; each group's scale s_g is unknown and profiled out (estimated from the residuals),
so a wrongly stated noise level cannot make an effect look significant. The fit minimises the
profile deviance

    D = sum_g (n_g - 1) log(s_g^2) + RSS_g / s_g^2,   RSS_g = sum_{k in g} ((y_k - f_k(theta)) / sigma_k)^2,
    s_g^2 = max(RSS_g / n_g, floor_g^2)

by iteratively reweighted least squares (weights 1 / (s_g sigma_k)). The floor (0.5 for stated
standard errors, 0.1 % of the group's RMS value without) keeps a tiny group that one parameter
fits exactly from making every later parameter look decisive.

Test. A candidate with q parameters added to the current model is a nested model; the
likelihood-ratio statistic LR = D_0 - D_1 is chi^2(q) under "the effect is absent" (Wilks). The
groups' sizes enter with n_g - 1 (a Bartlett-type correction for small groups such as four
energy runs).

Held-out error. K-fold over whole run steps (step responses: over time blocks of the run):
the model is refitted without the fold by one Gauss-Newton step from the full-data fit
(exact for a linear model; the fits here are near-linear at the optimum), and the held-out
entries are predicted. Reported per procedure as RMS(held-out residual) / RMS(measured),
the same normalisation as `fitting.error_by_procedure`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from scipy import optimize

from omnibench.analysis import least_squares
from omnibench.analysis.diagnosis.encoder_se import encoder_se
from omnibench.analysis.diagnosis.probabilities import chi2_sf
from omnibench.analysis.diagnosis.robust_se import cluster_se
from omnibench.analysis.least_squares import Parameters, param_bounds, param_value, with_params
from omnibench.analysis.observations import Observations
from omnibench.analysis.predictor import Predictor
from omnibench.effects.library import Effect

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

#: diagnose's forward-difference step, in units of each parameter's scale (latencies: one
#: physics step, `least_squares.fd_steps`)
FD_STEP = 1e-4
CV_FOLDS = 5
MIN_SCALE_KNOWN = 0.5  # floor of s_g for groups with stated standard errors
MIN_SCALE_UNKNOWN = 1e-3  # floor of s_g / RMS(measured) for groups without
STEP_RESPONSE_BLOCK = 2.0  # s: time blocks of a step-response run used as CV groups


@dataclass
class ModelFit:
    """A model fitted to a Problem (SI values)."""

    robot: Robot
    free: list[str]
    values: dict[str, float]
    se: dict[str, float]
    f: np.ndarray  # predictions of every entry
    scale: dict[str, float]  # profiled noise scale s_g per group
    deviance: float
    J: np.ndarray  # d prediction / d parameter (n entries x p), unweighted, value units
    nfev: int = 0  # simulations the fit ran
    converged: bool = True

    def weights(self, problem: "Problem") -> np.ndarray:
        """1 / (s_g sigma_k) of every entry (0 where unused)."""
        s = np.array([self.scale.get(g, 1.0) for g in problem.group])
        w = 1.0 / (s * problem.sigma)
        return np.where(problem.used, w, 0.0)

    def residual(self, problem: "Problem") -> np.ndarray:
        """Measured minus predicted, in the entries' units."""
        return problem.y - self.f


class Problem(least_squares.Problem):
    """The measurement vector of some procedures of `obs` and its model predictions: every
    entry with a value is used, weighted by its stated standard error (1 without one, in a group
    of its own); each call's parameter sets at the simulator's sub-steps; a group becomes blind
    to a parameter once its difference step left it unchanged at two points."""

    def __init__(self, obs: Observations, procedures: Sequence[str] | None = None) -> None:
        self.obs = obs
        pred = Predictor(obs, procedures)
        self.procedures = pred.procedures
        t = pred.table.copy()
        y = pred.measured.astype(float)
        sig = pred.sigma.astype(float)
        known = np.isfinite(sig) & (sig > 0)
        base = (t["procedure"].astype(str) + "/" + t["signal"].astype(str)).to_numpy()
        super().__init__(pred, np.isfinite(y), np.where(known, sig, 1.0),
                         np.where(known, base, base + "/no-se").astype(object))
        # CV groups: whole run steps; a step-response run in time blocks
        step = t["step"].to_numpy()
        block = np.where(t["procedure"].to_numpy() == "step_response",
                         np.floor(np.nan_to_num(t["time"].to_numpy(float)) / STEP_RESPONSE_BLOCK), step)
        t["cv_group"] = t["run"].astype(str) + "#" + pd.Series(block).astype(int).astype(str)
        t["since_step"] = _time_since_duty_change(t)
        self.table = t
        self.groups = sorted(set(self.group[self.used]))
        # smallest noise scale a group may take: the stated standard errors may be pessimistic
        # by 2x at most; a group without them is not trusted below 0.1 % of its own size (four
        # energy runs fitted "exactly" would otherwise make any later parameter look decisive)
        self.floor = {}
        for g in self.groups:
            m = self.used & (self.group == g)
            self.floor[g] = (MIN_SCALE_KNOWN if not str(g).endswith("/no-se")
                             else MIN_SCALE_UNKNOWN * float(np.sqrt(np.mean(self.y[m] ** 2))) or 1e-12)
        #: per noise group: its used entries (mask) and their count, for `rss` (called per evaluation)
        self._masks = {g: (m, int(m.sum())) for g in self.groups for m in [self.used & (self.group == g)]}

    # ----------------------------------------------------------------- likelihood pieces
    def rss(self, f: np.ndarray) -> dict[str, tuple[float, int]]:
        """Per group: (sum of squared sigma-weighted residuals, count)."""
        z = (self.y - f) / self.sigma
        return {g: (float(np.sum(z[m] ** 2)), n) for g, (m, n) in self._masks.items()}

    def deviance(self, f: np.ndarray) -> float:
        """Profile deviance: sum_g (n_g - 1) log(s_g^2) + RSS_g / s_g^2 with s_g the profiled
        scale (= (n_g - 1) log(RSS_g / n_g) + n_g unless the scale sits at its floor)."""
        d = 0.0
        sc = self.scales(f)
        for g, (rss, n) in self.rss(f).items():
            if n >= 2:
                d += (n - 1) * math.log(sc[g] ** 2) + rss / sc[g] ** 2
        return d

    def scales(self, f: np.ndarray) -> dict[str, float]:
        """Profiled noise scale per group: sqrt(RSS_g / n_g), not below the group's floor."""
        out = {}
        for g, (rss, n) in self.rss(f).items():
            out[g] = max(math.sqrt(rss / max(n, 1)), self.floor.get(g, 1e-12), 1e-12)
        return out


def _time_since_duty_change(t: pd.DataFrame) -> np.ndarray:
    """For step-response entries: time since that wheel's duty last changed, s (NaN elsewhere)."""
    out = np.full(len(t), np.nan)
    sr = t["procedure"].to_numpy() == "step_response"
    if not sr.any():
        return out
    for _, idx in t[sr].groupby(["run", "wheel"]).groups.items():
        idx = np.asarray(list(idx))
        tt = t.loc[idx, "time"].to_numpy(float)
        uu = t.loc[idx, "u"].to_numpy(float)
        order = np.argsort(tt, kind="stable")
        last = tt[order[0]] if len(order) else np.nan
        prev = np.nan
        for k in order:
            if uu[k] != prev:
                last, prev = tt[k], uu[k]
            out[idx[k]] = tt[k] - last
    return out


def _robot_with_effect(robot: Robot, effect: Effect, values: Mapping[str, float] | None = None) -> Robot:
    """`robot` declaring `effect` (its fitted parameters at `values`, default zero = absent)."""
    # absent: every size at zero; a shape parameter that cannot be zero (a Stribeck speed) at its start
    specs = {p.name: p for p in effect.term.params}
    vals = {p: (0.0 if specs[p].lower <= 0.0 else float(effect.start.get(p, specs[p].default))) for p in effect.fit}
    vals.update(values or {})
    effects = {k: dict(v) for k, v in robot.effects.items()}
    effects[effect.name] = effect.params(vals)
    return robot.replace(effects=effects)


#: Weighted fits a model fit may take while its groups' scales settle. A candidate that removes a
#: large misfit shrinks its group's scale many-fold; stopped after two passes (as candidate fits
#: were), its data still count at the declared model's scale and other groups pull the effect
#: off: an undeclared deadband (u_0 0.03) in the lab's whole grid on the independent physics was
#: fitted at 0.023 +- 0.003 and rejected as explaining no structure; settled, 0.0300 +- 0.0001 and
#: the sweep's structure is gone. Fits whose scales settle at once stop after the first pass.
SETTLE_PASSES = 6


#: A candidate's fit (not the declared model's, nor an accepted model's polish) stops once a step
#: gains less than this much deviance, or moves the parameters by less than CANDIDATE_XTOL of
#: their scales: its likelihood ratio is judged against thresholds of 10-20 and AIC differences
#: of 2, and a step that gains 0.1 moves the parameters by ~0.3 SE. The tight tolerances (1e-7)
#: spent a third of the 2019 logs' candidate fits on steps that gained < 0.01, most of them
#: steps rejected one after another on latencies' staircase (a physics step) until the trust
#: region shrank to 1e-7.
CANDIDATE_DEVIANCE_TOL = 0.1
CANDIDATE_XTOL = 1e-4


def fit_model(problem: Problem, robot: Robot, free: Sequence[str], *, max_nfev: int = 20, passes: int = SETTLE_PASSES,
              scale: Mapping[str, float] | None = None,
              settled_enough: Callable[[float, float], bool] | None = None, candidate: bool = False) -> ModelFit:
    """Minimise the profile deviance over `free` (names as in fitting: a, b, ..., effect.param),
    re-weighting each group by its own residual scale until every scale settles within 2 % (at
    most `passes` weighted fits), or until `settled_enough(deviance before the pass, after it)`
    says further passes cannot change what the fit is for (a candidate that cannot pass).
    candidate: converge only as far as a candidate's test needs (CANDIDATE_DEVIANCE_TOL).

    `robot` is the start point and holds every fixed parameter."""
    free = list(free)
    # least_squares' cost is half the weighted RSS, ~ half the used entries at settled scales
    ftol = max(1e-7, CANDIDATE_DEVIANCE_TOL / max(int(problem.used.sum()), 1)) if candidate else 1e-7
    xtol = CANDIDATE_XTOL if candidate else 1e-7
    params = Parameters(robot, free)
    scl, lo, hi = params.scale, params.lower, params.upper
    x = np.clip(params.x_of(robot), lo, hi)
    used = problem.used
    steps = params.steps(FD_STEP)
    at = params.robot_at
    nfev0 = problem.nfev

    # Between settle passes only the weights change: the unweighted predictions and differences
    # at a point stay valid, so each is simulated once per fit (keyed by the point's bytes; the
    # next pass starts where the last stopped, and the final Jacobian is usually the last one).
    sims: dict[bytes, np.ndarray] = {}  # unweighted predictions at a point
    diffs: dict[bytes, np.ndarray] = {}  # unweighted forward differences there (p x n entries)

    def predicted(xv: np.ndarray) -> np.ndarray:
        key = xv.tobytes()
        if key not in sims:
            sims[key] = problem.predict([at(xv)])[0]
        return sims[key]

    def differences(xv: np.ndarray) -> np.ndarray:
        key = xv.tobytes()
        if key not in diffs:
            F = problem.stencil(params, xv, steps)
            sims[key] = F[0]
            diffs[key] = problem.differences(F, steps)
        return diffs[key]

    f0 = predicted(x)
    s = dict(scale) if scale else problem.scales(f0)
    converged = True
    dev_before = problem.deviance(f0)
    frozen: np.ndarray | None = None  # a settling pass's Jacobian: the differences where the last pass ended
    for k in range(passes):
        w = 1.0 / (np.array([s.get(g, 1.0) for g in problem.group]) * problem.sigma)
        # After an exact pass that converged but left the scales unsettled, the passes that only settle the
        # weights take their steps on the differences where that pass ended (the weights move,
        # the point barely): one simulation per step instead of a Jacobian. Once the scales
        # settle, an exact pass from there ends the fit (or starts the next round of settling),
        # so the fit ends, as before, at an optimum of its final weights with settled scales;
        # the last pass allowed is always exact.
        settling = frozen is not None and k < passes - 1

        def resid(xv: np.ndarray) -> np.ndarray:
            return ((problem.y - predicted(xv)) * w)[used]

        def jac(xv: np.ndarray) -> np.ndarray:
            # least_squares asks for the Jacobian where it has just evaluated the residual
            return -((frozen if settling else differences(xv)) * w).T[used]

        if free:
            sol = optimize.least_squares(resid, x, jac=jac, bounds=(lo, hi), method="trf", max_nfev=max_nfev,
                                         x_scale=1.0, ftol=ftol, xtol=xtol, gtol=1e-9)
            x = sol.x
            if not settling:
                converged = converged and sol.status > 0
        f0 = predicted(x)
        s_new = problem.scales(f0)
        settled = all(abs(s_new[g] / s.get(g, 1.0) - 1) < 0.02 for g in s_new)
        s = s_new
        if settling:
            if settled:  # an exact pass next: at these weights, from where the settling ended
                frozen = None
            continue
        if settled:
            break
        dev_after = problem.deviance(f0)
        if settled_enough is not None and settled_enough(dev_before, dev_after):
            break
        dev_before = dev_after
        if free and sol.status > 0:  # settle on this Jacobian only from a converged pass: near its optimum
            frozen = differences(x)
    fitted = at(x)
    # Jacobian at the solution (value units) and covariance from the profiled weights
    if free:
        J = differences(x).T / scl
        f0 = sims[x.tobytes()]
    else:
        J = np.zeros((len(problem), 0))
    w = 1.0 / (np.array([s.get(g, 1.0) for g in problem.group]) * problem.sigma)
    if free:  # standard errors from each group's scale with the degrees of freedom the fit used
        w = w / _dof_factor(problem, J, w, f0, s)
    Jw = (J * w[:, None])[used]
    se = {p: float("nan") for p in free}
    if free:  # cluster-robust over the CV groups: step-response residuals correlate in time;
        # and never below what the encoder's rounding, revisited by a periodic motion, leaves
        rw = ((problem.y - f0) * w)[used]
        robust = cluster_se(Jw, rw, problem.table["cv_group"].to_numpy()[used])
        rounding = encoder_se(problem, f0, Jw, w)
        if rounding is not None:
            robust = np.maximum(robust, rounding)
        for p, v in zip(free, robust):
            se[p] = float(v)
    return ModelFit(robot=fitted, free=free, values={p: param_value(fitted, p) for p in free}, se=se, f=f0,
                    scale=s, deviance=problem.deviance(f0), J=J, nfev=problem.nfev - nfev0,
                    converged=converged)


def _dof_factor(problem: Problem, J: np.ndarray, w: np.ndarray, f: np.ndarray, s: Mapping[str, float]) -> np.ndarray:
    """Per entry: the group's scale with its degrees of freedom over the profiled one (>= 1).

    The profiled scale s_g^2 = RSS_g / n_g is the maximum-likelihood value, biased low by the
    parameters the group's own entries pin down: three energy runs that fix I_q leave two
    degrees of freedom, not three. For the standard errors the group's scale is
    sqrt(RSS_g / (n_g - H_g)), H_g the sum of the group's leverages in the weighted fit (the
    textbook unbiased estimate when one group holds all the data), never below its floor."""
    used = problem.used
    Jw = (J * w[:, None])[used]
    h = np.zeros(len(problem))
    if Jw.shape[1]:
        Q, _ = np.linalg.qr(Jw)
        h[used] = np.sum(Q ** 2, axis=1)
    out = np.ones(len(problem))
    rss = problem.rss(f)
    for g, (r, n) in rss.items():
        m = used & (problem.group == g)
        H = float(h[m].sum())
        if n - H < 1.0:
            continue
        s_dof = max(math.sqrt(r / (n - H)), problem.floor.get(g, 1e-12), 1e-12)
        out[m] = max(s_dof / s.get(g, 1.0), 1.0)
    return out


@dataclass
class Screen:
    """First-order (score-test) look at every candidate from the current fit."""

    approx_lr: dict[str, float]
    estimate: dict[str, dict[str, float]]
    #: how much of the candidate's sensitivity the current model's own parameters cannot mimic
    #: (norm after / before projecting their directions out): 0 when it changes no prediction
    #: in these data, ~0 when the change equals a change of the fitted parameters
    distinct: dict[str, float]
    #: the approximate LR with the estimate held in the effect's physical range (bounded least
    #: squares on the same linearisation): what a physical value of the effect can gain to first
    #: order. diagnosis fits neither a candidate nor a pair's second effect (which starts from
    #: the estimate clipped into the range, `fit_candidates`) whose LR holds only outside it
    in_range: dict[str, float] = field(default_factory=dict)
    #: the exact LR at the candidate's closed-form start from the sweep (`data_points`), for the
    #: candidates that have one: approx_lr (and estimate, in_range) take it where it is larger
    data_lr: dict[str, float] = field(default_factory=dict)


def secant_steps(effect: Effect) -> dict[str, float]:
    """Size of the step used to probe each fitted parameter (its `start`, else a quarter of the
    largest realistic size among the effect's parameters of the same unit)."""
    out = {}
    for p in effect.fit:
        unit = effect.term.params[effect.term.param_names.index(p)].unit
        same = [abs(v) for k, v in effect.example.items()
                if effect.term.params[effect.term.param_names.index(k)].unit == unit]
        big = max(same, default=0.0) or max((abs(v) for v in effect.example.values()), default=1.0) or 1.0
        out[p] = effect.start.get(p) or 0.25 * big
    return out


def screen(problem: Problem, current: ModelFit, candidates: Sequence[Effect]) -> Screen:
    """Approximate LR of each candidate: the weighted residual projected on the candidate's
    secant sensitivities, orthogonal to the current model's own parameter directions."""
    robots = []
    cols: list[tuple[str, str, float]] = []
    for eff in candidates:
        for p, h in secant_steps(eff).items():
            robots.append(_robot_with_effect(current.robot, eff, {p: h}))
            cols.append((eff.name, p, h))
    F = problem.predict(robots) if robots else np.zeros((0, len(problem)))
    w = current.weights(problem)
    used = problem.used
    r = ((problem.y - current.f) * w)[used]
    Jb = (current.J * w[:, None])[used]
    # residual and candidate columns with the current model's directions projected out
    if Jb.shape[1]:
        Q, _ = np.linalg.qr(Jb)
        proj = lambda v: v - Q @ (Q.T @ v)  # noqa: E731
    else:
        proj = lambda v: v  # noqa: E731
    r_perp = proj(r)
    groups = problem.group[used]
    masks = [(m, int(m.sum())) for m in (groups == g for g in problem.groups)]

    def lr_of(new: np.ndarray) -> float:
        # change of the profile deviance, group by group (a small group that the candidate
        # explains entirely counts as much as it would in the exact test)
        return sum((n - 1) * math.log(max(float(r[m] @ r[m]), 1e-300) / max(float(new[m] @ new[m]), 1e-12 * n))
                   for m, n in masks if n >= 2)

    out, est, distinct, in_range = {}, {}, {}, {}
    for eff in candidates:
        idx = [k for k, c in enumerate(cols) if c[0] == eff.name]
        raw = np.stack([((F[k] - current.f) / cols[k][2] * w)[used] for k in idx], axis=1)
        A = np.stack([proj(raw[:, i]) for i in range(raw.shape[1])], axis=1)
        size = float(np.linalg.norm(raw))
        distinct[eff.name] = float(np.linalg.norm(A)) / size if size > 0 else 0.0
        coef, *_ = np.linalg.lstsq(A, r_perp, rcond=None)
        moves = bool(np.any(np.abs(A) > 0))
        out[eff.name] = max(lr_of(r_perp - A @ coef), 0.0) if moves else 0.0
        est[eff.name] = {cols[k][1]: float(c) for k, c in zip(idx, coef)}
        spec = [eff.term.params[eff.term.param_names.index(cols[k][1])] for k in idx]
        lo, hi = np.array([q.lower for q in spec], float), np.array([q.upper for q in spec], float)
        if not moves:
            in_range[eff.name] = 0.0
        elif np.all((coef >= lo) & (coef <= hi)):
            in_range[eff.name] = out[eff.name]
        else:
            inside = optimize.lsq_linear(A, r_perp, bounds=(lo, hi)).x
            in_range[eff.name] = max(lr_of(r_perp - A @ inside), 0.0)
    # where the physics gives the candidate's values in closed form, its LR there too: an exact
    # deviance drop at a point of the extended model, so never above the fitted LR. The first-order
    # test cannot stand in for it when the candidate's fit moves the declared coefficients far (the
    # README deadband campaign: R_a 3.5 -> 1.85 ohm, c 0.0049 -> 0.01): 99.9 % of the deadband's
    # secant is the fitted coefficients' directions, and whether the rest reads as a dead zone
    # (firmware actuation: estimate u_0 = -0.0001, LR 0.01) or not is chance
    data_lr = {}
    for eff in candidates:
        pts = data_points(problem, current, eff, dict(eff.start))
        if not pts:
            continue
        dev, st = min(((problem.deviance(f), st) for _, st, f in pts), key=lambda x: x[0])
        data_lr[eff.name] = max(current.deviance - dev, 0.0)
        if data_lr[eff.name] > out[eff.name]:
            out[eff.name] = data_lr[eff.name]
            est[eff.name] = {p: float(st[p]) for p in eff.fit if p in st}
            in_range[eff.name] = max(in_range[eff.name], data_lr[eff.name])
    return Screen(out, est, distinct, in_range, data_lr)


def fit_candidate(problem: Problem, current: ModelFit, effect: Effect, estimate: Mapping[str, float] | None = None,
                  *, max_nfev: int = 15, needed: float | None = None) -> ModelFit:
    """Refit the current model's parameters together with `effect`'s, starting from the screen's
    estimate (clipped into the parameter bounds) or the effect's `start`, and from each of the
    effect's `restarts`: the fit of least deviance. Where a closed form gives the effect's values
    from the data (`data_start`), the start is that one, with one Gauss-Newton step for the
    parameters it leaves, if it fits the data better than the screen's (three simulations).
    needed: the likelihood ratio the candidate must reach; settling stops once it cannot (`hopeless`)."""
    start = dict(effect.start)
    if estimate:
        for p, v in estimate.items():
            lo, hi = effect.term.params[effect.term.param_names.index(p)].lower, \
                effect.term.params[effect.term.param_names.index(p)].upper
            if math.isfinite(v) and lo <= v <= hi and v != 0.0:
                start[p] = v
    free = list(current.free) + [f"{effect.name}.{p}" for p in effect.fit]
    base = current.robot
    pts = data_points(problem, current, effect, start)
    if pts:
        f_s = problem.predict([_robot_with_effect(base, effect, start)])[0]
        starts = [(base, start, f_s), *pts]
        # kept where it fits the data better than the screen's start
        base, start, _ = starts[int(np.argmin([problem.deviance(f) for _, _, f in starts]))]
    # the current fit's noise scales describe its own residuals, not a start that moved its
    # parameters: there the first pass weighs the groups by the start's (the README deadband
    # campaign's forward-run wheel speeds, 0.35 mrad/s rms in the declared fit, otherwise held a
    # data start's first pass to its evaluation limit)
    scale = current.scale if base is current.robot else None
    best = None
    lead: list[float] = []  # the best start's deviance after each of its passes, then its final one
    for st in _restarts(effect, start):
        robot = _robot_with_effect(base, effect, st)
        trail: list[float] = []
        f = fit_model(problem, robot, free, max_nfev=max_nfev, scale=scale, candidate=True,
                      settled_enough=_behind(trail, lead, None if needed is None else hopeless(current.deviance, needed)))
        if best is None or f.deviance < best.deviance:
            best, lead = f, trail + [f.deviance]
    assert best is not None, "_restarts yields the start point at least"
    return best


def _behind(trail: list[float], lead: Sequence[float],
            then: Callable[[float, float], bool] | None) -> Callable[[float, float], bool]:
    """fit_model's `settled_enough` for a restart: records its deviance after each pass in
    `trail`, and stops its settle passes once it is behind the best start's fit after as many
    passes (`lead`; [] for the first start), or when `then` says so. The starts that end in the
    same minimum differ after their first pass by up to ~50 in deviance, those that end in a
    better one were ahead already (the Stribeck speed 0.5 world: 253 against 263 after the first
    pass, 249 against 259 at the end); the settle passes of those behind were half of the
    Stribeck candidate's CPU."""
    def done(before: float, after: float) -> bool:
        trail.append(after)
        if lead and after > lead[min(len(trail) - 1, len(lead) - 1)]:
            return True
        return then is not None and then(before, after)
    return done


#: A candidate's settle passes stop when its likelihood ratio so far, plus HOPELESS_GAIN times the
#: last pass's deviance drop (the passes' drops shrink: re-weighting converges), stays below
#: HOPELESS_FRACTION of the ratio it needs: the passes cannot make it pass (README campaign's
#: latencies on the deadband runs: LR 0.0-2.3 of 19-24 needed after pass one; passes two and three
#: cost 23-62 s of CPU each and moved the LR by < 0.1).
HOPELESS_GAIN = 2.0
HOPELESS_FRACTION = 0.5


def hopeless(reference: float, needed: float) -> Callable[[float, float], bool]:
    """fit_model's `settled_enough` for a candidate against the current model's deviance
    `reference`: True when LR + HOPELESS_GAIN x (the pass's drop, from at most `reference`)
    < HOPELESS_FRACTION x `needed`."""
    def done(before: float, after: float) -> bool:
        gain = max(min(before, reference) - after, 0.0)
        return (reference - after) + HOPELESS_GAIN * gain < HOPELESS_FRACTION * needed
    return done


#: the ground's torque terms (roller-axis friction, rolling resistance): no current is logged where they act
GROUND_TORQUES = ("a_r", "b_r", "C_r")


def data_start(problem: Problem, current: ModelFit, effect: Effect) -> dict[str, float]:
    """Start values ('effect.param' and the core parameters it trades against) that the effect's
    closed form (`Effect.sweep_start`) gives from the sweep for `effect` in its form, {} when it
    has none or gives none. The shifted deadband's, from the sweep's voltage balance (u_0, R_a,
    k_e) and torque balance (a, b, c): the declared fit's R_a took up the dead zone's offset, and
    from it the fit crept along the valley of u_0 with R_a and the Coulomb term, every settle
    pass to its evaluation limit."""
    if effect.sweep_start is None or "sweep" not in problem.procedures:
        return {}
    got = effect.sweep_start(problem.obs.table("sweep"), effect.fixed, current.robot)
    if not got:
        return {}
    out = {(f"{effect.name}.{k}" if k in effect.fit else k): float(v) for k, v in got.items()}
    # the ground runs log no current: the current fit knows their roller and rolling friction only
    # through R_a x torque (on the README's deadband campaign R_a 3.51 with half of each), so
    # they keep that product
    if "R_a" in current.values and "R_a" in got:
        k = current.values["R_a"] / got["R_a"]
        out.update({p: current.values[p] * k for p in GROUND_TORQUES if p in current.values})
    return out


def data_points(problem: Problem, current: ModelFit, effect: Effect,
                start: Mapping[str, float]) -> list[tuple[Robot, dict[str, float], np.ndarray]]:
    """The candidate at its closed-form start (`data_start`; `start` for the effect's parameters it
    does not give) and after one Gauss-Newton step there of the current fit's parameters it leaves
    (the current fit's Jacobian): [(robot, effect values, predictions)] of the two (two
    simulations), [] when the effect has no closed form for these data."""
    free = list(current.free) + [f"{effect.name}.{p}" for p in effect.fit]
    data = {k: v for k, v in data_start(problem, current, effect).items() if k in free}
    if not data:
        return []
    robot_d = with_params(current.robot, {k: v for k, v in data.items() if "." not in k})
    start_d = {**start, **{k.split(".", 1)[1]: v for k, v in data.items() if "." in k}}
    rest = [k for k, p in enumerate(current.free) if p not in data]
    f_d = problem.predict([_robot_with_effect(robot_d, effect, start_d)])[0]
    w = current.weights(problem)
    used = problem.used
    step, *_ = np.linalg.lstsq((current.J[:, rest] * w[:, None])[used], ((problem.y - f_d) * w)[used], rcond=None)
    robot_g = with_params(robot_d, {current.free[k]: float(np.clip(param_value(robot_d, current.free[k]) + dv,
                                                                   *param_bounds(robot_d, current.free[k])))
                                    for k, dv in zip(rest, step)})
    f_g = problem.predict([_robot_with_effect(robot_g, effect, start_d)])[0]
    return [(robot_d, start_d, f_d), (robot_g, start_d, f_g)]


def _restarts(effect: Effect, start: Mapping[str, float]) -> list[dict[str, float]]:
    """The start point, then every combination of it with the alternative values of the
    effect's `restarts` parameters (a valley between two parameters is left only jointly)."""
    out = [dict(start)]
    for p, values in effect.restarts.items():
        out += [{**o, p: float(v)} for o in list(out) for v in values if v != start.get(p)]
    return out


def fit_candidates(problem: Problem, current: ModelFit, effects: Sequence[Effect],
                   starts: Sequence[Mapping[str, float]], *, max_nfev: int = 20,
                   needed: tuple[float, float] | None = None) -> ModelFit:
    """Refit the current model's parameters together with several effects at once (a pair),
    each starting from `starts` (values by 'effect.param', e.g. their single refits).
    needed: (reference deviance, likelihood ratio the pair must reach below it); settling
    stops once it cannot (`hopeless`): a pair must beat its lead effect's own fit."""
    robot = current.robot
    free = list(current.free)
    for eff, st in zip(effects, starts):
        vals = dict(eff.start)
        vals.update({k.split(".", 1)[1]: v for k, v in st.items() if k.startswith(eff.name + ".")})
        robot = _robot_with_effect(robot, eff, vals)
        free += [f"{eff.name}.{p}" for p in eff.fit]
    return fit_model(problem, robot, free, max_nfev=max_nfev, scale=current.scale, candidate=True,
                     settled_enough=None if needed is None else hopeless(*needed))


def lr_test(base: ModelFit, alt: ModelFit, q: int) -> tuple[float, float]:
    """(LR statistic, p-value) of a nested model with q extra parameters."""
    lr = max(base.deviance - alt.deviance, 0.0)
    return lr, chi2_sf(lr, q)


# ------------------------------------------------------------------------- held-out error
def cv_folds(problem: Problem, k: int = CV_FOLDS, seed: int = 0) -> np.ndarray:
    """Fold index (0..k-1) of every entry: whole run steps (step-response time blocks) kept
    together, assigned at random with every procedure spread over the folds."""
    fold = np.zeros(len(problem), dtype=int)
    rng = np.random.default_rng(seed)
    t = problem.table
    for proc in t["procedure"].unique():
        m = (t["procedure"] == proc).to_numpy()
        groups = sorted(t.loc[m, "cv_group"].unique())
        order = rng.permutation(len(groups))
        kk = min(k, len(groups))
        assign = {groups[i]: n % kk for n, i in enumerate(order)} if kk > 1 else {g: -1 for g in groups}
        fold[m] = t.loc[m, "cv_group"].map(assign).to_numpy()
    return fold


def heldout_residuals(problem: Problem, fit: ModelFit, folds: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Held-out residual of every entry (units of the entry): the fit without the entry's fold,
    by one weighted Gauss-Newton step from the full-data fit. NaN where an entry has no fold
    (a procedure with a single step cannot be held out)."""
    w = fit.weights(problem) if weights is None else weights
    r = fit.residual(problem)
    out = np.full(len(problem), np.nan)
    used = problem.used
    for k in sorted(set(folds[used & (folds >= 0)])):
        tr = used & (folds != k)
        ho = used & (folds == k)
        if fit.J.shape[1]:
            A = fit.J[tr] * w[tr, None]
            delta, *_ = np.linalg.lstsq(A, r[tr] * w[tr], rcond=None)
            out[ho] = r[ho] - fit.J[ho] @ delta
        else:
            out[ho] = r[ho]
    return out


def error_table(problem: Problem, residual: np.ndarray) -> dict[str, dict[str, Any]]:
    """Per procedure: nrmse (RMS residual / RMS measured, combined over its signals as an RMS)
    and per signal the RMS residual in its unit."""
    t = problem.table
    out: dict[str, dict[str, Any]] = {}
    for proc in t["procedure"].unique():
        sig_rows = {}
        ratios = []
        for sig in t.loc[t["procedure"] == proc, "signal"].unique():
            m = ((t["procedure"] == proc) & (t["signal"] == sig)).to_numpy() & np.isfinite(residual) & problem.used
            if not m.any():
                continue
            rms = float(np.sqrt(np.mean(residual[m] ** 2)))
            den = float(np.sqrt(np.mean(problem.y[m] ** 2)))
            unit = str(t.loc[m, "unit"].iloc[0])
            sig_rows[str(sig)] = {"rms": rms, "unit": unit, "n": int(m.sum())}
            if den > 0:
                ratios.append(rms / den)
        if sig_rows:
            out[str(proc)] = {"nrmse": float(np.sqrt(np.mean(np.square(ratios)))) if ratios else float("nan"),
                              "signals": sig_rows}
    return out


def cv_score(problem: Problem, residual: np.ndarray, weights: np.ndarray) -> float:
    """Held-out weighted sum of squares (common weights for the models compared)."""
    m = problem.used & np.isfinite(residual)
    return float(np.sum((residual[m] * weights[m]) ** 2))
