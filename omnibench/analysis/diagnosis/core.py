"""diagnose(): fit the declared model, find structure, add the effect that earns its place, repeat.

Algorithm (docs/diagnose.md has the long form):

1. Fit the declared model (parameters the data can identify, per `fitting.fit`) by profile
   likelihood over every entry of every procedure (engine.py).
2. Study the residual: binned-mean and runs tests per group against speed, duty, load,
   direction, wheel, time, current, payload, step order (structure.py).
3. Screen every library candidate with a first-order score test (residual projected on the
   candidate's sensitivities), refit the most promising `top_k` exactly (nonlinear, together
   with the model's own parameters).
4. A candidate earns its place when (a) its likelihood-ratio test against the current model
   passes p < alpha / m (m candidates tested: Bonferroni), (b) it lowers the held-out
   (K-fold over run steps) weighted error by more than 2 per parameter, (c) its fitted values
   are inside their physical range (not on a bound), and (d) it removes at least half of the
   strength (-log10 p) of some significant residual structure (a procedure/signal group against
   one variable); otherwise it only leans on structure something else makes: reported, not added. Among those, the lowest AIC wins; others within AMBIGUOUS of it
   are reported as not separable with these data, with the experiment that would separate them.
5. Add the winner, refit, repeat until nothing earns its place (or `max_effects`).
6. Report what structure remains, and the held-out error before and after per procedure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from omnibench.analysis.diagnosis import core_params, engine, structure, transient
from omnibench.analysis.observations import Observations
from omnibench.effects.library import EFFECTS, Effect
from omnibench.errors import UserError

ALPHA = 1e-3  # family-wise level for adding an effect
AMBIGUOUS = 10.0  # AIC difference below which two candidates are not told apart
PARTIAL = 0.5  # a candidate must remove at least this fraction of the residual structure
SCREEN_FRACTION = 0.5  # screen LR below this fraction of the add threshold: not refitted
WORSE = 0.05  # no procedure's held-out error may end more than this fraction above the declared model's
MAX_FITS = 6  # refits per round when the top_k all fail
POLISH_NFEV = 60  # evaluations allowed when fitting the declared and each accepted model
ZERO_SE = 2.0  # a candidate whose every fitted parameter is within this many SE of 0 is absent
RELATIVE_SCREEN = 0.02  # nor below this fraction of the best candidate's (relative to threshold)
CONFOUNDED = 1e-6  # share of a candidate's sensitivity left after the fitted parameters' directions


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

    def evidence(self) -> dict[str, Any]:
        def f(x: float) -> float | None:
            return float(x) if x is not None and math.isfinite(x) else None

        return {"round": self.round, "likelihood_ratio": f(self.lr), "parameters_added": self.q, "p_value": f(self.p),
                "aic_drop": f(self.aic_drop), "heldout_gain": f(self.cv_gain), "screen_lr": f(self.approx_lr),
                "structure_before": f(self.structure_before), "structure_after": f(self.structure_after)}


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
                from omnibench.analysis.diagnosis.timing import wheel_order_note

                if wheel_order_note(c.name, c.values, c.se):
                    L.append(f"    {wheel_order_note(c.name, c.values, c.se)}")
                L.append(f"    evidence: LR = {c.lr:.1f} for {c.q} parameter(s), p = {c.p:.1e}; AIC -{c.aic_drop:.1f}; "
                         f"held-out weighted error -{c.cv_gain:.1f}; structure {c.structure_before:.0f} -> {c.structure_after:.0f}")
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
    extra = transient.findings(problem.table, r, z, problem.used, problem.group)  # command timing's signature
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


def _explains(before: tuple[list, int], after: tuple[list, int]) -> bool:
    """True when the new model removes at least PARTIAL of some significant structure (a
    procedure/signal group against one variable), or when there was none to remove. (Other
    structure may then stand out more: the noise scale shrinks; the LR test has judged the fit.)"""
    b, a = _finding_scores(*before), _finding_scores(*after)
    if not b:
        return True
    return any(a.get(k, 0.0) <= (1 - PARTIAL) * s for k, s in b.items())


def _base_free(robot: Any, obs: Observations, procs: Sequence[str]) -> tuple[Any, list[str], list[str]]:
    """Start robot, identifiable free parameters of the declared model, notes (via fitting.fit)."""
    from omnibench.analysis import fitting

    fit_procs = [p for p in fitting.DEFAULT_PROCEDURES if p in procs]
    notes: list[str] = []
    if not fit_procs:
        return robot, [], ["no sweep/forward/lateral data: the declared model's coefficients are held at the robot file's values"]
    res = fitting.fit(robot, obs, procedures=fit_procs)
    free = [p for p in res.fitted]
    for p in res.free:
        if p not in free:
            notes.append(f"{p} held at its robot-file value: {res.identifiable[p].reason}")
    return res.robot, free, notes


def diagnose(robot: Any, obs: Observations, *, candidates: Sequence[str] | None = None,
             procedures: Sequence[str] | None = None, alpha: float = ALPHA, max_effects: int = 3,
             top_k: int = 4, folds: int = engine.CV_FOLDS, seed: int = 0,
             progress: Callable[[str], None] | None = None) -> Diagnosis:
    """Close the loop on `obs` for the declared `robot`; see the module docstring."""
    say = progress or (lambda s: None)
    procs = [p for p in (procedures or obs.procedures()) if len(obs.table(p))]
    if not procs:
        raise UserError("no observations to diagnose")
    names = list(candidates) if candidates is not None else list(EFFECTS)
    for n in names:
        if n not in EFFECTS:
            raise UserError(f"unknown candidate effect {n!r}; known: {', '.join(EFFECTS)}")
    pool: list[Effect] = [EFFECTS[n] for n in names if n not in robot.effects]
    say("fitting the declared model")
    start, free, notes = _base_free(robot, obs, procs)
    free += [f"{e}.{p}" for e in robot.effects if e in EFFECTS for p in EFFECTS[e].fit]
    problem = engine.Problem(obs, procs)
    if not problem.used.any():
        raise UserError("no usable measurements in these runs")
    base = engine.fit_model(problem, start, free, max_nfev=POLISH_NFEV, passes=3)
    fold = engine.cv_folds(problem, folds, seed)
    base_struct, n_tests = _structure_of(problem, base)
    base_sig = structure.significant(base_struct, n_tests)
    current, cur_struct, cur_ntests = base, base_struct, n_tests
    base_err = engine.error_table(problem, engine.heldout_residuals(problem, base, fold))
    selected: list[Candidate] = []
    rejected: list[Candidate] = []
    ambiguous: list[dict[str, Any]] = []
    exposed: dict[str, structure.Finding] = {}
    def assess(c: Candidate, e: Any, cf: engine.ModelFit) -> bool:
        """Fill a refitted candidate's evidence and judge it (library effects and core parameters alike)."""
        c.lr, c.p = engine.lr_test(current, cf, e.n_params)
        c.aic_drop = c.lr - 2 * e.n_params
        w_common = current.weights(problem)
        ho0 = engine.heldout_residuals(problem, current, fold)
        ho1 = engine.heldout_residuals(problem, cf, fold, w_common)
        c.cv_gain = engine.cv_score(problem, ho0, w_common) - engine.cv_score(problem, ho1, w_common)
        # the per-procedure errors as they will be reported (each model with its own weights)
        e1 = engine.error_table(problem, engine.heldout_residuals(problem, cf, fold))
        # compared with the declared model, so small losses cannot pile up round after round
        c.worse = {p: (base_err[p]["nrmse"], e1[p]["nrmse"]) for p in base_err
                   if p in e1 and e1[p]["nrmse"] > (1 + WORSE) * base_err[p]["nrmse"]}
        st, nt = _structure_of(problem, cf)
        c.structure_before, c.structure_after = _score(cur_struct, cur_ntests), _score(st, nt)
        c.struct = (st, nt)
        return _judge(c, e, alpha / m, (cur_struct, cur_ntests))

    for rnd in range(1, max_effects + 1):
        if not pool and not core_params.candidates(problem, current):
            break
        say(f"round {rnd}: screening {len(pool)} candidate effects")
        scr = engine.screen(problem, current, pool) if pool else None
        m = len(pool) + len(core_params.candidates(problem, current))
        thr = {e.name: _lr_threshold(alpha / m, e.n_params) for e in pool}
        order = sorted(pool, key=lambda e: -scr.approx_lr[e.name] / thr[e.name])
        tried: list[Candidate] = []
        passing: list[Candidate] = []
        best_ratio = max((scr.approx_lr[e.name] / thr[e.name] for e in pool), default=0.0)
        for e in order:
            c = Candidate(e.name, rnd, scr.approx_lr[e.name], q=e.n_params)
            ratio = scr.approx_lr[e.name] / thr[e.name]
            n_fitted = len([t for t in tried if t.fitted])
            # refit the top_k; when all of those fail, keep going down the ranking (up to MAX_FITS)
            fallback = not passing and top_k <= n_fitted < MAX_FITS
            leading = ratio >= RELATIVE_SCREEN * best_ratio
            if (n_fitted < top_k and leading or fallback) and ratio >= SCREEN_FRACTION:
                say(f"round {rnd}: fitting {e.name}")
                try:
                    cf = engine.fit_candidate(problem, current, e, scr.estimate[e.name])
                except (np.linalg.LinAlgError, ValueError) as exc:  # a numerically hopeless start
                    c.reason = f"fit failed ({exc.__class__.__name__})"
                    tried.append(c)
                    continue
                c.fitted, c.fit = True, cf
                c.values = {p: cf.values[p] for p in cf.free if p.startswith(e.name + ".")}
                c.se = {p: cf.se[p] for p in c.values}
                if assess(c, e, cf):
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
        core_pass, core_tried = core_params.round_candidates(problem, current, rnd, assess=assess, make=Candidate,
                                                             say=say)
        passing += core_pass
        tried += core_tried
        if not passing:
            rejected += tried
            break
        passing.sort(key=lambda c: -c.aic_drop)
        best = passing[0]
        for c in passing[1:]:
            diff = best.aic_drop - c.aic_drop
            if diff < AMBIGUOUS:
                ambiguous.append({"chosen": best.name, "alternative": c.name, "aic_difference": float(diff),
                                  "experiment": separating_experiment(_spec(best.name), _spec(c.name))})
                c.reason = f"fits almost as well as {best.name} (AIC difference {diff:.1f}): not separable with these data"
            else:
                c.reason = f"significant, but {best.name} explains the data better (AIC difference {diff:.1f})"
        best.verdict = "selected"
        rejected += [c for c in tried if c is not best]
        selected.append(best)
        exposed_f = _exposing_finding(cur_struct, cur_ntests, best.struct)
        if exposed_f is not None:
            exposed[best.name] = exposed_f
        say(f"round {rnd}: added {best.name}")
        # Polish the accepted model to convergence: a candidate fit stops after a few
        # evaluations, and the next round's likelihood ratios must not be inflated by the
        # convergence the next candidate's refit would merely continue.
        current = engine.fit_model(problem, best.fit.robot, best.fit.free, max_nfev=POLISH_NFEV, passes=3)
        if current.deviance > best.fit.deviance:
            current = best.fit
        else:
            best.fit = current
            best.values = {p: current.values[p] for p in best.values}
            best.se = {p: current.se[p] for p in best.values}
            best.struct = _structure_of(problem, current)
        cur_struct, cur_ntests = best.struct
        pool = [e for e in pool if e.name != best.name]
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
                     problem=problem, base_heldout=base_ho, final_heldout=final_ho, notes=notes, exposed_by=exposed)


def _at_bound(effect: Effect, values: Mapping[str, float]) -> str:
    """'' or words naming a fitted parameter that sits on its bound."""
    specs = {p.name: p for p in effect.term.params}
    for full, v in values.items():
        spec = specs[full.split(".")[-1]]
        lo, hi = spec.lower, spec.upper
        span = (hi - lo) if math.isfinite(hi - lo) else max(abs(v), 1.0)
        for edge in (lo, hi):
            if math.isfinite(edge) and edge != 0.0 and abs(v - edge) <= 1e-3 * span:
                return f"{full.split('.')[-1]} = {v:.4g} {spec.unit}, bound {edge:g}"
    return ""


def _judge(c: Candidate, e: Effect, p_needed: float, before: tuple[list, int]) -> bool:
    """Does a refitted candidate earn its place? Sets c.reason when it does not."""
    if not (c.p < p_needed):
        c.reason = f"not significant: LR = {c.lr:.1f} for {c.q} parameter(s), p = {c.p:.1e} (needs < {p_needed:.1e})"
    elif c.values and all(abs(v) < ZERO_SE * c.se.get(k, 0.0) for k, v in c.values.items()):
        c.reason = (f"its fitted size is indistinguishable from zero ("
                    + ", ".join(f"{k} = {v:.3g} ± {c.se.get(k, float('nan')):.2g}" for k, v in c.values.items())
                    + "): the likelihood gain comes from refitting the other parameters, not from the effect")
    elif _at_bound(e, c.values):
        c.reason = (f"its fit runs to the edge of the physical range ({_at_bound(e, c.values)}): it stands in "
                    "for something else rather than measuring itself")
    elif not (c.cv_gain > 2 * c.q):
        change = f"falls by {c.cv_gain:.1f}" if c.cv_gain >= 0 else f"rises by {-c.cv_gain:.1f}"
        c.reason = f"does not earn its parameters on held-out steps (held-out weighted error {change}, needs to fall by > {2 * c.q})"
    elif c.worse:
        c.reason = "makes the held-out error worse in " + ", ".join(
            f"{p} ({100 * a:.2f} % -> {100 * b:.2f} %)" for p, (a, b) in c.worse.items())
    elif c.struct is None or not _explains(before, c.struct):
        c.reason = (f"explains none of the residual structure (score {c.structure_before:.0f} -> "
                    f"{c.structure_after:.0f}, no structure loses half its strength): it leans on structure "
                    "another mechanism makes")
    else:
        return True
    return False


def _lr_threshold(p: float, q: int) -> float:
    from scipy import stats

    return float(stats.chi2.isf(p, q))


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
