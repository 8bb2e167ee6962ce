"""The one least-squares engine of the analysis: what `omnibench fit` (fitting), `omnibench
diagnose` (diagnosis.engine) and the planner's information (design.information) differentiate.

Three pieces, one place each:

- parameter names on a robot: the paper's symbols (`a, b, c, a_r, b_r, c_r, C_r`), motor
  constants (`k_t, k_e, R_a, eta, I_0, I_w`, `V_batt`) and `<effect>.<param>` of a declared
  effect; their value (`param_value`), physical bounds (`param_bounds`), scale (`param_scale`),
  unit (`param_unit`) and a robot with some of them set (`with_params`);
- `Parameters`: the parameter vector x = theta / scale of some free names <-> a robot (the
  others held at that robot's values), with the scaled bounds and the difference steps;
- `Problem`: the measurement vector of a `Predictor` (measured y, standard errors sigma, the
  entries used, their noise groups), its predictions for robots, and forward-difference
  stencils (`stencil`, `differences`) that stop simulating the groups a parameter does not
  move; `WeightedResiduals` on it: the weighted residual (y - f) / sigma of the used entries
  and its Jacobian in scaled parameters, what scipy's least squares calls.

The difference step rule (`fd_steps`): a relative step of each parameter's scale, and exactly one
physics step for a command latency (see SHIFT_TERMS).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from omnibench.analysis.predictor import PHYSICS_DT, Predictor
from omnibench.errors import UserError

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

CORE = ("a", "b", "c", "a_r", "b_r", "c_r", "C_r")
MOTOR = ("k_t", "k_e", "R_a", "eta", "I_0", "I_w")
FITTABLE_FIELDS = CORE + MOTOR + ("V_batt",)  # V_batt: a run's supply where it was not logged (sessions.py)
#: Typical magnitudes (SI) used to scale parameters and finite-difference steps.
TYPICAL = {"a": 0.01, "b": 0.5, "c": 0.01, "a_r": 2.0, "b_r": 1.0, "c_r": 0.01, "C_r": 0.02,
           "k_t": 1.5, "k_e": 1.5, "R_a": 2.0, "eta": 0.6, "I_0": 0.1, "I_w": 0.003, "V_batt": 24.0}
UNITS = {"a": "N m s/rad", "b": "N m", "c": "1/N", "a_r": "N s/m", "b_r": "N", "c_r": "1/N", "C_r": "1",
         "k_t": "N m/A", "k_e": "V s/rad", "R_a": "ohm", "eta": "1", "I_0": "A", "I_w": "kg m^2", "V_batt": "V"}
# Command latencies shift the duty schedule in time. The simulator integrates on a fixed
# physics step, and where a wheel's speed crosses zero inside a step (every reversal) its
# trajectory carries an error that depends on where in the step the crossing falls: the
# prediction jumps each time a crossing moves to the next step (up to ~20 in the deviance
# on a 4 s square wave), and a difference over a few microseconds sees those jumps as
# slopes, so the fit stops on one of them (command_latency 19.55 ms +- 7 us for 20 ms).
# Shifting a latency by exactly one physics step shifts the whole discretised trajectory by
# one step, jumps included: the difference over one step is the smooth sensitivity.
SHIFT_TERMS = ("command_latency", "serial_command_latency", "per_wheel_latency")
FD_STEP = 1e-5  # the fit's forward-difference step, relative to each parameter's scale


# ----------------------------------------------------------------------------- parameter names
def _effect_param(robot: Robot, name: str) -> tuple[str, str, Any]:
    eff, _, p = name.partition(".")
    from omnibench.model.terms import get_term

    if eff not in robot.effects:
        raise UserError(f"free parameter {name}: the robot declares no effect {eff!r} "
                        f"(declared: {', '.join(robot.effects) or 'none'})")
    try:
        term = get_term(eff)
    except KeyError as exc:
        raise UserError(str(exc)) from None
    spec = next((q for q in term.params if q.name == p), None)
    if spec is None:
        raise UserError(f"free parameter {name}: {eff} has no parameter {p!r} ({', '.join(term.param_names)})")
    return eff, p, spec


def param_value(robot: Robot, name: str) -> float:
    """Current value (SI) of a parameter name on `robot`."""
    if "." in name:
        eff, p, spec = _effect_param(robot, name)
        return float(robot.effects[eff].get(p, spec.default))
    if name not in FITTABLE_FIELDS:
        raise UserError(f"cannot fit {name!r}: choose from {', '.join(FITTABLE_FIELDS)} or <effect>.<param>")
    return float(getattr(robot, name))


def param_bounds(robot: Robot, name: str) -> tuple[float, float]:
    """Physical bounds (SI) of a parameter."""
    if "." in name:
        _, _, spec = _effect_param(robot, name)
        return float(spec.lower), float(spec.upper)
    if name in CORE:  # the paper's terms' physical ranges (omnibench/model/friction.py)
        from omnibench.model.terms import all_terms

        spec = {p.name: p for t in all_terms() if t.core for p in t.params}[name]
        return float(spec.lower), float(spec.upper)
    if name == "I_0":
        return 0.0, math.inf
    if name == "eta":
        return 1e-3, 1.0
    return 1e-6, math.inf


def param_scale(robot: Robot, name: str) -> float:
    """Typical magnitude used to scale a parameter (its value, else a documented typical size)."""
    v = abs(param_value(robot, name))
    if "." in name:
        _, _, spec = _effect_param(robot, name)
        span = spec.upper - spec.lower
        # a parameter whose natural value is 0 (an offset) is scaled by its range, not by 0
        return max(v, abs(spec.default), 0.01 * span if math.isfinite(span) else 0.0, 1e-6)
    return max(v, TYPICAL.get(name, 1.0) * 0.1)


def param_unit(robot: Robot, name: str) -> str:
    """SI unit of a parameter ('' when it has none on record)."""
    if "." in name:
        return str(_effect_param(robot, name)[2].unit)
    return UNITS.get(name, "")


def with_params(robot: Robot, values: Mapping[str, float]) -> Robot:
    """A copy of `robot` with parameters set (fields and `<effect>.<param>`)."""
    fields: dict[str, float] = {}
    effects = None
    for name, v in values.items():
        if "." in name:
            eff, p = name.split(".", 1)
            if effects is None:
                effects = {k: dict(x) for k, x in robot.effects.items()}
            effects.setdefault(eff, {})[p] = float(v)
        else:
            fields[name] = float(v)
    if effects is not None:
        fields["effects"] = effects  # type: ignore[assignment]
    return robot.replace(**fields) if fields else robot


def fd_steps(free: Sequence[str], scale: np.ndarray, step: float) -> np.ndarray:
    """Forward-difference step of each free parameter in units of its scale: `step`, and one
    physics step (PHYSICS_DT, s) for a latency (SHIFT_TERMS)."""
    return np.array([PHYSICS_DT / s if p.split(".")[0] in SHIFT_TERMS and s > 0 else step
                     for p, s in zip(free, scale)])


# ----------------------------------------------------------------------------- parameter vector
class Parameters:
    """The scaled parameter vector x = theta / scale of `free` on `robot` (which holds every
    other parameter): x <-> robot, and the physical bounds in x."""

    def __init__(self, robot: Robot, free: Sequence[str], scale: np.ndarray | None = None) -> None:
        self.robot, self.free = robot, list(free)
        self.scale = np.array([param_scale(robot, p) for p in self.free]) if scale is None else scale

    @property
    def lower(self) -> np.ndarray:
        """Lower physical bounds, in units of each scale."""
        return np.array([param_bounds(self.robot, p)[0] for p in self.free]) / self.scale

    @property
    def upper(self) -> np.ndarray:
        """Upper physical bounds, in units of each scale."""
        return np.array([param_bounds(self.robot, p)[1] for p in self.free]) / self.scale

    def x_of(self, robot: Robot) -> np.ndarray:
        """The vector of `robot`'s values of the free parameters (units of each scale)."""
        return np.array([param_value(robot, p) for p in self.free]) / self.scale

    def robot_at(self, x: np.ndarray) -> Robot:
        """`robot` with the free parameters at x (units of each scale)."""
        return with_params(self.robot, {p: float(v) for p, v in zip(self.free, x * self.scale)})

    def steps(self, step: float) -> np.ndarray:
        """Forward-difference steps (units of each scale): `fd_steps` with relative step `step`."""
        return fd_steps(self.free, self.scale, step)


# ----------------------------------------------------------------------------- the problem
class Problem:
    """The measurement vector of a Predictor's entries and its predictions.

    pred: what predicts every entry; used: the entries that enter the fit; sigma: each entry's
    standard error (units of the entry); group: each entry's noise group (procedure/signal).

    substeps_of: a robot whose stable sub-steps every prediction keeps at least (each call's
    parameter sets on one integrator grid: at least the sub-steps of this robot and of the
    call's first robot, as `omnibench fit` simulates); None: the simulator chooses per group.
    blind_after: how many points at which a parameter's difference step left a simulation group
    unchanged make the group blind to it (no longer simulated for it, `stencil`)."""

    def __init__(self, pred: Predictor, used: np.ndarray, sigma: np.ndarray, group: np.ndarray | None = None, *,
                 substeps_of: Robot | None = None, blind_after: int = 2) -> None:
        self.pred = pred
        self.y = pred.measured.astype(float)
        self.used, self.sigma = used, sigma
        if group is None:
            t = pred.table
            group = (t["procedure"].astype(str) + "/" + t["signal"].astype(str)).to_numpy()
        self.group = group
        self.nfev = 0
        self._substeps = (max(1, pred.substeps([substeps_of])) if len(pred) else 1) if substeps_of is not None else None
        self._blind_after = blind_after
        #: simulation groups (Predictor.group_entries) whose predictions a parameter does not move:
        #: parameter name -> group keys (seen unchanged by its difference step at `blind_after`
        #: points, and never changed); a stencil does not simulate them for that parameter
        self.blind: dict[str, set[tuple]] = {}
        self._unchanged: dict[tuple[str, tuple], set[str] | None] = {}  # points seen unchanged; None: moved
        self._group_idx = pred.group_entries()

    def __len__(self) -> int:
        return len(self.y)

    def _sub(self, robots: Sequence[Robot]) -> int | None:
        if self._substeps is None:
            return None
        return max(self._substeps, self.pred.substeps(robots[:1]))

    def predict(self, robots: Sequence[Robot]) -> np.ndarray:
        """Predictions (len(robots), n entries)."""
        self.nfev += len(robots)
        return self.pred.predict(list(robots), substeps=self._sub(robots))

    def predict_steps(self, robots: Sequence[Robot], names: Sequence[str]) -> np.ndarray:
        """Predictions (len(robots), n entries) of a difference stencil: robots[j + 1] is robots[0]
        with parameter names[j] stepped. A group the parameter is known not to move (`blind`)
        is not simulated for it: its predictions are robots[0]'s, bit for bit what the
        simulation would give. Learns `blind` from what it simulates: a group counts as blind
        to a parameter once `blind_after` of its steps (at different points) changed nothing there."""
        skip = {key: {1 + j for j, n in enumerate(names) if key in self.blind.get(n, ())}
                for key in self._group_idx}
        self.nfev += len(robots)
        F = self.pred.predict(list(robots), substeps=self._sub(robots),
                              same_as_first=skip if any(skip.values()) else None)
        point = repr(robots[0])
        for key, idx in self._group_idx.items():
            for j, n in enumerate(names):
                seen = self._unchanged.get((n, key), set())
                if 1 + j in skip[key] or seen is None:
                    continue
                if np.array_equal(F[1 + j, idx], F[0, idx]):
                    seen = seen | {point}
                    self._unchanged[(n, key)] = seen
                    if len(seen) >= self._blind_after:
                        self.blind.setdefault(n, set()).add(key)
                else:
                    self._unchanged[(n, key)] = None  # it moves them somewhere: never blind
        return F

    def stencil(self, params: Parameters, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """Predictions (1 + p, n entries) at x and at x with each free parameter stepped by
        steps[j] (units of its scale), through `predict_steps`."""
        xs = [x]
        for j in range(len(x)):
            xp = x.copy()
            xp[j] += steps[j]
            xs.append(xp)
        return self.predict_steps([params.robot_at(v) for v in xs], params.free)

    @staticmethod
    def differences(F: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """Forward differences (p, n entries) of a stencil's predictions F: d prediction / dx_j,
        unweighted, entry units per unit of each scale."""
        return (F[1:] - F[0]) / steps[:, None]


class WeightedResiduals:
    """The weighted residual r = ((y - f) / sigma)[used] of a Problem over `params` (x in units
    of each scale) and its forward-difference Jacobian dr/dx, as scipy's least squares calls them.
    The last residual's prediction and the last Jacobian are kept for their x.

    sigma: each entry's weighting standard error; setting it forgets the cached residual and
    Jacobian (a reweighted fit)."""

    def __init__(self, problem: Problem, params: Parameters, sigma: np.ndarray, step: float) -> None:
        self.problem, self.params = problem, params
        self._sigma = sigma
        self.steps = params.steps(step)
        self._cache: tuple[np.ndarray, np.ndarray] | None = None
        self._jcache: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def sigma(self) -> np.ndarray:
        """Weighting standard error of every entry (units of the entry)."""
        return self._sigma

    @sigma.setter
    def sigma(self, sigma: np.ndarray) -> None:
        self._sigma = sigma
        self._cache = None
        self._jcache = None

    @property
    def robot(self) -> Robot:
        """The start robot (it holds every parameter that is not free)."""
        return self.params.robot

    @property
    def scale(self) -> np.ndarray:
        """Each free parameter's scale (SI)."""
        return self.params.scale

    @property
    def nfev(self) -> int:
        """Parameter sets predicted so far (the problem's count)."""
        return self.problem.nfev

    def robot_at(self, x: np.ndarray) -> Robot:
        """The start robot with the free parameters at x (units of each scale)."""
        return self.params.robot_at(x)

    def predict(self, x_list: Sequence[np.ndarray]) -> np.ndarray:
        """Predictions (len(x_list), n entries)."""
        return self.problem.predict([self.params.robot_at(x) for x in x_list])

    def prediction_at(self, x: np.ndarray) -> np.ndarray:
        """The prediction at x: the last residual's or Jacobian's when it was at x, else predicted."""
        if self._cache is not None and np.array_equal(self._cache[0], x):
            return self._cache[1]
        return self.predict([x])[0]

    def residual(self, x: np.ndarray) -> np.ndarray:
        """The weighted residual at x (keeps its prediction)."""
        f = self.predict([x])[0]
        self._cache = (x.copy(), f)
        return self.weighted(f)

    def weighted(self, f: np.ndarray) -> np.ndarray:
        """(y - f) / sigma of the used entries."""
        return ((self.problem.y - f) / self._sigma)[self.problem.used]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """d(weighted residual)/dx (n_used, n_free), forward differences in one batch (cached per x)."""
        if self._jcache is not None and np.array_equal(self._jcache[0], x):
            return self._jcache[1]
        F = self.problem.stencil(self.params, x, self.steps)
        self._cache = (x.copy(), F[0])
        used = self.problem.used
        J = -Problem.differences(F, self.steps).T[used] / self._sigma[used][:, None]
        self._jcache = (x.copy(), J)
        return J

    def extra_columns(self, x: np.ndarray, names: Sequence[str], step: float = FD_STEP) -> np.ndarray:
        """Jacobian columns of parameters held fixed (per unit of their scale, relative step
        `step`), at x."""
        base = self.params.robot_at(x)
        robot = self.params.robot
        robots = [base] + [with_params(base, {n: param_value(robot, n) + step * param_scale(robot, n)})
                           for n in names]
        F = self.problem.predict(robots)
        cols = [(F[1 + k] - F[0]) / step for k in range(len(names))]
        used = self.problem.used
        return -np.stack(cols, axis=1)[used] / self._sigma[used][:, None]


def weighted_residuals(robot: Robot, pred: Predictor, free: Sequence[str], used: np.ndarray, sigma: np.ndarray, *,
                       scale: np.ndarray | None = None, step: float = FD_STEP) -> WeightedResiduals:
    """The fit's weighted residuals of `free` (start and fixed values from `robot`, scales from it
    unless given) over `pred`'s `used` entries: each call's parameter sets simulated on at least
    `robot`'s sub-steps, and a group a parameter's first difference step left unchanged not
    simulated for it again (`omnibench fit`, the planner's information)."""
    problem = Problem(pred, used, sigma, substeps_of=robot, blind_after=1)
    return WeightedResiduals(problem, Parameters(robot, free, scale), sigma, step)
