"""The candidate library as diagnosis sees it: for each effect, what to fit and how big it is.

Each `Effect` names a registered Term and adds what diagnosis needs beyond the physics:
which parameters are fitted (`fit`), the values the others are held at (`fixed`), a
realistic size (`example`, used by tests, benchmarks and as a sanity scale), the start of the
fit (`start`), which procedure and which residual variable show it (`reveals`, `variable`),
and which experiment separates it from look-alikes (`separates`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from omnibench.effects import driver
from omnibench.model.terms import Term, get_term


@dataclass(frozen=True)
class Effect:
    """One candidate for diagnosis (SI values)."""

    name: str
    fit: tuple[str, ...]
    example: Mapping[str, float]
    start: Mapping[str, float]
    fixed: Mapping[str, float] = field(default_factory=dict)
    procedures: tuple[str, ...] = ()
    variable: str = "speed"
    separates: Mapping[str, str] = field(default_factory=dict)
    #: forms the effect takes in real hardware: form name -> held parameter values; diagnosis
    #: fits each and reports which the data chose and by how much (the first is the default)
    forms: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    #: simpler candidates this one contains as a special case (serial_command_latency with
    #: tau_packet = 0 is command_latency): diagnosis prefers them unless the extra parameters
    #: are significant given them (a likelihood-ratio test, not an AIC drop of 2 per parameter).
    #: The two together are no more than this one (the library's nested effects are delays, and
    #: delays add): diagnosis does not fit them as a pair
    nests: tuple[str, ...] = ()
    #: other start values of a parameter whose likelihood has several minima (the Stribeck speed
    #: against the sweep's discrete speeds; its static friction, whose valley with the speed has
    #: a second minimum below the realistic size: on one benchmark world b_s 0.19 +- 0.0006 at
    #: deviance 259 from the screen's estimate, 0.33 +- 0.055 at 249 from 0.25): the candidate is
    #: also fitted from each combination, and the lowest deviance kept
    restarts: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    #: start values in closed form from the sweep, where the physics gives one (a plugin point
    #: diagnosis reads): called with the sweep's observation table, the held values of the
    #: form being fitted and the current model's Robot, it returns {parameter: value} (the
    #: effect's own and the core ones it trades against) or None; diagnosis screens the
    #: candidate there too and starts its fit there where that fits the data better than the
    #: screen's estimate (the shifted deadband: `driver.deadband_sweep_start`)
    sweep_start: Callable[[Any, Mapping[str, float], Any], Mapping[str, float] | None] | None = None

    def with_form(self, form: str) -> "Effect":
        """This effect with `form`'s parameters held (unchanged for '' or an effect without forms)."""
        if not form:
            return self
        return replace(self, fixed={**self.fixed, **self.forms[form]})

    @property
    def term(self) -> Term:
        return get_term(self.name)

    @property
    def size_params(self) -> tuple[str, ...]:
        """The fitted parameters that say how big the effect is (zero: absent), not its shape."""
        specs = {p.name: p for p in self.term.params}
        return tuple(p for p in self.fit if specs[p].lower <= 0.0)

    @property
    def n_params(self) -> int:
        """Parameters the candidate costs in a nested-model test."""
        return len(self.fit)

    def params(self, values: Mapping[str, float] | None = None) -> dict[str, float]:
        """Full parameter set of the term: defaults, then `fixed`, then `values` (or `start`)."""
        out = dict(self.term.defaults())
        out.update(self.fixed)
        out.update(self.start if values is None else values)
        return {k: float(v) for k, v in out.items()}

    def world(self, scale: float = 1.0) -> dict[str, dict[str, float]]:
        """A Scenario.effects entry carrying this effect at `scale` times its realistic size."""
        vals = {k: v * scale for k, v in self.example.items()}
        return {self.name: self.params(vals)}


_E = Effect
EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        _E("stribeck_friction", fit=("b_s", "w_s"), example={"b_s": 0.25, "w_s": 1.0}, start={"b_s": 0.05, "w_s": 1.0},
           fixed={"c_s": 0.01, "shape": 2.0}, restarts={"w_s": (0.4, 2.5), "b_s": (0.25,)}, procedures=("upside_down_sweep", "step_response"),
           forms={"Gaussian decay": {"shape": 2.0}, "exponential decay": {"shape": 1.0}},
           variable="speed",
           separates={"driver_deadband": "repeat the sweep with a heavier wheel set: Stribeck friction "
                      "grows with the axle load, a deadband does not; or log the motor current: a "
                      "deadband leaves the current-speed relation unchanged"}),
        _E("driver_deadband", fit=("u_0",), example={"u_0": 0.03}, start={"u_0": 0.01},
           fixed={"w_u": 0.002, "cut": 0.0}, procedures=("upside_down_sweep", "step_response"), variable="duty",
           forms={"shifted": {"cut": 0.0}, "cut": {"cut": 1.0}}, sweep_start=driver.deadband_sweep_start,
           separates={"stribeck_friction": "repeat the sweep with a heavier wheel set (deadband is "
                      "load independent) or log the motor current (deadband does not change it)"}),
        _E("asymmetric_coulomb", fit=("db",), example={"db": 0.06}, start={"db": 0.0}, fixed={"c_db": 0.01},
           procedures=("upside_down_sweep", "forward_runs"), variable="direction",
           separates={"per_wheel_friction": "run the sweep in both directions",
                      "floor_slope": "run the sweep upside down (a slope cannot act there, gearbox "
                      "asymmetry does) or repeat the forward runs with a payload (the slope force grows "
                      "with the mass) or turned round on the floor"}),
        _E("per_wheel_friction", fit=("db_2", "db_3", "db_4", "da_2", "da_3", "da_4"),
           example={"db_1": 0.0, "db_2": 0.08, "db_3": -0.06, "db_4": 0.05,
                    "da_1": 0.0, "da_2": 0.003, "da_3": -0.002, "da_4": 0.0},
           start={p: 0.0 for p in ("db_2", "db_3", "db_4", "da_2", "da_3", "da_4")},
           procedures=("upside_down_sweep",), variable="wheel",
           separates={"asymmetric_coulomb": "run the sweep in both directions",
                      "com_offset": "run the sweep upside down (no load distribution there)"}),
        _E("quadratic_drag", fit=("d_q",), example={"d_q": 1.5e-3}, start={"d_q": 1e-4},
           procedures=("upside_down_sweep",), variable="speed"),
        _E("cogging_torque", fit=("A_c",), example={"A_c": 0.3}, start={"A_c": 0.05},
           fixed={"n_c": 10.0, "phase": 0.0}, procedures=("step_response",),
           variable="speed"),
        _E("com_offset", fit=("dx", "dy"), example={"dx": 0.0, "dy": 0.04}, start={"dx": 0.0, "dy": 0.0},
           procedures=("forward_runs", "lateral_runs"), variable="heading"),
        _E("floor_slope", fit=("theta_s",), example={"theta_s": 0.0175}, start={"theta_s": 0.0},
           fixed={"psi_s": 0.0}, procedures=("forward_runs",), variable="direction"),
        _E("battery_resistance", fit=("R_b",), example={"R_b": 0.3}, start={"R_b": 0.02},
           procedures=("upside_down_sweep", "step_response", "energy_trajectories"), variable="current"),
        _E("quiescent_current", fit=("I_q",), example={"I_q": 0.3}, start={"I_q": 0.02},
           procedures=("energy_trajectories",), variable="time"),
        _E("winding_heating", fit=("theta",), example={"theta": 25.0}, start={"theta": 5.0},
           fixed={"tau_th": 20.0, "alpha_cu": 0.00393}, procedures=("step_response",),
           forms={f"tau_th {t:g} s": {"tau_th": t} for t in (20.0, 5.0, 10.0, 40.0, 80.0)},
           variable="time"),
    )
}


def effect_names() -> list[str]:
    """Names of every candidate in the library."""
    return list(EFFECTS)
