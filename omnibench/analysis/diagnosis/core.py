"""diagnose(): fit the declared model, find structure, add the effect that earns its place, repeat.

Algorithm (docs/diagnose.md has the long form):

1. Fit the declared model (parameters the data can identify, per `fitting.fit`) by profile
   likelihood over every entry of every procedure (engine.py).
2. Study the residual: binned-mean and runs tests per group against speed, duty, load,
   direction, wheel, time, current, payload, step order (structure.py).
3. Screen every library candidate with a first-order score test (residual projected on the
   candidate's sensitivities), refit the most promising `top_k` exactly (nonlinear, together
   with the model's own parameters).
   An effect with several forms (Effect.forms) is refitted in each; the best form is kept and
   the report says which the data chose and by how much AIC.
4. A candidate earns its place when (a) its likelihood-ratio test against the current model
   passes p < alpha / m (m candidates tested: Bonferroni), (b) it lowers the held-out
   (K-fold over run steps) weighted error by more than 2 per parameter and no procedure's
   held-out error rises beyond that procedure's own noise (WORSE_SE), (c) its fitted values
   are inside their physical range (not on a bound), and (d) it removes at least half of the
   strength (-log10 p) of some significant residual structure in a procedure where its physics
   shows (a procedure/signal group against one variable); otherwise it only leans on structure
   something else makes: reported, not added.
   Adequacy: it is added only if the structure it acts on is gone with it (no longer
   significant by the same tests). When the best is not adequate, pairs led by the best significant
   candidates are refitted together; a pair is added when it earns its place, removes the
   structure, and each effect is significant given the other. A core-parameter re-estimate
   needs no adequacy, so when it leads and no library effect is adequate alone, a pair that
   earns its place in all else and beats it by more than AMBIGUOUS AIC is added instead, with
   the same exemption (else a re-estimate could stand in for two mechanisms that explain
   more). Otherwise the structure stays "unexplained". Among adequate candidates the lowest AIC wins; others within AMBIGUOUS of it
   are reported as not separable with these data, with the experiment that would separate them.
5. Add the winner, polish the fit and check the bounds again, repeat until nothing earns its
   place (or `max_effects`). "Added" reports the final model's values.
6. Report what structure remains, and the held-out error before and after per procedure.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from omnibench.analysis import modes as unknown_modes
from omnibench.analysis.diagnosis import core_params, engine, structure, transient
from omnibench.analysis.diagnosis.probabilities import chi2_isf
from omnibench.analysis.observations import Observations
from omnibench.effects.library import EFFECTS, Effect
from omnibench.errors import UserError

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

ALPHA = 1e-3  # family-wise level for adding an effect
AMBIGUOUS = 10.0  # AIC difference below which two candidates are not told apart
PARTIAL = 0.5  # a candidate must remove at least this fraction of the residual structure
SCREEN_FRACTION = 0.5  # screen LR below this fraction of the add threshold: not refitted
WORSE_SE = 2.0  # a procedure's held-out mean square may not rise by more than this many of its own SE
# (a mean of n squared residuals has relative SE sqrt(2 / n): a 4-run energy set at its noise
# floor may move by 140 %, a 256-entry sweep by 18 %, before a rise counts as worse)
MAX_FITS = 6  # refits per round when the top_k all fail
POLISH_NFEV = 60  # evaluations allowed when fitting the declared and each accepted model
ZERO_SE = 2.0  # a candidate whose every fitted parameter is within this many SE of 0 is absent
RELATIVE_SCREEN = 0.02  # nor below this fraction of the best candidate's (relative to threshold)
#: nor when an adequate candidate fitted this round has a likelihood ratio this many times its
#: first-order one: it could win only if its exact LR were that much above its linearised
#: estimate (the README deadband campaign: driver_deadband LR 974, the three latencies' first-
#: order 8-12, fitted 0.0-2.3 in 215 s of CPU). Refitted after all when nothing is added.
DOMINANCE = 10.0
CONFOUNDED = 1e-6  # share of a candidate's sensitivity left after the fitted parameters' directions
PAIR_LEADS = 2  # best fitted candidates tried as the first of a pair when no single one is adequate
PAIR_TOP = 3  # partners screened against each lead's fit and refitted with it
TABLE_OF = {"upside_down_sweep": "sweep", "forward_runs": "forward", "lateral_runs": "lateral",
            "energy_trajectories": "energy", "step_response": "step_response"}


@dataclass
class Candidate:
    """One candidate's evidence in one round."""

    name: str
    round: int
    approx_lr: float
    fitted: bool = False
    values: dict[str, float] = field(default_factory=dict)
    se: dict[str, float] = field(default_factory=dict)
    lr: float = float("nan")
    p: float = float("nan")
    q: int = 0
    aic_drop: float = float("nan")
    cv_gain: float = float("nan")
    structure_before: float = float("nan")
    structure_after: float = float("nan")
    verdict: str = ""
    reason: str = ""
    fit: Any = None
    struct: tuple[list, int] | None = None  # residual structure of the refitted model (findings, tests)
    worse: dict[str, tuple[float, float]] = field(default_factory=dict)  # procedure -> (declared, with it)
    form: str = ""  # the form the data chose (Effect.forms), '' for an effect with one form
    form_margin: dict[str, float] = field(default_factory=dict)  # other form -> AIC above the chosen
    acted: list = field(default_factory=list)  # (group, variable) structure it removed half or more of
    remaining: list = field(default_factory=list)  # ... of which still significant with it: not adequate
    partner: str = ""  # the other effect when it was added as a pair

    def evidence_line(self) -> str:
        """The report's one-line evidence; says why a structure score can rise with the effect."""
        line = (f"evidence: LR = {self.lr:.1f} for {self.q} parameter(s), p = {self.p:.1e}; AIC -{self.aic_drop:.1f}; "
                f"held-out weighted error -{self.cv_gain:.1f}; structure {self.structure_before:.0f} -> "
                f"{self.structure_after:.0f}")
        if self.structure_after > self.structure_before:
            line += (" (each score is measured against its own fit's residual scale: the effect shrinks that "
                     "scale, so the structure it leaves stands out more; what is left is listed as unexplained)")
        return line

    def evidence(self) -> dict[str, Any]:
        def f(x: float) -> float | None:
            return float(x) if x is not None and math.isfinite(x) else None

        return {"round": self.round, "likelihood_ratio": f(self.lr), "parameters_added": self.q, "p_value": f(self.p),
                "aic_drop": f(self.aic_drop), "heldout_gain": f(self.cv_gain), "screen_lr": f(self.approx_lr),
                "structure_before": f(self.structure_before), "structure_after": f(self.structure_after),
                "form": self.form or None, "form_aic_margin": {k: f(v) for k, v in self.form_margin.items()},
                "structure_removed": [list(k) for k in self.acted], "structure_left": [list(k) for k in self.remaining],
                "added_with": self.partner or None}


@dataclass
class Diagnosis:
    """What diagnose found (see `to_json`)."""

    declared: Any
    extended: Any
    base_fit: engine.ModelFit
    final_fit: engine.ModelFit
    selected: list[Candidate]
    rejected: list[Candidate]
    ambiguous: list[dict[str, Any]]
    unexplained: list[structure.Finding]
    base_structure: list[structure.Finding]
    before: dict[str, dict[str, Any]]
    after: dict[str, dict[str, Any]]
    problem: engine.Problem
    base_heldout: np.ndarray
    final_heldout: np.ndarray
    notes: list[str] = field(default_factory=list)
    exposed_by: dict[str, structure.Finding] = field(default_factory=dict)
    #: runs of unknown mode: the assignments of modes the declared fit tried and the one kept for
    #: the rest (`problem.obs` holds it); None: no such run
    mode_profile: unknown_modes.ModeProfile | None = None

    def to_json(self) -> dict[str, Any]:
        def f(x: float) -> float | None:
            return float(x) if x is not None and math.isfinite(x) else None

        sel = []
        for c in self.selected:
            eff = _spec(c.name)
            units = {p.name: p.unit for p in eff.term.params}
            from omnibench.analysis.diagnosis.timing import wheel_order_note

            sel.append({"effect": c.name, "title": eff.term.title, "kind": _kind(c.name),
                        "note": wheel_order_note(c.name, c.values, c.se) or None,
                        "parameters": {p: {"value": f(c.values[p]), "se": f(c.se[p]), "unit": units[p.split(".")[-1]]}
                                       for p in c.values},
                        "evidence": {**c.evidence(),
                                     "exposed_by": self.exposed_by[c.name].to_json() if c.name in self.exposed_by else None}})
        return {
            "selected": sel,
            "rejected": [{"effect": c.name, "round": c.round, "reason": c.reason, "evidence": c.evidence(),
                          "values": {p: f(v) for p, v in c.values.items()}} for c in self.rejected],
            "ambiguous": self.ambiguous,
            "unexplained": [u.to_json() for u in self.unexplained],
            "before": _err_json(self.before),
            "after": _err_json(self.after),
            "declared_fit": {p: {"value": f(self.base_fit.values[p]), "se": f(self.base_fit.se[p])} for p in self.base_fit.free},
            "extended_fit": {p: {"value": f(self.final_fit.values[p]), "se": f(self.final_fit.se[p])} for p in self.final_fit.free},
            "procedures": list(self.problem.procedures),
            "entries": int(self.problem.used.sum()),
            "notes": self.notes,
            "mode_profile": self.mode_profile.to_json() if self.mode_profile is not None else None,
        }

    def text(self) -> str:
        """The report a lab engineer reads."""
        L: list[str] = []
        L.append(f"Diagnosis of {self.declared.name} on {int(self.problem.used.sum())} measurements "
                 f"({', '.join(self.problem.procedures)}).")
        if self.base_structure:
            L.append("Declared model leaves structure in the residual:")
            for s in self.base_structure[:5]:
                L.append(f"  - {s.location()} [{s.test}, p={s.p:.1e}]")
        else:
            L.append("Declared model: no significant structure in the residual.")
        if self.selected:
            L.append("Added:")
            for c in self.selected:
                vals = ", ".join(f"{p.split('.')[-1]} = {c.values[p]:.4g} ± {c.se[p]:.2g}" for p in c.values)
                if core_params.is_core(c.name):
                    L.append(f"  + {core_params.describe(c.name, c.values[c.name], c.se[c.name], self.declared)}"
                             f" (final model: {self.final_fit.values.get(c.name, float('nan')):.4g})")
                else:
                    L.append(f"  + {c.name} ({EFFECTS[c.name].term.title}): {vals}")
                if c.form:
                    alt = ", ".join(f"{k} AIC +{v:.1f}" for k, v in c.form_margin.items())
                    L.append(f"    form: {c.form}" + (f" (the data chose it over: {alt})" if alt else ""))
                if c.partner:
                    L.append(f"    added together with {c.partner}: neither alone removes the structure")
                from omnibench.analysis.diagnosis.timing import wheel_order_note

                if wheel_order_note(c.name, c.values, c.se):
                    L.append(f"    {wheel_order_note(c.name, c.values, c.se)}")
                L.append(f"    {c.evidence_line()}")
                if c.name in self.exposed_by:
                    L.append(f"    exposed by: {self.exposed_by[c.name].location()}")
        else:
            L.append("Added: nothing (no candidate earns its parameters).")
        if self.ambiguous:
            L.append("Cannot tell apart with these data:")
            for a in self.ambiguous:
                L.append(f"  ? {a['chosen']} vs {a['alternative']} (AIC difference {a['aic_difference']:.1f}): {a['experiment']}")
        if self.rejected:
            L.append("Rejected:")
            for c in self.rejected[:12]:
                L.append(f"  - {c.name} (round {c.round}): {c.reason}")
        if self.unexplained:
            L.append("Structure no candidate explains:")
            for s in self.unexplained[:6]:
                L.append(f"  ! {s.location()} [{s.test}, p={s.p:.1e}]")
        else:
            L.append("Remaining residual: no significant structure.")
        L.append("Held-out error (K-fold over run steps), before -> after:")
        for proc in self.before:
            b, a = self.before[proc], self.after.get(proc, {})
            sig = ", ".join(f"{s} {v['rms']:.3g} -> {a.get('signals', {}).get(s, {}).get('rms', float('nan')):.3g} {v['unit']}"
                            for s, v in b["signals"].items())
            L.append(f"  {proc:<14} {100 * b['nrmse']:.2f} % -> {100 * a.get('nrmse', float('nan')):.2f} %   ({sig})")
        for n in self.notes:
            L.append(f"note: {n}")
        return "\n".join(L)


def _spec(name: str) -> Any:
    """A library effect, or a core parameter offered for re-estimation (core_params.py)."""
    return core_params.get(name) if core_params.is_core(name) else EFFECTS[name]


def _kind(name: str) -> str:
    return "core parameter re-estimated" if core_params.is_core(name) else "library effect"


def _err_json(t: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    return {p: {"nrmse": (v["nrmse"] if math.isfinite(v["nrmse"]) else None), "signals": v["signals"]} for p, v in t.items()}


def _structure_of(problem: engine.Problem, fit: engine.ModelFit) -> tuple[list[structure.Finding], int]:
    r = fit.residual(problem)
    z = r * fit.weights(problem)
    found, n = structure.analyse(problem.table, r, z, problem.used, problem.group, predicted=fit.f)
    extra = transient.findings(problem.table, r, z, problem.used, problem.group,  # command timing's signature
                               problem=problem, f=fit.f, w=fit.weights(problem))
    return found + extra, n + len(extra)


def _score(findings: Sequence[structure.Finding], n_tests: int) -> float:
    return float(sum(f.score for f in structure.significant(list(findings), n_tests)))


def _finding_scores(findings: Sequence[structure.Finding], n_tests: int) -> dict[tuple[str, str], float]:
    """Score of the strongest significant finding per (group, variable)."""
    out: dict[tuple[str, str], float] = {}
    for f in structure.significant(list(findings), n_tests):
        key = (f.group, f.variable)
        out[key] = max(out.get(key, 0.0), f.score)
    return out


def _base_free(robot: Robot, obs: Observations, procs: Sequence[str],
               fit_info: Mapping[str, Any] | None = None,
               say: Callable[[str], None] | None = None) -> tuple[Any, list[str], list[str]]:
    """Start robot, identifiable free parameters of the declared model, notes (via fitting.fit;
    from `fit_info`, the model file's [fit] table, when `robot` is what `omnibench fit` wrote for
    these runs: fitting.refit_needed)."""
    from omnibench.analysis import fitting

    fit_procs = [p for p in fitting.DEFAULT_PROCEDURES if p in procs]
    notes: list[str] = []
    if not fit_procs:
        return robot, [], ["no sweep/forward/lateral data: the declared model's coefficients are held at the robot file's values"]
    if fit_info and not fitting.refit_needed(robot, obs, fit_procs, fit_info):
        free = [str(p) for p in fit_info["fitted"]]
        for p, entry in fit_info.get("parameters", {}).items():
            if p not in free:
                notes.append(f"{p} held at its robot-file value: {entry.get('reason', '')}")
        return robot, free, notes
    res = fitting.fit(robot, obs, procedures=fit_procs, progress=(lambda m: say(f"declared model: {m}")) if say else None)
    free = [p for p in res.fitted]
    for p in res.free:
        if p not in free:
            notes.append(f"{p} held at its robot-file value: {res.identifiable[p].reason}")
    return res.robot, free, notes


def diagnose(robot: Robot, obs: Observations, *, candidates: Sequence[str] | None = None,
             procedures: Sequence[str] | None = None, alpha: float = ALPHA, max_effects: int = 3,
             top_k: int = 4, folds: int = engine.CV_FOLDS, seed: int = 0,
             progress: Callable[[str], None] | None = None, fit_info: Mapping[str, Any] | None = None) -> Diagnosis:
    """Close the loop on `obs` for the declared `robot`; see the module docstring. fit_info: the
    model file's [fit] table (model_file.load_model), if any: a model `omnibench fit` wrote for
    these very runs is not fitted again (`_base_free`)."""
    say = _timed(progress)
    procs = [p for p in (procedures or obs.procedures()) if len(obs.table(p))]
    if not procs:
        raise UserError("no observations to diagnose")
    names = list(candidates) if candidates is not None else list(EFFECTS)
    for n in names:
        if n not in EFFECTS:
            raise UserError(f"unknown candidate effect {n!r}; known: {', '.join(EFFECTS)}")
    pool: list[Effect] = [EFFECTS[n] for n in names if n not in robot.effects]
    say("fitting the declared model")
    start, free, notes = _base_free(robot, obs, procs, fit_info, say)
    free += [f"{e}.{p}" for e in robot.effects if e in EFFECTS for p in EFFECTS[e].fit]

    def declared_fit(o: Observations) -> tuple[tuple[engine.Problem, engine.ModelFit], float, dict[str, float]]:
        pr = engine.Problem(o, procs)
        if not pr.used.any():
            raise UserError("no usable measurements in these runs")
        say(f"fitting the declared model to all {len(pr)} measurements ({len(free)} parameters, "
            f"{', '.join(pr.procedures)})")
        f = engine.fit_model(pr, start, free, max_nfev=POLISH_NFEV)
        return (pr, f), f.deviance, {}

    # runs of unknown mode: the declared model fitted in every assignment of modes, the lowest
    # profile deviance kept, and those modes for the rest of the diagnosis (analysis/modes.py)
    obs, (problem, base), mode_profile = unknown_modes.profile_modes(obs, procs, declared_fit, say=say)
    if mode_profile is not None:
        notes.append(mode_profile.text() + "; the diagnosis keeps these modes")
    fold = engine.cv_folds(problem, folds, seed)
    base_struct, n_tests = _structure_of(problem, base)
    base_sig = structure.significant(base_struct, n_tests)
    current, cur_struct, cur_ntests = base, base_struct, n_tests
    base_err = engine.error_table(problem, engine.heldout_residuals(problem, base, fold))
    selected: list[Candidate] = []
    rejected: list[Candidate] = []
    ambiguous: list[dict[str, Any]] = []
    exposed: dict[str, structure.Finding] = {}
    def evaluate(c: Candidate, effects: Sequence[Effect], cf: engine.ModelFit, p_needed: float) -> bool:
        """Fill c's evidence from the refit cf (the current model plus `effects`) and judge it."""
        c.fitted, c.fit = True, cf
        c.values = {p: cf.values[p] for p in cf.free if p.split(".")[0] in {e.name for e in effects}}
        c.se = {p: cf.se[p] for p in c.values}
        c.q = sum(e.n_params for e in effects)
        c.lr, c.p = engine.lr_test(current, cf, c.q)
        c.aic_drop = c.lr - 2 * c.q
        w_common = current.weights(problem)
        ho0 = engine.heldout_residuals(problem, current, fold)
        ho1 = engine.heldout_residuals(problem, cf, fold, w_common)
        c.cv_gain = engine.cv_score(problem, ho0, w_common) - engine.cv_score(problem, ho1, w_common)
        # the per-procedure errors as they will be reported (each model with its own weights),
        # compared with the declared model's, so small losses cannot pile up round after round
        e1 = engine.error_table(problem, engine.heldout_residuals(problem, cf, fold))
        c.worse = {p: (base_err[p]["nrmse"], e1[p]["nrmse"]) for p in base_err
                   if p in e1 and _worse(base_err[p], e1[p])}
        st, nt = _structure_of(problem, cf)
        c.structure_before, c.structure_after = _score(cur_struct, cur_ntests), _score(st, nt)
        c.struct = (st, nt)
        procs_of = {TABLE_OF.get(p, p) for e in effects for p in e.procedures}
        c.acted, c.remaining = _acted_on((cur_struct, cur_ntests), c.struct, procs_of)
        return _judge(c, effects, p_needed, (cur_struct, cur_ntests), procs_of)

    def veto(fit: engine.ModelFit) -> str:
        """'' or words: a procedure whose held-out error the fit makes worse beyond its noise."""
        e1 = engine.error_table(problem, engine.heldout_residuals(problem, fit, fold))
        bad = [f"{p} ({100 * base_err[p]['nrmse']:.2f} % -> {100 * e1[p]['nrmse']:.2f} %)" for p in base_err
               if p in e1 and _worse(base_err[p], e1[p])]
        return ("makes the held-out error worse beyond its noise in " + ", ".join(bad)) if bad else ""

    rnd, lazy = 0, True
    fits_done: dict[str, Any] = {}  # this round's candidate fits (name -> fit, form, margin), for its retry
    while True:
        if lazy:
            rnd, fits_done = rnd + 1, {}
        if rnd > max_effects or (not pool and not core_params.candidates(problem, current)):
            break
        n_sets = sum(len(e.fit) * max(len(e.forms), 1) for e in pool)
        if lazy:
            say(f"round {rnd}: screening {len(pool)} candidate effects ({n_sets} parameter sets to simulate)")
            scr = _screen(problem, current, pool) if pool else None
        m = len(pool) + len(core_params.candidates(problem, current))
        thr = {e.name: _lr_threshold(alpha / m, e.n_params) for e in pool}
        order = sorted(pool, key=lambda e: -scr.approx_lr[e.name] / thr[e.name])
        tried: list[Candidate] = []
        passing: list[Candidate] = []
        deferred: list[Effect] = []  # not refitted: an adequate candidate's fitted LR dominates theirs
        fit_seconds: list[float] = []  # CPU seconds of each candidate fit this round (for the ETA)
        best_ratio = max((scr.approx_lr[e.name] / thr[e.name] for e in pool), default=0.0)
        # how many the screen sends to a full fit (the fallback may add more): for the progress line
        strong = [e for e in pool if scr.approx_lr[e.name] / thr[e.name]
                  >= max(RELATIVE_SCREEN * best_ratio, SCREEN_FRACTION)]
        n_lead = min(top_k, len(strong))
        unphysical = 0  # sent to a fit by their first-order LR, which holds only outside their range
        for e in order:
            c = Candidate(e.name, rnd, scr.approx_lr[e.name], q=e.n_params)
            ratio = scr.approx_lr[e.name] / thr[e.name]
            n_fitted = len([t for t in tried if t.fitted]) + unphysical
            # refit the top_k; when all of those fail, keep going down the ranking (up to MAX_FITS)
            fallback = not passing and top_k <= n_fitted < MAX_FITS
            leading = ratio >= RELATIVE_SCREEN * best_ratio
            winner = _dominating(passing, scr.approx_lr[e.name]) if lazy else None
            if ((n_fitted < top_k and leading) or fallback) and ratio >= SCREEN_FRACTION and winner is not None:
                c.reason = (f"first-order test LR ≈ {c.approx_lr:.1f}, not refitted: {winner.name}'s fitted "
                            f"LR = {winner.lr:.1f} is over {DOMINANCE:.0f} times that")
                say(f"round {rnd}: not fitting {e.name} ({c.reason})")
                deferred.append(e)
            elif (((n_fitted < top_k and leading) or fallback) and ratio >= SCREEN_FRACTION and lazy
                  and scr.in_range[e.name] < SCREEN_FRACTION * thr[e.name]):
                # it takes the place of a fit that fails (the next in the ranking is not promoted);
                # when the round is done again (its winner refused), every candidate is refitted
                unphysical += 1
                c.reason = (f"first-order test LR ≈ {c.approx_lr:.1f} only with {e.name} outside its physical "
                            f"range ({scr.in_range[e.name]:.1f} inside it, {thr[e.name]:.1f} needed): not refitted")
                say(f"round {rnd}: not fitting {e.name} ({c.reason})")
            elif ((n_fitted < top_k and leading) or fallback) and ratio >= SCREEN_FRACTION:
                n_all = max(n_lead, n_fitted + 1)
                if e.name not in fits_done:
                    say(f"round {rnd}: fitting {e.name} (candidate {n_fitted + 1} of {n_all}"
                        + (f", {len(e.forms)} forms" if len(e.forms) > 1 else "")
                        + _eta(fit_seconds, n_all - n_fitted) + ")")
                    t_fit = time.process_time()
                    try:
                        fits_done[e.name] = _fit_forms(problem, current, e, scr.estimate[e.name], thr[e.name])
                    except (np.linalg.LinAlgError, ValueError) as exc:  # a numerically hopeless start
                        fits_done[e.name] = exc
                    finally:
                        fit_seconds.append(time.process_time() - t_fit)
                if isinstance(fits_done[e.name], Exception):
                    c.reason = f"fit failed ({fits_done[e.name].__class__.__name__})"
                    tried.append(c)
                    continue
                cf, c.form, c.form_margin = fits_done[e.name]
                if evaluate(c, [e.with_form(c.form)], cf, alpha / m):
                    passing.append(c)
            else:
                c.reason = (f"first-order test LR ≈ {c.approx_lr:.1f}, far below the {thr[e.name]:.1f} needed"
                            if scr.approx_lr[e.name] < SCREEN_FRACTION * thr[e.name] else
                            f"first-order test LR ≈ {c.approx_lr:.1f}, far below the leading candidates'")
                if scr.distinct[e.name] == 0.0:
                    c.reason = (f"not testable with these data (it changes no prediction of them; "
                                f"shows in {', '.join(e.procedures)})")
                elif scr.distinct[e.name] < CONFOUNDED:
                    c.reason = ("not testable with these data (what it would change, a change of the "
                                f"fitted parameters changes alike; shows in {', '.join(e.procedures)})")
            tried.append(c)
        # a declared parameter the data say is wrong competes on the same evidence (core_params.py)
        core_pass, core_tried = core_params.round_candidates(
            problem, current, rnd, assess=lambda c, e, cf: evaluate(c, [e], cf, alpha / m), make=Candidate, say=say)
        passing += core_pass
        tried += core_tried
        passing.sort(key=lambda c: -c.aic_drop)
        passing = _prefer_nested(passing, alpha / m)
        # a core parameter (core_params.py) is a correction of the declared model, not a new
        # mechanism standing in for another: it needs no adequacy (a wrong declared value left in
        # biases every later test; what it leaves is reported, and sought in the next round)
        adequate = [c for c in passing if not c.remaining or core_params.is_core(c.name)]
        added: list[Candidate] = []
        # two effects at once, led by a significant one (no significant single, no pair: what one
        # effect cannot show, two are not tried for; pair fits are the costly part)
        leads = [c for c in tried if c.fitted and c.aic_drop > 0 and c.p < alpha / m
                 and not core_params.is_core(c.name)]
        pairs: list[tuple[list[Candidate], list[Candidate]]] = []  # fitted once, when first needed

        def best_pair(adequate_only: bool = True) -> list[Candidate]:
            if not pairs:
                singles = {n: f[0] for n, f in fits_done.items() if not isinstance(f, Exception) and not EFFECTS[n].forms}
                pairs.append(_best_pairs(problem, current, leads, pool, evaluate, alpha, m, say, rnd, singles)
                             if leads else ([], []))
            pair = pairs[0][0 if adequate_only else 1]
            return [] if pair and pair[0].reason else pair  # a pair refused after its final fit: once

        def pair_despite_structure() -> list[Candidate]:
            return best_pair(adequate_only=False)

        first = _first_choice(passing, leads, pair_despite_structure)
        if first:
            added = _polished(first, problem, say, rnd, veto)
        if not added:
            # no single candidate both earns its place and removes the structure it acts on
            pair = best_pair()
            if pair:
                added = _polished(pair, problem, say, rnd, veto)
        for c in adequate:
            if added:
                break
            if not c.reason:  # not already refused after its final fit
                added = _polished(_instead_of_core(c, passing, leads, pair_despite_structure), problem, say, rnd, veto)
        for c in passing:
            if c.remaining and not any(c is a for a in added) and not core_params.is_core(c.name):
                c.reason = ("does not remove the structure it acts on: still " + "; ".join(
                    _where(c.struct, k) for k in c.remaining) + " with it (an effect of another form, or a "
                    "second effect, is at work: left unexplained)")
        if not added and deferred and lazy:
            # the one that dominated them was refused after its final fit: the round again, with
            # every candidate the screen sends to a fit refitted (the fits already made are kept)
            say(f"round {rnd}: nothing added; fitting the candidates left out: {', '.join(e.name for e in deferred)}")
            lazy = False
            continue
        if not added:
            rejected += tried
            break
        lazy = True
        best = added[0]
        for c in passing:
            if any(c is a for a in added):
                continue
            diff = best.aic_drop - c.aic_drop
            if best.name in getattr(_spec(c.name), "nests", ()) and not c.remaining:
                c.reason = (f"contains {best.name} as a special case, and its extra parameters are not "
                            f"significant given it (LR = {c.lr - best.lr:.1f} for {c.q - best.q})")
            elif diff < AMBIGUOUS and not c.remaining:
                ambiguous.append({"chosen": best.name, "alternative": c.name, "aic_difference": float(diff),
                                  "experiment": separating_experiment(_spec(best.name), _spec(c.name))})
                c.reason = f"fits almost as well as {best.name} (AIC difference {diff:.1f}): not separable with these data"
            elif not c.remaining:
                c.reason = f"significant, but {best.name} explains the data better (AIC difference {diff:.1f})"
        for c in added:
            assert c.struct is not None, "an added candidate has been refitted"
            c.verdict = "selected"
            selected.append(c)
            exposed_f = _exposing_finding(cur_struct, cur_ntests, c.struct)
            if exposed_f is not None:
                exposed[c.name] = exposed_f
            say(f"round {rnd}: added {c.name}")
        names_added = {c.name for c in added}
        rejected += [c for c in tried if c.name not in names_added]
        current = best.fit
        assert best.struct is not None, "an added candidate has been refitted"
        cur_struct, cur_ntests = best.struct
        pool = [e for e in pool if e.name not in names_added]
    # "added" reports the final model's values, not those of the round that added the effect
    for c in selected:
        c.values = {p: current.values[p] for p in c.values if p in current.values}
        c.se = {p: current.se[p] for p in c.values}
    final_sig = structure.significant(cur_struct, cur_ntests)
    say("held-out errors")
    base_ho = engine.heldout_residuals(problem, base, fold)
    final_ho = engine.heldout_residuals(problem, current, fold)
    if (fold < 0).any():
        notes.append("procedures with a single run step cannot be held out: "
                     + ", ".join(sorted(set(problem.table.loc[fold < 0, "procedure"]))))
    if not base.converged or not current.converged:
        notes.append("a fit stopped at its evaluation limit; values are the last iterate")
    return Diagnosis(declared=robot, extended=current.robot, base_fit=base, final_fit=current, selected=selected,
                     rejected=rejected, ambiguous=ambiguous, unexplained=final_sig, base_structure=base_sig,
                     before=engine.error_table(problem, base_ho), after=engine.error_table(problem, final_ho),
                     problem=problem, base_heldout=base_ho, final_heldout=final_ho, notes=notes, exposed_by=exposed,
                     mode_profile=mode_profile)


def _timed(progress: Callable[[str], None] | None) -> Callable[[str], None]:
    """progress with the time since the diagnosis started and, from the second line on, the
    time the previous step took (what the next similar step will take, roughly)."""
    if progress is None:
        return lambda s: None
    t0 = time.monotonic()
    last = [t0]

    def say(msg: str) -> None:
        now = time.monotonic()
        step = f", previous step {now - last[0]:.0f} s" if last[0] > t0 else ""
        last[0] = now
        progress(f"{msg} [{_mmss(now - t0)}{step}]")
    return say


def _eta(seconds: Sequence[float], remaining: int) -> str:
    """'' or ', about m:ss CPU left for them': the mean CPU time of the candidate fits done so far
    times the `remaining` ones (this one included; rough: candidates and their forms differ)."""
    if not seconds or remaining <= 0:
        return ""
    return f", about {_mmss(remaining * float(np.mean(seconds)))} CPU left for them"


def _mmss(s: float) -> str:
    return f"{int(s // 60)}:{int(s % 60):02d}"


def _dominating(passing: Sequence[Candidate], approx_lr: float) -> Candidate | None:
    """An adequate library candidate fitted this round whose likelihood ratio is over DOMINANCE
    times `approx_lr` (a candidate's first-order LR), if any: that candidate is not refitted."""
    return next((c for c in passing if not c.remaining and not core_params.is_core(c.name)
                 and c.lr > DOMINANCE * max(approx_lr, 0.0)), None)


def _prefer_nested(passing: list[Candidate], p_needed: float) -> list[Candidate]:
    """`passing` (best AIC first) with a simpler candidate moved ahead of one that contains it as
    a special case (Effect.nests) when the containing one's extra parameters are not significant
    given it (LR test at p_needed): AIC alone takes any parameter that buys a deviance drop of 2."""
    out = list(passing)
    for _ in range(len(out)):
        top = out[0] if out else None
        if top is None or core_params.is_core(top.name) or top.fit is None:
            break
        simpler = [c for c in out[1:] if c.name in EFFECTS[top.name].nests and not c.remaining and c.fit is not None
                   and c.fit.deviance - top.fit.deviance < _lr_threshold(p_needed, max(top.q - c.q, 1))]
        if not simpler:
            break
        out.remove(simpler[0])
        out.insert(0, simpler[0])
    return out


def _at_bound(effect: Effect, values: Mapping[str, float]) -> str:
    """'' or words naming a fitted parameter of `effect` (among `values`) that sits on its bound."""
    specs = {p.name: p for p in effect.term.params}
    for full, v in values.items():
        name, _, par = full.partition(".")
        par = par or name  # a core parameter (core_params.py) is its own only parameter
        if name != effect.name:
            continue
        spec = specs[par]
        lo, hi = spec.lower, spec.upper
        span = (hi - lo) if math.isfinite(hi - lo) else max(abs(v), 1.0)
        for edge in (lo, hi):
            if math.isfinite(edge) and edge != 0.0 and abs(v - edge) <= 1e-3 * span:
                return f"{par} = {v:.4g} {spec.unit}, bound {edge:g}"
    return ""


def _worse(before: Mapping[str, Any], after: Mapping[str, Any]) -> bool:
    """Is a procedure's held-out error worse beyond its own noise? Its mean square may rise by
    WORSE_SE standard errors of a mean of n squares (relative SE sqrt(2 / n))."""
    n = sum(int(v.get("n", 0)) for v in before.get("signals", {}).values())
    e0, e1 = before["nrmse"], after["nrmse"]
    if not (n > 0 and math.isfinite(e0) and math.isfinite(e1) and e0 > 0):
        return False
    return (e1 / e0) ** 2 - 1.0 > WORSE_SE * math.sqrt(2.0 / n)


def _acted_on(before: tuple[list, int], after: tuple[list, int], procs: set[str]) -> tuple[list, list]:
    """(structure it acted on, of which still significant): the significant (group, variable)
    structure of the procedures where the effect shows that the new model reduced by at least
    PARTIAL of its strength, and those of them that are still significant with it."""
    b = {k: v for k, v in _finding_scores(*before).items() if k[0].split("/")[0] in procs}
    a = _finding_scores(*after)
    acted = [k for k, v in b.items() if a.get(k, 0.0) <= (1 - PARTIAL) * v]
    return acted, [k for k in acted if a.get(k, 0.0) > 0.0]


def _where(struct: tuple[list, int] | None, key: tuple[str, str]) -> str:
    """Words for the strongest finding of (group, variable) in struct."""
    found = [f for f in (struct[0] if struct else []) if (f.group, f.variable) == key]
    if found:
        f = min(found, key=lambda f: f.p)
        return f"{f.location()} [p={f.p:.1e}]"
    return f"{key[0]} against {key[1]}"


def _judge(c: Candidate, effects: Sequence[Effect], p_needed: float, before: tuple[list, int],
           procs: set[str]) -> bool:
    """Does a refitted candidate (one effect, or a pair) earn its place? Sets c.reason when not.
    Whether it is adequate (removes the structure it acts on) is judged by the caller."""
    own = lambda e: {k: v for k, v in c.values.items() if k.split(".")[0] == e.name}  # noqa: E731
    zero = [e for e in effects if own(e) and all(abs(v) < ZERO_SE * c.se.get(k, 0.0) for k, v in own(e).items())]
    bound = next((f"{e.name}: {_at_bound(e, c.values)}" for e in effects if _at_bound(e, c.values)), "")
    if not (c.p < p_needed):
        c.reason = f"not significant: LR = {c.lr:.1f} for {c.q} parameter(s), p = {c.p:.1e} (needs < {p_needed:.1e})"
    elif zero:
        c.reason = ("its fitted size is indistinguishable from zero ("
                    + ", ".join(f"{k} = {v:.3g} ± {c.se.get(k, float('nan')):.2g}" for k, v in own(zero[0]).items())
                    + "): the likelihood gain comes from refitting the other parameters, not from the effect")
    elif bound:
        c.reason = (f"its fit runs to the edge of the physical range ({bound}): it stands in "
                    "for something else rather than measuring itself")
    elif not (c.cv_gain > 2 * c.q):
        change = f"falls by {c.cv_gain:.1f}" if c.cv_gain >= 0 else f"rises by {-c.cv_gain:.1f}"
        c.reason = f"does not earn its parameters on held-out steps (held-out weighted error {change}, needs to fall by > {2 * c.q})"
    elif c.worse:
        c.reason = "makes the held-out error worse beyond its noise in " + ", ".join(
            f"{p} ({100 * a:.2f} % -> {100 * b:.2f} %)" for p, (a, b) in c.worse.items())
    elif c.struct is None or (not c.acted and (structure.significant(*before) or c.round > 1)):
        # (LR alone may add an effect only to a declared model whose residual the structure
        # tests cannot judge: a few energy runs; after that, an addition must act on structure)
        c.reason = (f"explains none of the residual structure where it shows ({', '.join(sorted(procs))}; score "
                    f"{c.structure_before:.0f} -> {c.structure_after:.0f}, no structure there loses half its "
                    "strength): it leans on structure another mechanism makes")
    else:
        return True
    return False


def _screen(problem: engine.Problem, fit: engine.ModelFit, pool: Sequence[Effect]) -> engine.Screen:
    """engine.screen over every form of every candidate; per candidate its most promising form's."""
    variants = [(e, f) for e in pool for f in (list(e.forms) or [""])]
    out = engine.Screen({}, {}, {})
    for form in sorted({f for _, f in variants}):
        effs = [e.with_form(form) for e, f in variants if f == form]
        scr = engine.screen(problem, fit, effs)
        for e in effs:
            if e.name not in out.approx_lr or scr.approx_lr[e.name] > out.approx_lr[e.name]:
                out.approx_lr[e.name], out.estimate[e.name] = scr.approx_lr[e.name], scr.estimate[e.name]
            out.distinct[e.name] = max(out.distinct.get(e.name, 0.0), scr.distinct[e.name])
            out.in_range[e.name] = max(out.in_range.get(e.name, 0.0), scr.in_range[e.name])
    return out


def _fit_forms(problem: engine.Problem, current: engine.ModelFit, e: Effect, estimate: Mapping[str, float],
               needed: float | None = None) -> tuple[engine.ModelFit, str, dict[str, float]]:
    """Refit `e` in each of its forms: (best fit, its form, other form -> AIC above it); needed:
    the likelihood ratio it must reach (engine.hopeless)."""
    fits = []
    for form in (list(e.forms) or [""]):
        try:
            fits.append((engine.fit_candidate(problem, current, e.with_form(form), estimate, needed=needed), form))
        except (np.linalg.LinAlgError, ValueError):
            if len(e.forms) <= 1:
                raise
    if not fits:
        raise ValueError("no form could be fitted")
    fits.sort(key=lambda x: x[0].deviance)
    best, form = fits[0]
    return best, form, {f: float(cf.deviance - best.deviance) for cf, f in fits[1:]}


def _polished(cands: list[Candidate], problem: engine.Problem, say: Callable[[str], None], rnd: int,
              veto: Callable[[engine.ModelFit], str]) -> list[Candidate]:
    """Polish the accepted fit to convergence (a candidate fit stops after a few evaluations, and
    the next round's likelihood ratios must not be inflated by convergence the next refit would
    merely continue), then check the bounds on the polished values: [] if one sits on its bound."""
    c0 = cands[0]
    say(f"round {rnd}: final fit with {' and '.join(c.name for c in cands)}")
    pol = engine.fit_model(problem, c0.fit.robot, c0.fit.free, max_nfev=POLISH_NFEV)
    fit = pol if pol.deviance <= c0.fit.deviance else c0.fit
    for c in cands:
        bound = _at_bound(_spec(c.name), {p: fit.values[p] for p in c.values})
        if bound:
            c.reason = (f"its final fit runs to the edge of the physical range ({bound}): it stands in for "
                        "something else rather than measuring itself")
            return []
    why = veto(fit)
    zero = [c.name for c in cands if c.values and all(abs(fit.values[p]) < ZERO_SE * fit.se[p] for p in c.values)]
    if zero:
        why = f"is indistinguishable from zero ({', '.join(zero)})"
    if why:
        for c in cands:
            c.reason = f"after its final fit it {why}"
        return []
    struct = _structure_of(problem, fit)
    for c in cands:
        c.fit, c.struct = fit, struct
        c.values = {p: fit.values[p] for p in c.values}
        c.se = {p: fit.se[p] for p in c.values}
    return cands


def _first_choice(passing: Sequence[Candidate], leads: Sequence[Candidate],
                  pair_despite_structure: Callable[[], list[Candidate]]) -> list[Candidate]:
    """What a round tries to add first: the best passing candidate (by AIC) if it is adequate,
    else nothing (pairs are tried next); a core re-estimate as `_instead_of_core` says."""
    if not passing or (passing[0].remaining and not core_params.is_core(passing[0].name)):
        return []
    return _instead_of_core(passing[0], passing, leads, pair_despite_structure)


def _instead_of_core(c: Candidate, passing: Sequence[Candidate], leads: Sequence[Candidate],
                     pair_despite_structure: Callable[[], list[Candidate]]) -> list[Candidate]:
    """[c], or the pair that comes before it. A core re-estimate needs no adequacy, so it could
    stand in for two mechanisms that explain more: when no library effect is adequate alone, a
    pair that earns its place in all else (`pair_despite_structure`) and beats the re-estimate by
    more than AMBIGUOUS AIC is added instead, with the same exemption (what it leaves is
    reported, and sought in the next round)."""
    if (core_params.is_core(c.name) and len(leads) > 1
            and all(x.remaining for x in passing if not core_params.is_core(x.name))):
        pair = pair_despite_structure()
        if pair and pair[0].aic_drop > c.aic_drop + AMBIGUOUS:
            return pair
    return [c]


def _best_pairs(problem: engine.Problem, current: engine.ModelFit, fitted: list[Candidate], pool: Sequence[Effect],
                evaluate: Callable, alpha: float, m: int, say: Callable[[str], None], rnd: int,
                singles: Mapping[str, engine.ModelFit] | None = None) -> tuple[list[Candidate], list[Candidate]]:
    """Two effects at once, when no single one is adequate. Each of the PAIR_LEADS best fitted
    candidates is taken as a provisional model, the others are screened against what it leaves,
    and it is refitted together with the PAIR_TOP most promising of them. A pair is added when it
    earns its place, removes the structure it acts on, and each effect is significant given the
    other. Returns the best such pair (its two candidates, sharing the pair's fit, or []) and the
    best that passes all but the structure (what competes with a core re-estimate). singles: this
    round's fits of one effect alone (effects of one form), reused for "the first given the second"."""
    best: tuple[float, list[Candidate]] | None = None
    best_any: tuple[float, list[Candidate]] | None = None
    done: set[frozenset] = set()
    for lead in sorted(fitted, key=lambda c: -c.aic_drop)[:PAIR_LEADS]:
        others = [e for e in pool if e.name != lead.name]
        if not others:
            continue
        scr = _screen(problem, lead.fit, others)
        thr = {e.name: _lr_threshold(alpha / m, e.n_params) for e in others}
        partners = sorted(others, key=lambda e: -scr.approx_lr[e.name] / thr[e.name])[:PAIR_TOP]
        for e2 in partners:
            key = frozenset((lead.name, e2.name))
            if key in done or scr.approx_lr[e2.name] < SCREEN_FRACTION * thr[e2.name]:
                continue
            done.add(key)
            e1 = EFFECTS[lead.name].with_form(lead.form)
            if e2.name in EFFECTS[lead.name].nests or lead.name in e2.nests:
                say(f"round {rnd}: not fitting the pair {lead.name} + {e2.name}: one contains the other "
                    "as a special case (delays add: the pair fits nothing the larger one cannot)")
                continue
            if scr.in_range[e2.name] < SCREEN_FRACTION * thr[e2.name]:
                # its fit starts from the estimate clipped into the physical range, where the
                # same first-order test gives it too little: an effect that helps only with an
                # unphysical sign (the fit ends at the range's edge, where it does nothing)
                say(f"round {rnd}: not fitting the pair {lead.name} + {e2.name}: {e2.name}'s first-order "
                    f"LR given {lead.name} is {scr.approx_lr[e2.name]:.1f} only outside its physical range, "
                    f"{scr.in_range[e2.name]:.1f} inside (needs {thr[e2.name]:.1f})")
                continue
            say(f"round {rnd}: fitting the pair {lead.name} + {e2.name}")
            # the second must matter given the first: its settle passes stop once it cannot
            need2 = _lr_threshold(alpha / m, e2.n_params)
            try:
                # from the lead's own fit (its effect and the core parameters already moved
                # there): the pair's passes start one effect from their end, not two
                cf = engine.fit_candidates(problem, lead.fit, [e2],
                                           [{f"{e2.name}.{k}": v for k, v in scr.estimate[e2.name].items()}],
                                           needed=(lead.fit.deviance, need2))
            except (np.linalg.LinAlgError, ValueError):
                continue
            if lead.fit.deviance - cf.deviance < need2:
                say(f"round {rnd}: the pair {lead.name} + {e2.name}: {e2.name} given {lead.name} reaches LR "
                    f"{lead.fit.deviance - cf.deviance:.1f} of the {need2:.1f} it needs")
                continue
            pc = Candidate(f"{lead.name}+{e2.name}", rnd, float("nan"))
            if not evaluate(pc, [e1, e2], cf, alpha / m):
                say(f"round {rnd}: the pair {lead.name} + {e2.name} does not earn its place "
                    f"(AIC drop {pc.aic_drop:.1f}): {pc.reason}")
                continue
            # and the first given the second
            alone = (singles or {}).get(e2.name)
            if alone is None:
                try:
                    alone = engine.fit_candidate(problem, current, e2, scr.estimate[e2.name])
                except (np.linalg.LinAlgError, ValueError):
                    alone = None
            if alone is not None and alone.deviance - cf.deviance < _lr_threshold(alpha / m, e1.n_params):
                continue
            if pc.remaining:
                say(f"round {rnd}: the pair {lead.name} + {e2.name} (AIC drop {pc.aic_drop:.1f}) leaves the "
                    "structure it acts on")
            improves_any = best_any is None or pc.aic_drop > best_any[0]
            improves_adequate = not pc.remaining and (best is None or pc.aic_drop > best[0])
            if improves_any or improves_adequate:
                pair = []
                for name, form, margin, partner in ((lead.name, lead.form, lead.form_margin, e2.name),
                                                    (e2.name, "", {}, lead.name)):
                    n = Candidate(name, rnd, pc.approx_lr, fitted=True,
                                  values={k: v for k, v in pc.values.items() if k.startswith(name + ".")},
                                  lr=pc.lr, p=pc.p, q=pc.q, aic_drop=pc.aic_drop, cv_gain=pc.cv_gain,
                                  structure_before=pc.structure_before, structure_after=pc.structure_after,
                                  fit=cf, struct=pc.struct, form=form, form_margin=margin, acted=pc.acted,
                                  partner=partner)
                    n.se = {k: pc.se[k] for k in n.values}
                    pair.append(n)
                if improves_any:
                    best_any = (pc.aic_drop, pair)
                if improves_adequate:
                    best = (pc.aic_drop, pair)
    return (best[1] if best else []), (best_any[1] if best_any else [])


def _lr_threshold(p: float, q: int) -> float:
    return chi2_isf(p, q)


def _exposing_finding(before: Sequence[structure.Finding], n_before: int, after: tuple[list, int]):
    """The significant structure of the previous model that the new effect reduced the most."""
    sig = structure.significant(list(before), n_before)
    if not sig:
        return None
    post = {(f.group, f.variable, f.test): f for f in after[0]}
    return max(sig, key=lambda f: f.score - post.get((f.group, f.variable, f.test), f).score)


def separating_experiment(a: Effect, b: Effect) -> str:
    """Words: which experiment would tell effect a from effect b."""
    if b.name in a.separates:
        return a.separates[b.name]
    if a.name in b.separates:
        return b.separates[a.name]
    pa, pb = set(a.procedures), set(b.procedures)
    only_a, only_b = sorted(pa - pb), sorted(pb - pa)
    if only_a or only_b:
        return (f"add runs that only one of them affects: {a.name} shows in {', '.join(a.procedures)}, "
                f"{b.name} in {', '.join(b.procedures)}")
    return (f"vary what they depend on differently: {a.name} shows against {a.variable}, "
            f"{b.name} against {b.variable}; extend that range (more levels, both directions, heavier wheels)")
