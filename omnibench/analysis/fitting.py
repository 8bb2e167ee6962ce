"""Fit the model's coefficients to the bench's observations, with honest uncertainties and an
identifiability verdict per parameter.

Public API (used by `omnibench fit` and by the diagnosis)::

    fit(robot, obs, free=None, *, procedures=None) -> FitResult
    fit_per_wheel(robot, obs, free=("a", "b", "c")) -> dict[int, FitResult]     # III.i per wheel
    sweep_linear_estimate(robot, sweep) -> dict                                   # paper's III.i LS
    predict_observations(robot, obs, procedures=None) -> DataFrame
    error_by_procedure(robot, obs, procedures=None, kind="nrmse") -> dict[str, float]
    default_free(robot, obs, procedures=None) -> list[str]

Parameter names are the paper's symbols (`a, b, c, a_r, b_r, c_r, C_r`, motor constants
`k_t, k_e, R_a`, also `eta, I_0`) and `<effect>.<param>` for a parameter of an effect the robot
declares in `robot.effects` (e.g. `stribeck_friction.b_s`); their values, bounds, scales and
units are the least-squares engine's (omnibench.analysis.least_squares), as are the weighted
residuals and their Jacobian (`weighted_residuals`) that diagnose and the planner share.

Method. Every observation is predicted through the simulator (`Predictor`), so any declared
term takes part. The weighted residuals r_k = (y_k - f_k(theta)) / sigma_k are minimised with
scipy's trust-region least squares; the Jacobian comes from forward differences (a step of
least_squares.FD_STEP = 1e-5 of each scale, one physics step for a command latency), all
perturbed parameter sets simulated in one `simulate_batch` call. sigma_k is the observation's own
standard error (encoder rounding through the speed estimator at that speed and window,
omnibench.analysis.quantisation; current noise over the
averaged samples, the operator's tape noise), a sweep speed's evaluated at the fitted model's
speed once the joint fit has one (`speed_sigma_at_prediction`: at the step's own estimate it
follows that estimate's error); where a run does not give one (the 2019 sweep),
each (procedure, signal) group gets the RMS of its residuals from a first pass.

Uncertainties: cov = (J^T W J)^-1 J^T W S W J (J^T W J)^-1, where S scales each observation
group's (procedure/signal) variance by its own chi^2 per degree of freedom (the group's share of
the dof from the leverages). With one group this is the textbook s^2 (J^T W J)^-1 with
s^2 = chi^2 / dof; with several it keeps one under- or over-stated noise figure (or a group whose
residual has structure) from mis-sizing the intervals of parameters other groups determine.
Unmodelled structure therefore widens the intervals instead of hiding. Standard errors, 95 %
intervals from Student's t with dof degrees of freedom, the correlation matrix.

Identifiability (docs/fit.md, "Identifiability verdicts"): the weighted Jacobian of the requested parameters, columns
scaled to unit length, is decomposed (SVD). Its rank and condition number are reported. A
singular value below RANK_TOL x the largest is a combination the data cannot see: the
parameters that carry it are not identifiable, are held at their robot-file values and are
reported as such (with the combination), never with a number of their own. A fitted parameter
whose column is nearly collinear with a *fixed* motor constant (the sweep without current:
a and the back-EMF damping eta k_t k_e / R_a; forward runs: C_r and c b) is reported
`conditional`: its value holds only if the fixed constant is right.

Verdicts that cannot contradict the data (`Verdict`, `_final_verdicts`): the covariance is split
into each measurement group's share of each parameter's variance; a parameter a group determines
(DETERMINES_SHARE of its variance or more) is `model inadequate` while that group's chi^2/dof
against its stated noise is above MISFIT_S2 and significant (chi^2 tail probability below
MISFIT_P: `misfit_groups`, the groups `misses_something` and the notes name), and `consistent with zero` while its
95 % interval includes zero; neither is called identified.
"""

from __future__ import annotations

import datetime as _dt
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from scipy import optimize, special

from omnibench.analysis.least_squares import (
    WeightedResiduals,
    param_bounds,
    param_unit,
    param_value,
    weighted_residuals,
    with_params,
)
from omnibench.analysis.observations import Observations, sweep_speed_se
from omnibench.analysis.predictor import Predictor
from omnibench.errors import UserError

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

#: Singular values below this fraction of the largest are directions the data cannot see.
RANK_TOL = 1e-6
#: A free parameter and a fixed constant are "not separable" when adding the constant's column
#: leaves a singular value below this fraction of the largest.
CONFOUND_TOL = 1e-3
#: Sweep steady states slower than this (rad/s) are left out of the fit: wheel stuck, or creeping
#: in a stiction/deadband region the paper's model does not describe; about 1.5 x one encoder
#: count per 30 ms sample of the 2019 logs (0.21 rad/s). (It was 3 x the ground's sign width
#: `sign_width_phi` while that was 0.1 rad/s; the sweep runs with an exact sign, so the width has
#: no say upside down.)
MIN_SWEEP_SPEED = 0.3
#: Ground-run wheel speeds slower than this many sign widths (`sign_width_phi`) are left out of
#: the fit: the model's wheel creeps there where a real one sticks (a lateral run at 45 deg stops
#: two wheels; docs/robot-file.md). (Above it the wheel sign, tanh, is Coulomb's to 4e-9.)
MIN_GROUND_SPEED_WIDTHS = 10.0
#: Typical magnitudes (SI) used to scale parameters and finite-difference steps.
DEFAULT_PROCEDURES = ("sweep", "forward", "lateral")


# ----------------------------------------------------------------------------- parameters

#: degrees of freedom a group needs before its own noise scale weights it in the fit (a smaller
#: group's chi^2/dof is too uncertain to weight by: a chi^2_1 draw ranges 0.004-4 in practice)
REWEIGHT_MIN_DOF = 20


def _noise_reweighting(groups: np.ndarray, used: np.ndarray, r: np.ndarray, J: np.ndarray) -> np.ndarray | None:
    """Factor on each entry's sigma: sqrt(chi^2/dof) of its group where the group has at least
    REWEIGHT_MIN_DOF degrees of freedom (leverages from J), 1 elsewhere; None when nothing changes
    by more than 5 %."""
    try:
        A = np.linalg.pinv(J.T @ J)
    except np.linalg.LinAlgError:
        return None
    lev = np.einsum("ij,jk,ik->i", J, A, J)
    g_used = groups[used]
    fac = np.ones(len(groups))
    for g in np.unique(g_used):
        m = g_used == g
        dof_g = float(m.sum() - lev[m].sum())
        if dof_g >= REWEIGHT_MIN_DOF:
            fac[groups == g] = math.sqrt(max(float(np.sum(r[m] ** 2)) / dof_g, 1e-6))
    return fac if np.any(np.abs(fac - 1.0) > 0.05) else None

def default_free(robot: Robot, obs: Observations, procedures: Sequence[str] | None = None) -> list[str]:
    """The parameters each procedure present is designed to measure: sweep -> a, b, c (and k_e,
    R_a when currents were logged); forward -> C_r; lateral -> a_r, b_r, c_r; plus every
    parameter of the effects the robot declares."""
    procs = set(procedures or obs.procedures())
    free: list[str] = []
    if "sweep" in procs and len(obs.sweep):
        free += ["a", "b", "c"]
        if obs.has_current:
            free += ["k_e", "R_a"]
    if "forward" in procs and len(obs.forward):
        free += ["C_r"]
    if "lateral" in procs and len(obs.lateral):
        free += ["a_r", "b_r", "c_r"]
    for eff, params in robot.effects.items():
        free += [f"{eff}.{p}" for p in params]
    return free


# ----------------------------------------------------------------------------- result
@dataclass(frozen=True)
class Verdict:
    """Identifiability of one parameter. status, from the worst down:

    - 'not identifiable': the data cannot see it (held at its robot-file value, no SE);
    - 'at bound': the fit stopped on a physical bound or at zero (the data push it past what is
      physical; its SE means nothing);
    - 'model inadequate': estimated, but a measurement group that determines it
      (DETERMINES_SHARE of its variance or more) has chi^2/dof above MISFIT_S2 against its stated
      noise, and significantly so (`misfit_groups`): the declared model misses something in these runs, and the value (with its SE,
      widened by the misfit) is what this model makes of them, not a measurement of the coefficient;
    - 'consistent with zero': estimated, its 95 % interval includes zero;
    - 'conditional': identified only given a fixed constant it cannot be separated from;
    - 'identified'.

    `condition` keeps the 'conditional' reason when a worse status took its place."""

    status: str
    reason: str
    condition: str = ""

    @property
    def ok(self) -> bool:
        """Estimated, with a standard error of its own (not 'not identifiable', not 'at bound'):
        'model inadequate' and 'consistent with zero' keep their number and SE, but only
        'identified' is a coefficient the data measured without a caveat."""
        return self.status in ESTIMATED

    def __bool__(self) -> bool:
        return self.ok


#: Verdicts of parameters that were estimated with a standard error of their own (`Verdict.ok`).
ESTIMATED = ("identified", "conditional", "consistent with zero", "model inadequate")


@dataclass
class FitResult:
    """Everything a fit found (SI units). Parameters that are not identifiable keep their
    robot-file value in `values` and have NaN `se`/`ci95`; check `identifiable[name]`."""

    robot: Robot
    free: list[str]
    values: dict[str, float]
    se: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    cov: pd.DataFrame
    corr: pd.DataFrame
    condition_number: float
    rank: int
    identifiable: dict[str, Verdict]
    residuals: pd.DataFrame
    chi2: float
    dof: int
    runs_used: list[str]
    procedures: list[str]
    s2: float = 1.0
    #: chi^2 per degree of freedom of each "procedure/signal" group (used to scale its noise)
    group_s2: dict[str, float] = field(default_factory=dict)
    #: degrees of freedom of each group (entries less their leverage): how far its chi^2/dof can be trusted
    group_dof: dict[str, float] = field(default_factory=dict)
    #: per fitted parameter: each group's share of its variance (the groups that determine it)
    variance_share: dict[str, dict[str, float]] = field(default_factory=dict)
    #: groups whose noise was estimated from their own residual (no stated noise: no chi^2 test)
    unstated_noise: list[str] = field(default_factory=list)
    initial: dict[str, float] = field(default_factory=dict)
    fixed: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    confounded: list[dict[str, Any]] = field(default_factory=list)
    #: per "procedure/signal" group: lag-1 autocorrelation of the residuals ordered by speed
    #: (rho, pairs, z = rho sqrt(pairs), rms, unit); z > STRUCTURE_Z flags structure
    structure: dict[str, dict[str, Any]] = field(default_factory=dict)
    nfev: int = 0
    date: str = ""
    #: digest of what the fit saw (`fit_digest`): a model file's [fit] table carries it, so that
    #: diagnose can tell that a model was fitted to exactly its runs and need not fit it again
    digest: str = ""

    @property
    def fitted(self) -> list[str]:
        """Parameters that were estimated (identifiable ones)."""
        return [p for p in self.free if p not in self.fixed]

    def misses_something(self) -> list[str]:
        """Why the declared model does not fit these data (the fit's own flags, as in its notes and
        verdicts): the misfit groups (`misfit_groups`: chi^2/dof above MISFIT_S2 against the
        stated noise, and significant; overall too, though the overall figure is about 1 once
        large groups are weighted by their own noise), or a group whose residuals are smooth along
        speed (z above STRUCTURE_Z). Empty when none."""
        bad = misfit_groups(self.group_s2, self.group_dof, self.unstated_noise, self.s2, self.dof)
        out = [f"chi2/dof {v:.3g}" if g == ALL_OBSERVATIONS else f"{g}: chi2/dof {v:.3g} against its stated noise"
               for g, v in bad.items()]
        out += [f"{g}: residual structure {st['z']:.1f} sigma" for g, st in (self.structure or {}).items()
                if st["z"] > STRUCTURE_Z]
        return out

    def inadequate(self) -> list[dict[str, Any]]:
        """The measurement groups that do not fit (`misfit_groups`), worst first: group, chi2_dof
        (against the stated noise), dof, the parameters it determines (name -> share of its
        variance, DETERMINES_SHARE or more: their verdict is 'model inadequate'; none when the fit
        weighted the group down so far by its own noise that it determines nothing) and `text`,
        that in one line."""
        out = []
        for g, v in misfit_groups(self.group_s2, self.group_dof, self.unstated_noise, self.s2, self.dof).items():
            det = {p: _share_of(self.variance_share.get(p, {}), g) for p in self.fitted}
            det = {p: sh for p, sh in sorted(det.items(), key=lambda x: -x[1]) if sh >= DETERMINES_SHARE
                   and self.identifiable[p].status == "model inadequate"}
            dof = float(self.dof if g == ALL_OBSERVATIONS else self.group_dof.get(g, 0.0))
            which = ", ".join(f"{p} ({100 * sh:.0f} %{' of its variance' if k == 0 else ''})"
                              for k, (p, sh) in enumerate(det.items()))
            what = (f"every coefficient ({', '.join(det)})" if g == ALL_OBSERVATIONS and det else
                    f"determines {which}" if det else
                    f"it determines no coefficient (weighted by its own noise, under "
                    f"{100 * DETERMINES_SHARE:.0f} % of any variance)")
            out.append({"group": g, "chi2_dof": v, "dof": dof, "determines": det,
                        "text": f"{g}: chi2/dof {chi2_text(v)} against its stated noise on {dof:.0f} dof; {what}"})
        return out

    def summary_rows(self) -> list[dict[str, Any]]:
        rows = []
        for p in self.free:
            v = self.identifiable[p]
            rows.append({"name": p, "value": self.values[p], "se": self.se[p], "ci95": self.ci95[p],
                         "unit": param_unit(self.robot, p), "identifiable": v.ok, "verdict": v.status,
                         "reason": v.reason})
        return rows

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict: parameters (name -> value, se, ci95, identifiable, verdict, reason), the
        correlation matrix, condition number, rank, chi2, dof, each group's chi2/dof and dof, each
        parameter's variance share by group, the misfit groups (`inadequate`), runs used, notes."""
        def f(x: float) -> float | None:
            return float(x) if x is not None and math.isfinite(x) else None

        return {
            "parameters": {r["name"]: {"value": f(r["value"]), "se": f(r["se"]),
                                       "ci95": [f(r["ci95"][0]), f(r["ci95"][1])], "unit": r["unit"],
                                       "identifiable": r["identifiable"], "verdict": r["verdict"],
                                       "reason": r["reason"]} for r in self.summary_rows()},
            "correlation": {a: {b: f(self.corr.loc[a, b]) for b in self.corr.columns} for a in self.corr.index},
            "condition_number": f(self.condition_number), "rank": int(self.rank),
            "n_parameters": len(self.free), "chi2": f(self.chi2), "dof": int(self.dof), "s2": f(self.s2),
            "group_s2": {k: f(v) for k, v in self.group_s2.items()},
            "group_dof": {k: f(v) for k, v in self.group_dof.items()},
            "variance_share": {p: {g: f(v) for g, v in sh.items()} for p, sh in self.variance_share.items()},
            "inadequate": self.inadequate(),
            "runs_used": list(self.runs_used), "procedures": list(self.procedures),
            "confounded": self.confounded, "notes": list(self.notes),
            "structure": {g: {k: (f(v) if isinstance(v, float) else v) for k, v in st.items()}
                          for g, st in self.structure.items()},
            "error_by_procedure": {k: f(v) for k, v in _nrmse_table(self.residuals[self.residuals["used"]]).items()},
        }

    def table(self) -> str:
        """A plain-text table a lab engineer reads."""
        lines = [f"{'parameter':<22} {'value':>12} {'SE':>10} {'95% interval':>27}  unit        verdict"]
        for r in self.summary_rows():
            if r["identifiable"] and math.isfinite(r["se"]):
                lo, hi = r["ci95"]
                lines.append(f"{r['name']:<22} {r['value']:>12.5g} {r['se']:>10.3g} [{lo:>11.5g}, {hi:>11.5g}]  "
                             f"{r['unit']:<11} {r['verdict']}")
            else:
                lines.append(f"{r['name']:<22} {'--':>12} {'--':>10} {'':>27}  {r['unit']:<11} {r['verdict']}")
            if r["verdict"] != "identified":
                lines.append(f"    {r['reason']}")
        lines.append(f"condition number {self.condition_number:.3g}, rank {self.rank} of {len(self.free)}, "
                     f"chi2 {self.chi2:.1f} on {self.dof} dof (s^2 = {self.s2:.3g})")
        return "\n".join(lines)


# ----------------------------------------------------------------------------- III.i closed form
def sweep_linear_estimate(robot: Robot, sweep: pd.DataFrame) -> dict[str, float]:
    """The paper's III.i least squares in the torque domain (a fast closed form; start values).

    Steady state upside down: tau_motor = (1 + c F_N)(a omega + b sign omega), with tau_motor =
    eta k_t i when the current was logged, else eta k_t (u V_batt - k_e omega) / R_a (V_batt the
    logged supply of the step where there is one, else the robot's). Linear in (a, b) at a given
    c, which is searched over its physical range; returns a, b, c (0 when a single load cannot
    separate it) and `n` rows used."""
    df = sweep[np.abs(sweep["omega"]) > MIN_SWEEP_SPEED]
    if len(df) < 2:
        return {"a": robot.a, "b": robot.b, "c": robot.c, "n": len(df)}
    w = df["omega"].to_numpy(float)
    F = df["F_N"].to_numpy(float)
    cur = df["current"].to_numpy(float)
    if np.isfinite(cur).all():
        y = robot.eta * robot.k_t * cur
    else:
        v = df["V_batt"].to_numpy(float) if "V_batt" in df else np.full(len(df), np.nan)
        v = np.where(np.isfinite(v) & (v > 0), v, robot.V_batt)  # the logged supply where there is one
        y = robot.eta * robot.k_t * (df["u"].to_numpy(float) * v - robot.k_e * w) / robot.R_a
    s = np.sign(w)
    multi = np.ptp(F) > 1e-6 * max(1.0, float(np.max(F)))
    X = np.column_stack([w, s])
    if not multi:
        (a, b), *_ = np.linalg.lstsq(X, y, rcond=None)
        return {"a": max(float(a), 0.0), "b": max(float(b), 0.0), "c": 0.0, "n": len(df)}

    # Two loads or more: y = (1 + c F)(a w + b s) is linear in (a, b) for a given c (variable
    # projection), so only c is searched. The four-column form (w, s, F w, F s) would need every
    # load at two speeds or more: with a second load at one level only (the design's diagnostic
    # floor) it is rank-deficient and its minimum-norm answer is far off (a 0, b 20 x too large).
    def solve(c: float) -> tuple[float, np.ndarray]:
        g = 1.0 + c * F
        ab, *_ = np.linalg.lstsq(X * g[:, None], y, rcond=None)
        r = y - (X * g[:, None]) @ ab
        return float(r @ r), ab

    grid = np.concatenate([[0.0], np.geomspace(1e-5, param_bounds(robot, "c")[1], 60)])
    k = int(np.argmin([solve(c)[0] for c in grid]))
    lo_c, hi_c = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    c = float(optimize.minimize_scalar(lambda x: solve(x)[0], bounds=(lo_c, hi_c), method="bounded",
                                       options={"xatol": 1e-12 * max(hi_c, 1e-9)}).x) if hi_c > lo_c else lo_c
    a, b = (float(v) for v in solve(c)[1])
    return {"a": max(a, 0.0), "b": max(b, 0.0), "c": max(c, 0.0), "n": len(df)}


# ----------------------------------------------------------------------------- the fit
def _usable(pred: Predictor, robot: Robot) -> np.ndarray:
    t = pred.table
    ok = np.isfinite(pred.measured)
    sw = (t["procedure"] == "sweep").to_numpy()
    slow = sw & (np.abs(t["speed"].to_numpy(float)) < MIN_SWEEP_SPEED)
    return ok & ~slow & ~creeping_ground_speeds(t, pred.measured, robot)


def creeping_ground_speeds(t: pd.DataFrame, speed: np.ndarray, robot: Robot) -> np.ndarray:
    """Ground-run wheel-speed entries slower than MIN_GROUND_SPEED_WIDTHS sign widths (`speed`:
    measured, or predicted where the planner asks)."""
    ground_w = t["procedure"].isin(["forward", "lateral"]).to_numpy() & (t["signal"] == "w").to_numpy()
    with np.errstate(invalid="ignore"):
        return ground_w & (np.abs(speed) < MIN_GROUND_SPEED_WIDTHS * robot.sign_width_phi)


def _scaled_svd(J: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    norms = np.linalg.norm(J, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    _, s, Vt = np.linalg.svd(J / norms, full_matrices=False)
    return s, Vt, norms


def _null_analysis(J: np.ndarray, names: list[str]) -> tuple[int, float, list[tuple[float, dict[str, float]]]]:
    """Rank, condition number and the near-null combinations {name: weight} of a Jacobian."""
    if J.shape[1] == 0:
        return 0, 1.0, []
    colnorm = np.linalg.norm(J, axis=0)
    zero = colnorm <= 1e-12 * max(1.0, float(colnorm.max()))
    s, Vt, _ = _scaled_svd(J)
    smax = s[0] if len(s) and s[0] > 0 else 1.0
    rank = int(np.sum(s > RANK_TOL * smax)) - int(zero.sum() and 0)
    cond = float(smax / s[-1]) if s[-1] > 0 else math.inf
    null = []
    for k in range(len(s)):
        if s[k] <= RANK_TOL * smax:
            v = Vt[k]
            null.append((float(s[k] / smax), {names[i]: float(v[i]) for i in range(len(names)) if abs(v[i]) > 0.2}))
    return rank, cond, null


#: When a combination is invisible, which of its parameters to hold fixed first (lower first).
def _fix_priority(name: str) -> int:
    """Motor constants first, then parameters of declared effects (they add to the paper's
    terms), then the paper's coefficients, load factors before the friction levels."""
    order = ["k_t", "eta", "R_a", "k_e", "I_0", "<effect>", "c", "c_r", "C_r", "a", "a_r", "b_r", "b"]
    return order.index("<effect>" if "." in name else name) if ("." in name or name in order) else len(order)


def _add_condition(verdicts: dict[str, Verdict], name: str, reason: str) -> None:
    """Mark `name` conditional (reasons accumulate; 'not identifiable' stays)."""
    v = verdicts.get(name)
    if v is None or v.status == "identified":
        verdicts[name] = Verdict("conditional", reason, condition=reason)
    elif v.status == "conditional":
        verdicts[name] = Verdict("conditional", f"{v.reason}; {reason}", condition=f"{v.reason}; {reason}")


def _combination(weights: Mapping[str, float]) -> str:
    return " ".join(f"{'+' if w >= 0 else '-'} {abs(w):.2f} {n}" for n, w in weights.items()).lstrip("+ ")


#: Warm-start order and the parameters each procedure is designed to measure (paper III.i-iii).
STAGES = (("sweep", {"a", "b", "c", "k_t", "k_e", "R_a", "eta"}), ("forward", {"C_r"}),
          ("lateral", {"a_r", "b_r", "c_r"}))


#: Each least-squares solve of the fit stops once a step gains less than this much deviance
#: (chi^2 of the weighted residuals; scipy's relative ftol is this over the number of residuals,
#: the cost at weights that describe the noise being half that number). A gain of 0.01 is a
#: parameter step of ~0.1 SE at most; the steps it leaves out moved the parameters by < 0.0002 SE
#: (issue 34: on a clean campaign's runs every value the same to 1.4e-4 SE, the SEs to 2e-6, the
#: fit 5.2 -> 4.1 s of CPU; ftol 1e-7 alone had taken one or two steps more per solve, each
#: gaining < 1e-4 with a Jacobian of ~10 simulations).
FIT_DEVIANCE_TOL = 0.01


def _solve(prob: WeightedResiduals, names: list[str], robot: Robot, x0: np.ndarray, max_nfev: int) -> tuple[np.ndarray, np.ndarray]:
    """Bounded trust-region least squares from x0; returns (x, weighted Jacobian at x)."""
    lo = np.array([param_bounds(robot, p)[0] for p in names]) / prob.scale
    hi = np.array([param_bounds(robot, p)[1] for p in names]) / prob.scale
    x0 = np.clip(x0, lo, hi)
    x0 = np.where(x0 <= lo, lo + 1e-9 * np.maximum(1.0, np.abs(lo)), x0)
    ftol = max(1e-7, FIT_DEVIANCE_TOL / max(int(prob.problem.used.sum()), 1))
    sol = optimize.least_squares(prob.residual, x0, jac=prob.jacobian, bounds=(lo, hi), method="trf",
                                 x_scale=1.0, max_nfev=max_nfev, ftol=ftol, xtol=1e-7, gtol=1e-9)
    return sol.x, prob.jacobian(sol.x)


#: A fitted value within this fraction of its scale from a bound (or from zero) is pinned there.
BOUND_TOL = 1e-6


def _pinned(value: float, bounds: tuple[float, float], scale: float) -> str:
    """'pinned at its lower bound 0' / '... at zero' when `value` sits on a bound or at zero, else ''."""
    lo, hi = bounds
    tol = BOUND_TOL * max(abs(scale), 1e-300)
    if value - lo <= tol:
        return f"pinned at its lower bound {lo:.4g}"
    if hi - value <= tol:
        return f"pinned at its upper bound {hi:.4g}"
    if abs(value) <= tol:
        return "pinned at zero"
    return ""


def fit(robot: Robot, obs: Observations, free: Sequence[str] | None = None, *,
        procedures: Sequence[str] | None = None, max_nfev: int = 40,
        progress: Callable[[str], None] | None = None) -> FitResult:
    """Weighted least-squares fit of `free` parameters to `obs` through the simulator.

    progress: called with a line at each stage (identifiability, each warm-start procedure, the
    joint fit, its reweighted pass).

    robot: the starting model (its values are the start point and hold every fixed parameter).
    free: parameter names (default `default_free`). procedures: which observation tables enter
    the fit (default: those of sweep, forward, lateral that have rows; energy and step responses
    are kept for validation). Returns a FitResult; raises UserError when nothing can be fitted.

    Phases, one function each: what enters (`_fit_request`, `_left_out`, `_stated_noise`), the
    start point (`_start_point`), identifiability at the start (`_identify`), the warm start in
    the paper's order (`_warm_start`), the joint fit (`_joint_fit`), the pass weighted by each
    group's own noise (`_reweighted`), the covariance (`_covariance`), the verdicts and notes
    (`_confounded`, `_final_verdicts`, `_misfit_notes`).
    """
    procs, free = _fit_request(robot, obs, free, procedures)
    pred = Predictor(obs, procs)
    used = _usable(pred, robot)
    if used.sum() <= 0:
        raise UserError(f"no usable observations (all sweep speeds are below {MIN_SWEEP_SPEED:g} rad/s?)")
    notes = _left_out(pred, used, robot)
    start = _start_point(robot, obs, procs, free)
    groups, sigma, unknown = _stated_noise(pred, used, notes)
    say = progress or (lambda msg: None)
    say(f"identifiability of {len(free)} parameters from {int(used.sum())} observations")
    ident = _identify(weighted_residuals(start, pred, free, used, sigma), robot, free, procs)
    current = _warm_start(robot, start, obs, pred, procs, ident.active, ident.fixed, used, sigma, max_nfev, say)
    prob, xa, J = _joint_fit(robot, current, pred, ident.active, used, sigma, groups, unknown, max_nfev, say)
    xa, J = _at_predicted_speeds(prob, pred, robot, ident.active, xa, J, max_nfev, say)
    xa, J, sigma_stated, stated_factor = _reweighted(prob, robot, ident.active, groups, used, xa, J, max_nfev, say)
    fitted_robot = prob.robot_at(xa)
    f = prob.prediction_at(xa)
    cv = _covariance(prob, pred, f, J, groups, used, sigma_stated, len(ident.active))
    values = {p: param_value(fitted_robot, p) for p in free}
    se = {p: float("nan") for p in free}
    ci = {p: (float("nan"), float("nan")) for p in free}
    for k, p in enumerate(ident.active):
        se[p] = float(cv.se[k])
        ci[p] = (values[p] - cv.tq * se[p], values[p] + cv.tq * se[p])
    verdicts = ident.verdicts
    confounded = _confounded(prob, robot, obs, procs, free, ident.active, xa, J, verdicts)
    group_s2 = {g: v * stated_factor.get(g, 1.0) for g, v in cv.group_s2.items()}  # against the stated noise
    unstated = sorted(str(g) for g in np.unique(groups[used]) if unknown[(groups == g) & used].mean() >= 0.5)
    shares = {p: {g: float(v[k]) for g, v in cv.share.items()} for k, p in enumerate(ident.active)}
    misfit = misfit_groups(group_s2, cv.group_dof, unstated, cv.s2, cv.dof)
    _final_verdicts(robot, prob, ident.active, values, se, ci, verdicts, misfit, shares)
    runs_used = sorted(set(cv.residuals.loc[cv.residuals["used"], "run"]))
    notes += _misfit_notes(cv, misfit)
    active = ident.active
    return FitResult(
        robot=fitted_robot, free=list(free), values=values, se=se, ci95=ci,
        cov=pd.DataFrame(cv.cov, index=active, columns=active),
        corr=pd.DataFrame(cv.corr, index=active, columns=active),
        condition_number=ident.cond, rank=ident.rank, identifiable=verdicts, residuals=cv.residuals,
        chi2=cv.chi2, dof=cv.dof, runs_used=runs_used, procedures=procs, s2=cv.s2,
        group_s2=group_s2, group_dof=cv.group_dof, variance_share=shares, unstated_noise=unstated,
        initial={p: param_value(robot, p) for p in free},
        fixed=ident.fixed, notes=notes, confounded=confounded, nfev=prob.nfev, structure=cv.structure,
        digest=fit_digest(pred, used, free),
        date=_dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
    )


def _fit_request(robot: Robot, obs: Observations, free: Sequence[str] | None,
                 procedures: Sequence[str] | None) -> tuple[list[str], list[str]]:
    """The procedures that enter (those with rows) and the free parameters, checked."""
    procs = [p for p in (procedures or DEFAULT_PROCEDURES) if len(obs.table(p))]
    if not procs:
        raise UserError("no observations to fit (need sweep, forward or lateral runs)")
    names = list(free) if free is not None else default_free(robot, obs, procs)
    if not names:
        raise UserError("no free parameters to fit")
    for p in names:
        param_value(robot, p)  # validates names
    if len(set(names)) != len(names):
        raise UserError("a free parameter is named twice")
    return procs, names


def _left_out(pred: Predictor, used: np.ndarray, robot: Robot) -> list[str]:
    """Notes on the measured entries the fit leaves out (creeping ground wheels, slow sweep steps)."""
    notes: list[str] = []
    n_creep = int((np.isfinite(pred.measured) & creeping_ground_speeds(pred.table, pred.measured, robot)).sum())
    n_slow = int((np.isfinite(pred.measured) & ~used).sum()) - n_creep
    if n_creep:
        notes.append(f"{n_creep} ground-run wheel speed(s) slower than "
                     f"{MIN_GROUND_SPEED_WIDTHS * robot.sign_width_phi:g} rad/s left out: a wheel that sticks, "
                     "where the model's smoothed friction lets it creep")
    if n_slow:
        notes.append(f"{n_slow} sweep steady state(s) slower than "
                     f"{MIN_SWEEP_SPEED:g} rad/s left out: wheel stuck or in the "
                     "stiction/deadband region the model does not describe (see residuals)")
    return notes


def _start_point(robot: Robot, obs: Observations, procs: Sequence[str], free: Sequence[str]) -> Robot:
    """The start values: the paper's closed form for III.i (a, b, c) where the sweep is fitted."""
    if "sweep" not in procs or not {"a", "b"} <= set(free):
        return robot
    est = sweep_linear_estimate(robot, obs.sweep)
    guess: dict[str, float] = {k: est[k] for k in ("a", "b", "c") if k in free}
    if "c" in guess and guess["c"] <= 0:
        guess.pop("c")
    return with_params(robot, guess)


def _stated_noise(pred: Predictor, used: np.ndarray, notes: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(group of each entry "procedure/signal", sigma, unknown): each entry's stated standard
    error; a group that mostly has none gets 1e-3 of its RMS for now (`unknown` marks them;
    `_joint_fit` replaces it by the residual RMS of a first pass). Appends a note per such group."""
    sigma = pred.sigma.copy()
    unknown = ~np.isfinite(sigma) | (sigma <= 0)
    t = pred.table
    # column-wise, not a row-wise "/".join (~40 ms of CPU per fit of the campaign's 424 entries)
    groups = (t["procedure"].astype(str) + "/" + t["signal"].astype(str)).to_numpy()
    for g in np.unique(groups[used]):
        m = (groups == g) & used
        if unknown[m].any() and unknown[m].mean() >= 0.5:
            # mostly without standard errors (the 2019 sweep: samples only for its last level): the few
            # rows that have one would outweigh the rest by their encoder noise alone; treat all alike
            unknown[groups == g] = True
            notes.append(f"{g}: most observations carry no standard error; all weighted alike, noise "
                         "estimated from the residual")
    sigma[unknown] = np.nan
    for g in np.unique(groups[unknown & used]):
        m = (groups == g) & used
        vals = np.abs(pred.measured[m])
        sigma[(groups == g) & unknown] = max(1e-3 * float(np.sqrt(np.mean(vals ** 2))), 1e-12)
    return groups, sigma, unknown


@dataclass
class _Identified:
    """What the data can see at the start point: the parameters fitted (`active`), those held
    at their robot-file values (`fixed`), the verdicts so far, rank and condition number of the
    requested parameters' scaled Jacobian."""

    active: list[str]
    fixed: list[str]
    verdicts: dict[str, Verdict]
    rank: int
    cond: float


def _identify(prob: WeightedResiduals, robot: Robot, free: list[str], procs: Sequence[str]) -> _Identified:
    """Identifiability at the start point: parameters without any column are not identifiable;
    each invisible combination holds its parameter of lowest `_fix_priority` fixed."""
    J0 = prob.jacobian(np.array([param_value(prob.robot, p) for p in free]) / prob.scale)
    rank_req, cond_req, _ = _null_analysis(J0, free)
    fixed: list[str] = []
    verdicts: dict[str, Verdict] = {}
    colnorm = np.linalg.norm(J0, axis=0)
    for j, p in enumerate(free):
        if colnorm[j] <= 1e-12 * max(1.0, float(colnorm.max())):
            fixed.append(p)
            verdicts[p] = Verdict("not identifiable", f"the data ({', '.join(procs)}) carry no information on {p}")
    active = [p for p in free if p not in fixed]
    while active:
        idx = [free.index(p) for p in active]
        _, _, nl = _null_analysis(J0[:, idx], active)
        if not nl:
            break
        ratio, comb = nl[-1] if nl else (0, {})
        cand = sorted(comb, key=lambda n: (_fix_priority(n), -abs(comb[n])))
        p_fix = cand[0]
        why = (f"not separable: the data see only the combination {_combination(comb)} (scaled; singular value "
               f"ratio {ratio:.1e}); {p_fix} held at {param_value(robot, p_fix):.4g} {param_unit(robot, p_fix)}")
        for n in comb:
            if n != p_fix:
                _add_condition(verdicts, n, f"not separable from {p_fix} (held at its robot-file value "
                                            f"{param_value(robot, p_fix):.4g}): only {_combination(comb)} is identified")
        verdicts[p_fix] = Verdict("not identifiable", why)
        fixed.append(p_fix)
        active.remove(p_fix)
    if not active:
        raise UserError("none of the free parameters can be identified from these observations: "
                        + "; ".join(f"{p}: {v.reason}" for p, v in verdicts.items()))
    return _Identified(active, fixed, verdicts, rank_req, cond_req)


def _warm_start(robot: Robot, start: Robot, obs: Observations, pred: Predictor, procs: Sequence[str],
                active: list[str], fixed: list[str], used: np.ndarray, sigma: np.ndarray, max_nfev: int,
                say: Callable[[str], None]) -> Robot:
    """The joint fit's start: the fixed parameters at their robot-file values, then (with more
    than one procedure) each procedure's own parameters fitted to it alone, in the paper's order
    (III.i -> III.ii -> III.iii)."""
    current = with_params(start, {p: param_value(robot, p) for p in fixed})
    if len(procs) > 1:
        for proc, names in STAGES:
            sub = [p for p in active if p in names]
            if proc not in procs or not sub:
                continue
            say(f"warm start on the {proc} runs: {', '.join(sub)}")
            mask = (pred.table["procedure"] == proc).to_numpy()
            sp = weighted_residuals(current, Predictor(obs, [proc]), sub, used[mask], sigma[mask])
            xs, _ = _solve(sp, sub, robot, np.array([param_value(current, p) for p in sub]) / sp.scale, max_nfev)
            current = sp.robot_at(xs)
    return current


def _joint_fit(robot: Robot, current: Robot, pred: Predictor, active: list[str], used: np.ndarray, sigma: np.ndarray,
               groups: np.ndarray, unknown: np.ndarray, max_nfev: int,
               say: Callable[[str], None]) -> tuple[WeightedResiduals, np.ndarray, np.ndarray]:
    """Every active parameter fitted to every procedure from `current`: (problem, x, weighted
    Jacobian at x). Twice when some sigmas were unknown: the second pass with each such group's
    residual RMS as its sigma (`sigma` is updated in place)."""
    prob = weighted_residuals(current, pred, active, used, sigma)
    xa = np.array([param_value(current, p) for p in active]) / prob.scale
    passes = 2 if unknown[used].any() else 1
    say(f"joint fit of {len(active)} parameters ({', '.join(active)})")
    for pass_ in range(passes):
        xa, J = _solve(prob, active, robot, xa, max_nfev)
        if pass_ + 1 < passes:
            f = prob.predict([xa])[0]
            res = pred.measured - f
            for g in np.unique(groups[unknown & used]):
                m = (groups == g) & used
                rms = float(np.sqrt(np.mean(res[m] ** 2))) if m.any() else 1.0
                sigma[(groups == g) & unknown] = max(rms, 1e-12)
            prob.sigma = sigma
    return prob, xa, J


def speed_sigma_at_prediction(pred: Predictor, f: np.ndarray, sigma: np.ndarray) -> np.ndarray | None:
    """`sigma` with each sweep speed's error evaluated at the predicted speed `f`
    (observations.sweep_speed_se) where the step's window is known; None when none is.

    An encoder speed's error swings with the speed near a whole number of counts per reading;
    at the step's own estimate it follows that estimate's own error, and weighting by it pulls
    the fit toward the steps whose rounding happened to read precise: on the short sweep through
    the firmware, a level at 5.97 counts per reading gave its steps' weighted mean 0.44 of their
    scatter below the truth (b 0.5 SE low and c 0.65 SE high on average over 40 sweeps). At the prediction the
    error no longer depends on the step's own noise."""
    t = pred.table
    idx = np.flatnonzero(((t["procedure"] == "sweep") & (t["signal"] == "omega")).to_numpy())
    sw = pred.obs.sweep
    if not len(idx) or "omega_s2" not in sw or not pred.obs.windows:
        return None
    row = {(r, int(k), int(w)): i for i, (r, k, w) in enumerate(zip(sw["run"], sw["step"], sw["wheel"]))}
    pos = [row.get((t["run"].iat[i], int(t["step"].iat[i]), int(t["wheel"].iat[i]))) for i in idx]
    have = np.array([p is not None for p in pos], dtype=bool)
    if not have.any():
        return None
    idx = idx[have]
    se = sweep_speed_se(pred.obs, sw.iloc[[p for p in pos if p is not None]], f[idx])
    ok = np.isfinite(se) & (se > 0)
    # a run whose steps are not all windowed (the 2019 sweep: one raw step among tabled speeds)
    # keeps its stated errors: one row on another scale would outweigh the rest of its run
    runs = t["run"].to_numpy()[idx]
    partial = set(runs[~ok])
    ok &= np.array([r not in partial for r in runs], dtype=bool)
    if not ok.any():
        return None
    out = sigma.copy()
    out[idx[ok]] = se[ok]
    return out


def _at_predicted_speeds(prob: WeightedResiduals, pred: Predictor, robot: Robot, active: list[str], xa: np.ndarray,
                         J: np.ndarray, max_nfev: int, say: Callable[[str], None]) -> tuple[np.ndarray, np.ndarray]:
    """The joint fit again with each sweep speed weighted by its error at the fitted model's
    speed instead of its own (`speed_sigma_at_prediction`): (x, Jacobian)."""
    sigma = speed_sigma_at_prediction(pred, prob.prediction_at(xa), prob.sigma)
    if sigma is None or np.allclose(sigma, prob.sigma, rtol=1e-9, atol=0.0, equal_nan=True):
        return xa, J
    say("joint fit again, each steady speed weighted by its error at the model's speed")
    prob.sigma = sigma
    return _solve(prob, active, robot, xa, max_nfev)


def _reweighted(prob: WeightedResiduals, robot: Robot, active: list[str], groups: np.ndarray, used: np.ndarray,
                xa: np.ndarray, J: np.ndarray, max_nfev: int,
                say: Callable[[str], None]) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, float]]:
    """The joint fit again with each large group weighted by its own noise, when that moves a
    group's weight by more than 5 % (`_noise_reweighting`): the stated errors of different
    estimators are off by different factors (encoder speeds s^2 0.15-0.4, tape ~1 on the
    simulated robot); weighting by the stated ones alone is a consistent but inefficient
    estimator whose sandwich SEs are 8-22 % above the information the data hold (C_r, b, c),
    the information the planner counts. Returns (x, Jacobian, the stated sigmas, each group's
    factor on its variance)."""
    f = prob.predict([xa])[0]
    reweight = _noise_reweighting(groups, used, prob.weighted(f), J)
    stated_factor = {str(g): 1.0 for g in np.unique(groups)}
    sigma_stated = prob.sigma.copy()
    if reweight is not None:
        say("joint fit again, each group weighted by its own noise")
        stated_factor = {str(g): float(reweight[groups == g][0]) ** 2 for g in np.unique(groups)}
        prob.sigma = prob.sigma * reweight
        xa, J = _solve(prob, active, robot, xa, max_nfev)
    return xa, J, sigma_stated, stated_factor


@dataclass
class _Covariance:
    """The fit's statistics at its solution (see `_covariance`)."""

    chi2: float
    dof: int
    s2: float
    cov: np.ndarray
    se: np.ndarray
    corr: np.ndarray
    tq: float
    group_s2: dict[str, float]
    group_dof: dict[str, float]
    residuals: pd.DataFrame
    structure: dict[str, dict[str, Any]]
    #: per group: its share of each active parameter's variance (the diagonal of cov; shares sum to 1)
    share: dict[str, np.ndarray] = field(default_factory=dict)


def _covariance(prob: WeightedResiduals, pred: Predictor, f: np.ndarray, J: np.ndarray, groups: np.ndarray,
                used: np.ndarray, sigma_stated: np.ndarray, n_active: int) -> _Covariance:
    """chi^2, dof, the sandwich covariance (SI), standard errors, correlations and the 95 %
    t quantile. Per-group noise scale (Birge ratio of each procedure/signal group, with the
    group's share of the degrees of freedom from the leverages), then the sandwich covariance: a
    group whose stated errors are too small (or whose residual carries structure) widens the
    intervals of the parameters it informs, not of all.

    Each group's share of a parameter's variance: the estimate moves with the data as
    d theta = A J^T d r (A = (J^T J)^-1), so group g contributes (A J_g^T S_g J_g A)_pp to
    var(theta_p); the shares sum to 1 and count what a group informs through the parameters it
    is correlated with (the sweep's currents for the rollers' a_r, through b), which the
    group's share of the diagonal of J^T J would not."""
    r = prob.weighted(f)
    n_used = int(used.sum())
    dof = max(n_used - n_active, 1)
    chi2 = float(r @ r)
    JTJ = J.T @ J
    try:
        A = np.linalg.inv(JTJ)
    except np.linalg.LinAlgError:
        A = np.linalg.pinv(JTJ)
    lev = np.einsum("ij,jk,ik->i", J, A, J)
    g_used = groups[used]
    s2_row = np.empty(n_used)
    group_s2: dict[str, float] = {}
    group_dof: dict[str, float] = {}
    residuals = _residual_frame(pred, f, sigma_stated, used)
    structure = residual_structure(residuals)
    for g in np.unique(g_used):
        m = g_used == g
        dof_g = max(float(m.sum() - lev[m].sum()), 1.0)
        group_s2[str(g)] = float(np.sum(r[m] ** 2) / dof_g)
        group_dof[str(g)] = dof_g
        st = structure.get(str(g))
        if st is not None and st["z"] > STRUCTURE_Z and 0 < st["rho"] < 1:
            # residuals that are smooth along speed carry fewer independent pieces of information
            # than entries: an AR(1) effective-sample-size correction widens the group's variance
            st["variance_inflation"] = (1 + st["rho"]) / (1 - st["rho"])
            group_s2[str(g)] *= st["variance_inflation"]
        s2_row[m] = group_s2[str(g)]
    cov_x = A @ (J.T @ (J * s2_row[:, None])) @ A
    contrib = (A @ J.T) ** 2 * s2_row[None, :]
    total = contrib.sum(axis=1)
    total = np.where(total > 0, total, 1.0)
    share = {str(g): contrib[:, g_used == g].sum(axis=1) / total for g in np.unique(g_used)}
    cov = cov_x * np.outer(prob.scale, prob.scale)
    se_a = np.sqrt(np.maximum(np.diag(cov), 0))
    # Student's t quantile: scipy.special's stdtrit is what stats.t.ppf evaluates (bit for bit),
    # without importing scipy.stats (~1 s of CPU in every `omnibench fit`; scipy.special is
    # loaded with scipy.optimize anyway)
    tq = float(special.stdtrit(dof, 0.975))
    d = np.where(se_a > 0, se_a, 1.0)
    corr = cov / np.outer(d, d)
    return _Covariance(chi2, dof, chi2 / dof, cov, se_a, corr, tq, group_s2, group_dof, residuals, structure, share)


def _confounded(prob: WeightedResiduals, robot: Robot, obs: Observations, procs: Sequence[str], free: Sequence[str],
                active: list[str], xa: np.ndarray, J: np.ndarray, verdicts: dict[str, Verdict]) -> list[dict[str, Any]]:
    """Conditional parameters: fitted ones the data cannot separate from a fixed constant (the
    sweep without current: k_e; forward runs without a sweep: c). Marks them in `verdicts` and
    returns what each constant is confounded with."""
    confounded: list[dict[str, Any]] = []
    nuisance = []
    if "sweep" in procs and not obs.has_current and "k_e" not in free:
        nuisance.append("k_e")
    if "forward" in procs and "C_r" in active and "c" not in free and "sweep" not in procs:
        nuisance.append("c")
    for nu in nuisance:
        Jx = np.column_stack([J, prob.extra_columns(xa, [nu])])
        s, Vt, _ = _scaled_svd(Jx)
        ratio = float(s[-1] / s[0]) if s[0] > 0 else 0.0
        if ratio < CONFOUND_TOL:
            v = Vt[-1]
            cols = active + [nu]
            comb = {cols[i]: float(v[i]) for i in range(len(cols)) if abs(v[i]) > 0.2}
            for p in comb:
                if p in active:
                    _add_condition(
                        verdicts, p,
                        f"not separable from {nu} (fixed at {param_value(robot, nu):.4g} {param_unit(robot, nu)}): "
                        f"the data see only {_combination(comb)} (singular value ratio {ratio:.1e})"
                        + ("; log the motor current to separate friction from the back-EMF damping "
                           "eta k_t k_e / R_a" if nu == "k_e" else ""))
            confounded.append({"fixed": nu, "with": [p for p in comb if p != nu], "ratio": ratio,
                               "combination": _combination(comb)})
    return confounded


#: A measurement group carrying at least this share of a parameter's variance determines it: its
#: misfit makes the parameter's verdict 'model inadequate'.
DETERMINES_SHARE = 0.2
#: The pseudo-group of every observation, for a misfit of the whole fit (it determines every parameter).
ALL_OBSERVATIONS = "all observations"


def misfit_groups(group_s2: Mapping[str, float], group_dof: Mapping[str, float], unstated: Sequence[str],
                  s2: float, dof: float) -> dict[str, float]:
    """The measurement groups whose residuals exceed their stated noise, with their chi^2/dof
    (`group_s2`, against the stated noise): above MISFIT_S2, and significantly (the chi^2 tail
    probability of the group's chi^2 on its `group_dof` below MISFIT_P: any group of 6 dof or more
    at MISFIT_S2, a two-entry group only far above it). A group in `unstated` had its noise
    estimated from its own residual: it has no such test. ALL_OBSERVATIONS when the whole fit's
    chi^2/dof `s2` on `dof` passes the same test. Worst first."""
    out = {g: float(v) for g, v in group_s2.items()
           if g not in unstated and _significant_misfit(float(v), float(group_dof.get(g, 0.0)))}
    if _significant_misfit(float(s2), float(dof)):
        out[ALL_OBSERVATIONS] = float(s2)
    return dict(sorted(out.items(), key=lambda x: -x[1]))


def _significant_misfit(s2: float, dof: float) -> bool:
    return (math.isfinite(s2) and s2 > MISFIT_S2 and dof > 0
            and float(special.chdtrc(dof, s2 * dof)) < MISFIT_P)


def chi2_text(v: float) -> str:
    """A chi^2/dof for people: 3 significant digits, a large one whole (1678, not 1.68e+03)."""
    return f"{v:.0f}" if abs(v) >= 1000 else f"{v:.3g}"


def _share_of(shares: Mapping[str, float], group: str) -> float:
    return 1.0 if group == ALL_OBSERVATIONS else float(shares.get(group, 0.0))


def _final_verdicts(robot: Robot, prob: WeightedResiduals, active: list[str], values: Mapping[str, float],
                    se: Mapping[str, float], ci: Mapping[str, tuple[float, float]],
                    verdicts: dict[str, Verdict], misfit: Mapping[str, float],
                    shares: Mapping[str, Mapping[str, float]]) -> None:
    """The verdict of each fitted parameter (Verdict, worst first): 'at bound' for a value on a
    physical bound or at zero; 'model inadequate' where a group in `misfit` (group -> chi^2/dof)
    carries DETERMINES_SHARE or more of its variance (`shares`: parameter -> group -> share);
    'consistent with zero' where its 95 % interval includes zero; 'conditional' as `_identify`
    and `_confounded` found; 'identified' for the rest."""
    for k, p in enumerate(active):
        pinned = _pinned(values[p], param_bounds(robot, p), float(prob.scale[k]))
        if pinned:
            verdicts[p] = Verdict("at bound", f"{pinned}: the data push it past its physical range (check the "
                                              "measurements that inform it); its standard error means nothing")
    for p in active:
        if p in verdicts and verdicts[p].status not in ("identified", "conditional"):
            continue
        cond = verdicts[p].condition if p in verdicts else ""
        rel = se[p] / abs(values[p]) if values[p] else math.inf
        lo, hi = ci[p]
        zero = lo <= 0 <= hi
        zero_why = f"its 95 % interval [{lo:.4g}, {hi:.4g}] includes zero (relative standard error {rel:.2g})"
        bad = sorted(((g, _share_of(shares.get(p, {}), g)) for g in misfit), key=lambda x: -x[1])
        bad = [(g, sh) for g, sh in bad if sh >= DETERMINES_SHARE]
        if bad:
            why = "; ".join(f"{g}: chi2/dof {chi2_text(misfit[g])} against its stated noise"
                            + ("" if g == ALL_OBSERVATIONS else f" ({100 * sh:.0f} % of its variance)")
                            for g, sh in bad)
            verdicts[p] = Verdict("model inadequate",
                                  f"{why}: the declared model misses something in these runs (see omnibench "
                                  "diagnose); the value, and its SE widened by the misfit, are this model's "
                                  "reading of them, not a measurement of the coefficient"
                                  + (f"; {zero_why}" if zero else "") + (f"; {cond}" if cond else ""),
                                  condition=cond)
        elif zero:
            verdicts[p] = Verdict("consistent with zero", zero_why + ": the data do not tell it from zero"
                                  + (f"; {cond}" if cond else ""), condition=cond)
        elif p not in verdicts:
            verdicts[p] = Verdict("identified", f"relative standard error {rel:.2g}")


def _misfit_notes(cv: _Covariance, misfit: Mapping[str, float]) -> list[str]:
    """Notes where the residuals exceed the noise (`misfit`: `misfit_groups`, overall and per group
    against its stated noise) or are smooth along speed."""
    notes: list[str] = []
    if ALL_OBSERVATIONS in misfit:
        notes.append(f"chi2/dof = {misfit[ALL_OBSERVATIONS]:.3g}: residuals exceed the measurement noise; the model "
                     "misses something (see residuals / omnibench diagnose); intervals are widened by s")
    for g, v in misfit.items():
        if g != ALL_OBSERVATIONS:
            notes.append(f"{g}: chi2/dof = {v:.3g} against its stated noise: residuals exceed the "
                         "measurement noise; the model misses something, or the noise is under-stated (see "
                         "residuals / omnibench diagnose); intervals are widened by it")
    for g, st in cv.structure.items():
        if st["z"] > STRUCTURE_Z:
            notes.append(f"{g}: residuals are smooth along speed (lag-1 autocorrelation {st['rho']:.2f} over "
                         f"{st['pairs']} neighbour pairs, {st['z']:.1f} sigma above noise): structure the model "
                         f"misses (residual RMS {st['rms']:.3g} {st['unit']}; see the residual plot, "
                         "omnibench diagnose)"
                         + (f"; its variance is inflated x{st['variance_inflation']:.2g} for the correlation"
                            if "variance_inflation" in st else ""))
    return notes


def fit_digest(pred: Predictor, used: np.ndarray, free: Sequence[str]) -> str:
    """SHA-256 (hex) of what a fit saw: every observation entry (procedure, run, step, wheel,
    signal, measured value, standard error, used or not) and the free parameters' names."""
    import hashlib

    h = hashlib.sha256()
    t = pred.table
    for col in ("procedure", "run", "step", "wheel", "signal"):
        h.update("\x1f".join(map(str, t[col].tolist())).encode())
    h.update(np.ascontiguousarray(pred.measured, dtype=float).tobytes())
    h.update(np.ascontiguousarray(pred.sigma, dtype=float).tobytes())
    h.update(np.ascontiguousarray(used, dtype=bool).tobytes())
    h.update("\x1f".join(free).encode())
    return h.hexdigest()


def robot_digest(robot: Robot) -> str:
    """SHA-256 (hex) of every value of a robot (its repr: floats round-trip exactly)."""
    import hashlib

    return hashlib.sha256(repr(robot).encode()).hexdigest()


def refit_needed(robot: Robot, obs: Observations, procedures: Sequence[str], fit_info: Mapping[str, Any]) -> bool:
    """False when `robot` is, unchanged, what `fit(…, obs, procedures=procedures)` wrote with
    its default free parameters: its [fit] table (`fit_info`) names these procedures, the
    digest of these observations (`fit_digest`) and the digest of this robot (`robot_digest`).
    Fitting it again would start from the closed form and land on the same optimum (to the
    fit's tolerance): diagnose then starts from the file's values instead."""
    if not fit_info or list(fit_info.get("procedures", [])) != list(procedures):
        return True
    if fit_info.get("robot_digest") != robot_digest(robot) or "fitted" not in fit_info:
        return True
    pred = Predictor(obs, procedures)
    free = default_free(robot, obs, procedures)
    return fit_info.get("digest") != fit_digest(pred, _usable(pred, robot), free)


#: Residual smoothness (z of the lag-1 autocorrelation) above which a group is flagged as structured.
STRUCTURE_Z = 3.0
#: chi^2/dof above which the fit says the residuals exceed the measurement noise (the model misses something).
MISFIT_S2 = 4.0
#: ... when its chi^2 is also this improbable for noise as stated (chi^2 tail probability): a group of a
#: few entries needs more than MISFIT_S2 (a chi^2_1 draw exceeds 4 one time in 22).
MISFIT_P = 1e-3


def residual_structure(residuals: pd.DataFrame) -> dict[str, dict[str, Any]]:
    """Does a residual group look like noise? Within each (wheel, load, direction) series, residuals
    are ordered by speed (entries without a speed, e.g. displacements, by step); the pooled lag-1 autocorrelation rho of neighbours is ~N(0, 1/pairs) for
    white noise, while a missing effect (deadband, Stribeck, a per-wheel offset) makes neighbours
    alike: z = rho sqrt(pairs) > STRUCTURE_Z flags it. Works without known noise levels."""
    out: dict[str, dict[str, Any]] = {}
    df = residuals[residuals["used"] & np.isfinite(residuals["residual"])]
    if not len(df):
        return out
    # Columns once, groups as pandas makes them (in order of appearance; a missing key: no group):
    # `outer` each (procedure, signal), `series` each (procedure, signal, wheel, load, direction).
    # Each series is ordered by one stable sort of a few columns, not a groupby of the whole
    # table per group and a sort of every column per series (~0.2 s of CPU of an `omnibench fit`).
    speed = df["speed"].to_numpy(float)
    predicted = df["predicted"].to_numpy(float)
    normalised = df["normalised"].to_numpy(float)
    residual = df["residual"].to_numpy(float)
    # a speed's own residual is ordered by the model's speed: ordered by the measured one, the
    # repeats of a level would line up by their own noise and look alike
    own = np.isclose(speed, df["measured"].to_numpy(float), rtol=0.0, atol=0.0) & np.isfinite(predicted)
    key = np.where(own, predicted, speed)
    keys = pd.DataFrame({"procedure": df["procedure"], "signal": df["signal"], "wheel": df["wheel"],
                         "_F": df["F_N"].round(6).fillna(-1.0), "_d": np.sign(df["speed"].fillna(0.0))})
    outer = keys.groupby(["procedure", "signal"], sort=False).ngroup().to_numpy()
    series = keys.groupby(["procedure", "signal", "wheel", "_F", "_d"], sort=False).ngroup().to_numpy()
    zc = np.full(len(df), np.nan)
    for k in range(outer.max(initial=-1) + 1):
        m = outer == k
        z = np.where(np.isfinite(normalised[m]), normalised[m], residual[m]).astype(float)
        zc[m] = z - z.mean()
    # a series whose keys are not all finite (displacements) is ordered by step alone: run order
    finite = np.ones(series.max(initial=-1) + 2, dtype=bool)
    np.logical_and.at(finite, series + 1, np.isfinite(key))
    order = pd.DataFrame({"_series": series, "_key": np.where(finite[series + 1], key, 0.0),
                          "step": df["step"].to_numpy(), "_z": zc, "_outer": outer})
    order = order[(series >= 0) & (outer >= 0)].sort_values(["_series", "_key", "step"], kind="stable")
    zs = order["_z"].to_numpy()
    ser = order["_series"].to_numpy()
    first = np.flatnonzero(np.diff(ser)) + 1
    series_outer = order["_outer"].to_numpy()[np.concatenate([[0], first])] if len(ser) else np.zeros(0, int)
    num = np.zeros(outer.max(initial=-1) + 1)
    den = np.zeros_like(num)
    pairs = np.zeros(len(num), dtype=int)
    for k, v in zip(series_outer, np.split(zs, first)):
        if len(v) < 3:
            continue
        num[k] += float(np.sum(v[1:] * v[:-1]))
        den[k] += float(np.sum(v * v))
        pairs[k] += len(v) - 1
    names = keys[["procedure", "signal"]].to_numpy()
    unit = df["unit"].to_numpy()
    for k in range(len(num)):
        if pairs[k] < 5 or den[k] <= 0:
            continue
        m = outer == k
        i0 = int(np.flatnonzero(m)[0])
        proc, sig = names[i0]
        rho = float(num[k]) / float(den[k])
        out[f"{proc}/{sig}"] = {"rho": rho, "pairs": int(pairs[k]), "z": rho * math.sqrt(int(pairs[k])),
                                "rms": float(np.sqrt(np.mean(df["residual"][m] ** 2))), "unit": str(unit[i0])}
    return out


def fit_per_wheel(robot: Robot, obs: Observations, free: Sequence[str] = ("a", "b", "c")) -> dict[int, FitResult]:
    """III.i per wheel: the sweep of each wheel fitted on its own (wheels differ on a real robot)."""
    out = {}
    for j in sorted(int(w) for w in obs.sweep["wheel"].unique()):
        out[j] = fit(robot, obs.select(wheels=[j], procedures=["sweep"]), list(free), procedures=["sweep"])
    return out


# ----------------------------------------------------------------------------- predictions
def _residual_frame(pred: Predictor, f: np.ndarray, sigma: np.ndarray, used: np.ndarray) -> pd.DataFrame:
    df = pred.table.copy()
    df["predicted"] = f
    df["sigma"] = sigma
    df["residual"] = df["measured"] - df["predicted"]
    df["normalised"] = df["residual"] / df["sigma"]
    df["used"] = used
    return df


def predict_observations(robot: Robot, obs: Observations, procedures: Sequence[str] | None = None) -> pd.DataFrame:
    """The model's prediction of every observation entry: the entry table (procedure, run, step,
    wheel, signal, unit, measured, sigma, speed, F_N, direction, time, current, u, payload) plus
    predicted, residual (measured - predicted) and normalised (residual / sigma; NaN when the
    observation has no standard error)."""
    pred = Predictor(obs, procedures)
    if not len(pred):
        return _residual_frame(pred, np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool))
    f = pred.predict([robot])[0]
    return _residual_frame(pred, f, pred.sigma, _usable(pred, robot))


def _nrmse_table(df: pd.DataFrame) -> dict[str, float]:
    out = {}
    for p, g in df.groupby("procedure", sort=False):
        vals = []
        for _, h in g.groupby("signal"):
            m = np.isfinite(h["residual"]) & np.isfinite(h["measured"])
            if m.sum() == 0:
                continue
            den = float(np.sqrt(np.mean(h.loc[m, "measured"] ** 2)))
            vals.append(float(np.sqrt(np.mean(h.loc[m, "residual"] ** 2))) / den if den > 0 else math.inf)
        out[str(p)] = float(np.sqrt(np.mean(np.square(vals)))) if vals else float("nan")
    return out


def error_by_procedure(robot: Robot, obs: Observations, procedures: Sequence[str] | None = None,
                       kind: str = "nrmse") -> dict[str, float]:
    """A normalised prediction error per procedure (for held-out comparisons).

    kind="nrmse" (default): for each signal of the procedure RMS(measured - predicted) /
    RMS(measured), combined over the procedure's signals as their root mean square
    (dimensionless; 0.01 = 1 %). kind="z": RMS of (measured - predicted) / sigma over entries
    with a standard error (about 1 when the model explains the data to the noise).
    Sweep steady states below the sign-width threshold are included (they are data too)."""
    df = predict_observations(robot, obs, procedures)
    if kind == "nrmse":
        return _nrmse_table(df)
    if kind == "z":
        out = {}
        for p, g in df.groupby("procedure", sort=False):
            z = g["normalised"].to_numpy(float)
            z = z[np.isfinite(z)]
            out[str(p)] = float(np.sqrt(np.mean(z ** 2))) if len(z) else float("nan")
        return out
    raise ValueError(f"kind must be 'nrmse' or 'z', not {kind!r}")
