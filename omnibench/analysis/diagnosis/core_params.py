"""Core parameters as diagnosis candidates: a declared coefficient the data say is wrong.

When the residual points at a parameter the model already has (the wheel inertia I_w: every
step response rises too fast), re-estimating it is a candidate like any library effect: it
competes on the same evidence (likelihood ratio, held-out gain, per-procedure held-out error,
explained structure) and is reported as a re-estimate, "I_w re-estimated: 0.00266 → 0.018".
Only parameters the data can move are offered (I_w needs step responses), and not when the
model already fits them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from omnibench.analysis.diagnosis import engine

#: core parameter -> (title, procedures that show it)
CORE_CANDIDATES: dict[str, tuple[str, tuple[str, ...]]] = {
    "I_w": ("Wheel inertia re-estimated (rotor seen through the gearbox)", ("step_response",)),
}


UNITS = {"I_w": "kg m^2"}


@dataclass(frozen=True)
class _Spec:
    name: str
    unit: str
    lower: float
    upper: float


@dataclass(frozen=True)
class _TermView:
    """The bits of a Term diagnosis reads (title, params with bounds)."""

    title: str
    params: tuple[_Spec, ...]

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)


@dataclass(frozen=True)
class CoreParameter:
    """A declared parameter offered for re-estimation; reads like library.Effect where
    diagnosis needs it (name, n_params, term.params, procedures, variable, separates)."""

    name: str
    title: str
    procedures: tuple[str, ...]
    variable: str = "time since duty change"
    separates: Mapping[str, str] = field(default_factory=dict)

    @property
    def n_params(self) -> int:
        return 1

    @property
    def term(self) -> _TermView:
        return _TermView(self.title, (_Spec(self.name, UNITS.get(self.name, ""), 0.0, math.inf),))


def candidates(problem: engine.Problem, current: engine.ModelFit) -> list[CoreParameter]:
    """Core parameters worth re-estimating here: not already fitted, shown by a procedure present."""
    procs = set(problem.procedures)
    return [CoreParameter(n, t, p) for n, (t, p) in CORE_CANDIDATES.items()
            if n not in current.free and procs & set(p)]


def is_core(name: str) -> bool:
    """True for a core-parameter candidate's name (not a library effect)."""
    return name in CORE_CANDIDATES


def get(name: str) -> CoreParameter:
    title, procs = CORE_CANDIDATES[name]
    return CoreParameter(name, title, procs)


def describe(name: str, value: float, se: float, declared: Any) -> str:
    """'I_w re-estimated: 0.00266 → 0.0176 ± 0.0003 kg m^2'."""
    return f"{name} re-estimated: {getattr(declared, name):.4g} → {value:.4g} ± {se:.2g} {UNITS.get(name, '')}"


def round_candidates(problem: engine.Problem, current: engine.ModelFit, rnd: int, *,
                     assess: Callable[[Any, Any, engine.ModelFit], bool],
                     make: Callable[..., Any], say: Callable[[str], None]) -> tuple[list[Any], list[Any]]:
    """(passing, tried) core candidates of one round: each refitted with the current model's
    parameters, then given the library effects' evidence and judgement by `assess(candidate,
    spec, fit)` (diagnosis/core.py)."""
    passing, tried = [], []
    for spec in candidates(problem, current):
        say(f"round {rnd}: re-estimating {spec.name}")
        c = make(spec.name, rnd, float("nan"), q=1)
        try:
            cf = engine.fit_model(problem, current.robot, list(current.free) + [spec.name], max_nfev=15,
                                  scale=current.scale, candidate=True)
        except (np.linalg.LinAlgError, ValueError) as exc:
            c.reason = f"re-estimate failed ({exc.__class__.__name__})"
            tried.append(c)
            continue
        c.fitted, c.fit = True, cf
        c.values = {spec.name: cf.values[spec.name]}
        c.se = {spec.name: cf.se[spec.name]}
        if assess(c, spec, cf):
            passing.append(c)
        tried.append(c)
    return passing, tried
