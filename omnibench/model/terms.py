"""Model terms: each friction, load or electrical mechanism is a named, documented Term.

A Term owns parameters (name, unit, default) and numba hook functions. The kernel
(`omnibench.model.kernel`) is generated from the registry of all terms, so adding a new
effect is: write its hooks, `register(Term(...))` in a module that a plugin entry point names
(see PLUGIN_GROUP below). Nothing in the integrator or the fit changes.

The registry is a plugin registry, as python-can's interfaces: the model's own terms
(`model/friction.py`) are registered first; then every module named by an entry point of
the group `omnibench.terms` is imported, and registers its terms as it is imported. omnibench's
own effects register this way (`pyproject.toml`:
`[project.entry-points."omnibench.terms"] effects = "omnibench.effects"`), so the model never
imports them; another installed package may add terms the same way. The entry points are
installation metadata: after changing them, install again (`pip install -e .`).

Hook signatures (all arrays float64; `p` is the term's own parameter slice, `xs` its own
states, `ctx` the read-only context of `omnibench.model.context`):

- normal_force(FN[4], ctx, p)             adjust normal forces in place, N
- duty(u[4], ctx, p)                      map commanded duty to effective duty in place
- electrical(elec, xs, ctx, p)            adjust the electrical slots (ELEC_*) in place
- wheel_torque(out[4], phi[4], phi_dot[4], FN[4], i[4], xs, ctx, p)
                                          write the torque the term applies on each wheel axle, N m
- roller_force(out[4], sigma[4], FN[4], ctx, p)
                                          write the force along each contact roller's axis, N
- body_force(out[3], q[3], v[3], ctx, p)  write a generalised force in the body frame (N, N, N m)
- state_derivative(dxs, xs, i[4], phi_dot[4], elec, ctx, p)
                                          time derivative of the term's own states

`out` arrays arrive zeroed; the kernel adds them up and books each term's power so the
energy balance names every term.

Hooks are written for one trajectory; the kernel runs them on lane groups of trajectories
after `omnibench.model.lanes` rewrites them from their source. So a hook indexes its arrays
one element at a time (no slices, no `.shape`, no passing an array on) and returns nothing.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.metadata import entry_points

HOOKS = (
    "normal_force",
    "duty",
    "electrical",
    "wheel_torque",
    "roller_force",
    "body_force",
    "state_derivative",
)

#: The model's own terms (the paper's friction and electrical model), registered first.
CORE_MODULES = ("omnibench.model.friction",)
#: Entry-point group of the term plugins: each entry names a module that registers terms on import.
PLUGIN_GROUP = "omnibench.terms"


@dataclass(frozen=True)
class Param:
    """One parameter of a term: its symbol, SI unit, default and meaning."""

    name: str
    unit: str
    default: float
    doc: str
    lower: float = float("-inf")
    upper: float = float("inf")


@dataclass(frozen=True)
class Term:
    """A physical mechanism the model sums. `core` terms are the paper's own (always declared)."""

    name: str
    title: str
    doc: str
    params: tuple[Param, ...]
    hooks: dict[str, Callable] = field(default_factory=dict)
    n_states: int = 0
    state_init: tuple[float, ...] = ()
    core: bool = False
    reveals: str = ""

    def __post_init__(self) -> None:
        unknown = set(self.hooks) - set(HOOKS)
        if unknown:
            raise ValueError(f"term {self.name}: unknown hooks {sorted(unknown)}")
        if len(self.state_init) != self.n_states:
            raise ValueError(f"term {self.name}: state_init must have {self.n_states} values")

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    def defaults(self) -> dict[str, float]:
        return {p.name: p.default for p in self.params}


_REGISTRY: dict[str, Term] = {}


def register(term: Term) -> Term:
    """Add a term to the registry (idempotent for the same name and object)."""
    existing = _REGISTRY.get(term.name)
    if existing is not None and existing is not term:
        raise ValueError(f"a term named {term.name!r} is already registered")
    _REGISTRY[term.name] = term
    return term


@functools.cache
def term_modules() -> tuple[str, ...]:
    """The modules that register terms: the core ones, then the plugins (entry points of
    PLUGIN_GROUP, by name). The kernel is generated from everything they register."""
    plugins = sorted(entry_points(group=PLUGIN_GROUP), key=lambda ep: ep.name)
    if not plugins:
        raise RuntimeError(f"no term plugins are installed (entry points {PLUGIN_GROUP!r}, omnibench's own "
                           "effects among them): install omnibench again (pip install -e .)")
    return CORE_MODULES + tuple(ep.value for ep in plugins)


def all_terms() -> list[Term]:
    """Every registered term, in a stable order (core terms first, then by module order)."""
    for module in term_modules():
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
    return list(_REGISTRY.values())


def get_term(name: str) -> Term:
    """The registered term called `name`, or KeyError naming the known ones."""
    terms = {t.name: t for t in all_terms()}
    if name not in terms:
        raise KeyError(f"unknown term {name!r}; known: {', '.join(sorted(terms))}")
    return terms[name]


@dataclass(frozen=True)
class Layout:
    """Where each term's parameters and states sit in the kernel's flat vectors."""

    terms: tuple[Term, ...]
    param_offset: tuple[int, ...]
    state_offset: tuple[int, ...]
    n_params: int
    n_states: int

    @classmethod
    def build(cls) -> "Layout":
        terms = tuple(all_terms())
        p_off, s_off, p, s = [], [], 0, 0
        for t in terms:
            p_off.append(p)
            s_off.append(s)
            p += len(t.params)
            s += t.n_states
        return cls(terms, tuple(p_off), tuple(s_off), p, s)

    def index(self, name: str) -> int:
        for k, t in enumerate(self.terms):
            if t.name == name:
                return k
        raise KeyError(name)


_LAYOUT: Layout | None = None


def layout() -> Layout:
    """The layout of all registered terms (built once)."""
    global _LAYOUT
    if _LAYOUT is None or len(_LAYOUT.terms) != len(all_terms()):
        _LAYOUT = Layout.build()
    return _LAYOUT
