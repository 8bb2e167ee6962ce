"""The campaign's answer: the model it ends with (the diagnosed one when diagnosis added an
effect, else the declared fit), each coefficient with its standard error and 95 % interval, the
declared fit beside it as "before", and the energy error of both.

Built from the analysis stages' JSON (fit, validate-energy, diagnose); the terminal summary and
report.md both read it, so they say the same thing. Values are rounded to their standard error
(two significant digits of the SE), in one format everywhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

Z95 = 1.959964  #: the 95 % interval is value ± Z95·SE (normal approximation)

#: units as a lab engineer reads them ("1" is what the robot file says for a ratio)
_UNIT_WORDS = {"1": "dimensionless", "": ""}


def unit_words(unit: Any) -> str:
    """A parameter's unit for people: "1" (a ratio, e.g. C_r) becomes "dimensionless"."""
    u = "" if unit is None else str(unit)
    return _UNIT_WORDS.get(u, u)


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _exponent(v: float) -> int:
    return math.floor(math.log10(abs(v))) if v else 0


def with_se(value: Any, se: Any) -> str:
    """`value ± se`, the value rounded to the SE's second significant digit, e.g.
    3.4662, 0.0391 -> "3.466 ± 0.039"; very small or large magnitudes share one power of ten:
    3.774e-5, 3.44e-7 -> "(3.774 ± 0.034)e-05". Without a finite SE: the value to 4 digits."""
    if not _finite(value):
        return "–"
    if not _finite(se) or se <= 0:
        return f"{value:.4g}"
    scale = max(_exponent(value), _exponent(se))
    if scale < -3 or scale >= 5:  # one shared power of ten
        m = 10.0 ** scale
        digits = max(scale - (_exponent(se) - 1), 0)
        return f"({value / m:.{digits}f} ± {se / m:.{digits}f})e{scale:+03d}"
    digits = max(1 - _exponent(se), 0)  # the SE's second significant digit
    return f"{value:.{digits}f} ± {se:.{digits}f}"


def rounded_like(value: Any, se: Any) -> str:
    """`value` alone, rounded as with_se rounds it (for an interval's ends)."""
    if not _finite(value):
        return "–"
    if not _finite(se) or se <= 0:
        return f"{value:.4g}"
    scale = max(_exponent(value), _exponent(se))
    if scale < -3 or scale >= 5:
        m = 10.0 ** scale
        digits = max(scale - (_exponent(se) - 1), 0)
        return f"{value / m:.{digits}f}e{scale:+03d}"
    return f"{value:.{max(1 - _exponent(se), 0)}f}"


@dataclass
class Coefficient:
    """One coefficient of the campaign's final model."""

    name: str
    value: float | None
    se: float | None
    unit: str
    verdict: str = ""
    before: tuple[float | None, float | None] | None = None  #: the declared fit's (value, SE)
    added: bool = False  #: a parameter of an effect diagnosis added
    interval: tuple[float, float] | None = None  #: the fit's own 95 % interval, when it gave one

    def ci95(self) -> tuple[float, float] | None:
        """The 95 % interval: the fit's own (t quantile) when known, else value ± Z95·SE."""
        if self.value is None or not _finite(self.se):
            return None
        if self.interval is not None:
            return self.interval
        return self.value - Z95 * self.se, self.value + Z95 * self.se  # type: ignore[operator]

    def cells(self) -> dict[str, str]:
        """The coefficient as text: value ± SE, interval, unit, before."""
        ci = self.ci95()
        return {"value": with_se(self.value, self.se),
                "ci95": f"[{rounded_like(ci[0], self.se)}, {rounded_like(ci[1], self.se)}]" if ci else "–",
                "unit": unit_words(self.unit),
                "before": ("(not in the declared model)" if self.added else
                           with_se(*self.before) if self.before is not None else "–")}


@dataclass
class Answer:
    """What the campaign identified, how well, what diagnosis added, the energy error."""

    model: str  #: "diagnosed" or "declared" (or "none": the fit did not run)
    coefficients: list[Coefficient] = field(default_factory=list)
    added: list[dict[str, Any]] = field(default_factory=list)  #: diagnose's selected effects
    energy_before: float | None = None  #: mean |error| %, the declared fit
    energy_after: float | None = None  #: mean |error| %, the diagnosed model
    heldout: dict[str, tuple[float | None, float | None]] = field(default_factory=dict)  #: NRMSE before/after
    fit_error: dict[str, float] = field(default_factory=dict)  #: the declared fit's NRMSE by procedure
    unexplained: list[dict[str, Any]] = field(default_factory=list)
    model_file: str | None = None
    #: the declared fit's measurement groups whose misfit makes verdicts 'model inadequate'
    #: (FitResult.inadequate: group, chi2_dof, dof, determines, text), worst first
    inadequate: list[dict[str, Any]] = field(default_factory=list)
    diagnose: str = "not run"  #: the diagnose stage's status (ok, failed, skipped, not run)
    diagnose_why: str = ""  #: why it was skipped or failed


def campaign_answer(stages: dict[str, Any]) -> Answer:
    """The Answer from the analysis stages' records (see omnibench.campaign.stages.run_analysis)."""
    fit = ((stages.get("fit") or {}).get("result") or {}) if isinstance(stages.get("fit"), dict) else {}
    diag_stage = stages.get("diagnose") or {}
    diag = diag_stage.get("result") or {} if diag_stage.get("status") == "ok" else {}
    params: dict[str, Any] = fit.get("parameters") or {}
    ve = (stages.get("validate-energy") or {}).get("result") or {}
    ve_after = ((diag_stage.get("validate_energy") or {}).get("result") or {})
    selected = list(diag.get("selected") or [])
    ext = diag.get("extended_fit") or {}
    ans = Answer(model="diagnosed" if selected and ext else ("declared" if params else "none"),
                 added=selected, unexplained=list(diag.get("unexplained") or []),
                 energy_before=ve.get("mean_abs_error_pct"), energy_after=ve_after.get("mean_abs_error_pct"),
                 fit_error=dict(fit.get("error_by_procedure") or {}),
                 inadequate=list(fit.get("inadequate") or []),
                 diagnose=str(diag_stage.get("status") or "not run"),
                 diagnose_why=str(diag_stage.get("why") or (str(diag_stage.get("stderr") or "").strip().splitlines()
                                                             or [""])[-1]))
    for proc, b in (diag.get("before") or {}).items():
        a = (diag.get("after") or {}).get(proc) or {}
        ans.heldout[proc] = ((b or {}).get("nrmse"), a.get("nrmse"))
    if ans.model == "diagnosed":
        ans.model_file = (diag.get("written") or {}).get("model")
        units = {k: (v or {}).get("unit", "") for k, v in params.items()}
        for sel in selected:
            for k, v in (sel.get("parameters") or {}).items():
                units.setdefault(k, (v or {}).get("unit", ""))
        added_params = {k for sel in selected for k in (sel.get("parameters") or {})}
        for name, v in ext.items():
            p = params.get(name) or {}
            before = (p.get("value"), p.get("se") if p.get("identifiable", True) else None) if p else None
            ans.coefficients.append(Coefficient(name, (v or {}).get("value"), (v or {}).get("se"),
                                                units.get(name, ""), "", before,
                                                added=name in added_params or not p,
                                                interval=_interval((v or {}).get("ci95"))))
        for name, p in params.items():  # fitted before, not refitted by diagnosis: kept as fitted
            if name not in ext:
                ans.coefficients.append(_declared(name, p, verdict_note=" (not refitted by diagnosis)"))
    else:
        ans.model_file = (stages.get("fit") or {}).get("model")
        ans.coefficients = [_declared(name, p) for name, p in params.items()]
    return ans


def inadequacy(ans: Answer) -> list[str]:
    """What is wrong when the declared model does not fit the runs (empty when it does): a
    headline, one line per misfit group (by how much, which coefficients it determines), and
    what diagnose found or did not find: the headline first, then the items. Plain text: the
    terminal summary and the report's first screen both say it."""
    if not ans.inadequate:
        return []
    names = list(dict.fromkeys(p for g in ans.inadequate for p in (g.get("determines") or {})))
    listed = ", ".join(names)
    if ans.model == "diagnosed":
        lines = ["The declared model is INADEQUATE for these runs: "
                 + (f"its fit of {listed} is verdict 'model inadequate' (a misfit group determines each):" if names
                    else "groups misfit, though none determines a coefficient of its fit:")]
    else:
        lines = ["MODEL INADEQUATE for these runs: the declared model misses something, "
                 + (f"so {listed} {'is' if len(names) == 1 else 'are'} not identified (verdict 'model inadequate': "
                    "a misfit group determines each; the values are this model's reading of the runs):" if names
                    else "though no misfit group determines a coefficient:")]
    lines += [str(g.get("text") or g.get("group")) for g in ans.inadequate]
    if ans.model == "diagnosed":
        added = ", ".join(str(s.get("effect")) for s in ans.added)
        lines.append(f"diagnose found {added} and added it: the model below is the diagnosed one "
                     "(the declared fit's verdicts: Analysis, fit)")
    elif ans.diagnose == "ok":
        if ans.unexplained:
            lines.append("diagnose found no candidate effect that explains it; the structure it left unexplained: "
                         + "; ".join(str(u.get("location") or f"{u.get('group')} against {u.get('variable')}")
                                     for u in ans.unexplained[:3]))
        else:
            lines.append("diagnose found no candidate effect that explains it, and no structure it could place")
    elif ans.diagnose == "failed":
        lines.append(f"diagnose failed ({ans.diagnose_why or 'see Analysis'}): nothing is known of the missing effect")
    else:
        lines.append(f"diagnose did not run ({ans.diagnose_why or ans.diagnose}); `omnibench diagnose --model "
                     f"{ans.model_file or 'MODEL'} RUNS` looks for the missing effect")
    return lines


def _declared(name: str, p: dict[str, Any], verdict_note: str = "") -> Coefficient:
    se = p.get("se") if p.get("identifiable", True) else None
    return Coefficient(name, p.get("value"), se, p.get("unit", ""), f"{p.get('verdict', '')}{verdict_note}".strip(),
                       (p.get("value"), se), interval=_interval(p.get("ci95")))


def _interval(ci: Any) -> tuple[float, float] | None:
    """A fit's [low, high] 95 % interval when both ends are finite numbers, else None."""
    if isinstance(ci, (list, tuple)) and len(ci) == 2 and all(_finite(x) for x in ci):
        return float(ci[0]), float(ci[1])
    return None
