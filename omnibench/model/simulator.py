"""Simulate the Omnibot: one trajectory (`simulate`), many at once (`simulate_batch`), or
step by step for the simulated board (`Simulator`). All share one compiled kernel.

Commands are duties u in [-1, 1] per wheel, held from their time stamp until the next one
(zero-order hold). Physics runs at `dt` (default 1 ms), sub-stepped when friction
regularisation makes the equations stiff (see `stable_substeps`).

Methods: "rk4" (classical Runge-Kutta, the default, 4 derivative evaluations per step) and
"heun" (explicit trapezoid, 2 evaluations: about twice the throughput, for large batches).
On the default robot's 10 s ground run at 1 ms, against RK4 with 20 sub-steps, RK4's final
pose is off by ~1e-6 m and Heun's by ~4e-5 m / 2e-5 rad, Heun's battery energy by ~3e-5
relative (tests/model/test_kernel_numerics.py holds these figures).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba
import numpy as np

from omnibench.model import geometry, kernel
from omnibench.model.context import GRAVITY
from omnibench.model.friction import CORE_PARAMS
from omnibench.model.robot import Robot
from omnibench.model.scenario import Scenario
from omnibench.model.stiffness import decay_rates, ground_split
from omnibench.model.terms import Layout, layout

if TYPE_CHECKING:
    import pandas as pd

# numba's OpenMP threading layer (GNU libgomp here) lets its worker threads spin between parallel
# regions; a fit calls the parallel kernel ~90 times with Python in between, and on a machine with
# other work the spinning workers take CPU from it and from the caller's own thread (issue 34:
# `omnibench fit` on a clean campaign's runs, all cores, load 6-7: CPU 10.1 -> 9.1 s, wall 15.2 ->
# 13.6 s, three runs each). Passive waiting sleeps at once; waking costs microseconds against a
# region's milliseconds of work. Threading only: no number changes. Read when the OpenMP runtime
# loads (the first `simulate_batch` of more than one lane group), so set here, before; a value
# the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "passive")

METHODS = {"heun": kernel.METHOD_HEUN, "rk4": kernel.METHOD_RK4}
DEFAULT_METHOD = "rk4"
# Largest h * lambda allowed per method, with a margin below the real-axis stability limit of
# each explicit scheme (Heun / explicit RK2: 2.0; classical RK4: 2.785). lambda is the largest
# decay rate of the speeds at rest, differentiated from the model with every enabled term
# (`stiffness.decay_rates`).
STABILITY_LIMITS = {"heun": 1.8, "rk4": 2.5}
STABILITY_LIMIT = STABILITY_LIMITS[DEFAULT_METHOD]

_CORE_TERM_OF = {"a": "transmission_friction", "b": "transmission_friction", "c": "transmission_friction",
                 "a_r": "roller_friction", "b_r": "roller_friction", "c_r": "roller_friction",
                 "C_r": "rolling_resistance"}


def term_parameters(robot: Robot, scenario: Scenario | None = None) -> dict[str, dict[str, float]]:
    """Every enabled term with its parameter values: the paper's terms from the robot's fields,
    the robot's declared effects, then the world's undeclared effects (these win)."""
    out: dict[str, dict[str, float]] = {}
    for name in CORE_PARAMS:
        out.setdefault(_CORE_TERM_OF[name], {})[name] = float(getattr(robot, name))
    for source in (robot.effects, (scenario.effects if scenario else {})):
        for name, params in source.items():
            merged = dict(out.get(name, {}))
            merged.update({k: float(v) for k, v in params.items()})
            out[name] = merged
    return out


@dataclass(frozen=True)
class Prepared:
    """Kernel inputs for one trajectory."""

    x0: np.ndarray
    rv: np.ndarray
    P: np.ndarray
    EN: np.ndarray
    Rm: np.ndarray
    Sm: np.ndarray
    Minv: np.ndarray
    M: np.ndarray
    substeps_lambda: float


def normal_forces(robot: Robot, scenario: Scenario) -> np.ndarray:
    """Base normal force on each wheel, N: W/4 on the ground, the wheel's own weight upside down."""
    if scenario.mode == "upside_down":
        masses = scenario.wheel_mass if scenario.wheel_mass is not None else robot.wheel_mass
        return np.asarray(masses, dtype=float) * GRAVITY
    return np.full(4, (robot.m + scenario.payload) * GRAVITY / 4.0)


def prepare(robot: Robot, scenario: Scenario, lay: Layout | None = None) -> Prepared:
    """Flatten (robot, scenario) into the kernel's per-trajectory arrays."""
    lay = lay or layout()
    p = _prepare(robot, scenario, lay)
    lam = decay_rates(p.x0[None], p.rv[None], p.P[None], p.EN[None], p.Rm[None], p.Sm[None], p.Minv[None],
                      p.M[None], lay)[0]
    return dataclasses.replace(p, substeps_lambda=float(lam))


def decay_rates_of(pairs: Sequence[tuple[Robot, Scenario]], lay: Layout | None = None) -> np.ndarray:
    """`prepare(robot, scenario).substeps_lambda` of many pairs, in one kernel call."""
    if not pairs:
        return np.zeros(0)
    lay = lay or layout()
    preps = [_prepare(r, s, lay) for r, s in pairs]
    stack = lambda name: np.ascontiguousarray(np.stack([getattr(p, name) for p in preps]))  # noqa: E731
    X0, RV, P, EN, Rm, Sm, Minv, M = (stack(n) for n in ("x0", "rv", "P", "EN", "Rm", "Sm", "Minv", "M"))
    return decay_rates(X0, RV, P, EN, Rm, Sm, Minv, M, lay)


def _prepare(robot: Robot, scenario: Scenario, lay: Layout) -> Prepared:
    """`prepare` without the stiffness (simulate_batch computes it for all sets at once)."""
    mass = robot.m + scenario.payload
    FN = normal_forces(robot, scenario)
    rv = np.array([
        0.0 if scenario.mode == "ground" else 1.0, mass, robot.I_w, robot.k_t, robot.k_e, robot.R_a,
        robot.eta, robot.V_batt, robot.I_0, robot.L, robot.l, robot.r,
        # upside down the wheels stick and slip with an exact sign (kernel.EXACT_SIGN_WIDTH);
        # the robot's regularisation width is the ground's numerical device
        robot.sign_width_phi if scenario.mode == "ground" else kernel.EXACT_SIGN_WIDTH,
        robot.sign_width_sigma, mass * GRAVITY, FN[0], FN[1], FN[2], FN[3],
        0.0, 0.0, 0.0,  # lam_base, lam_phi, lam_sigma: fixed sub-steps unless simulate_batch(adaptive=True)
    ])  # in the order of kernel.RV_NAMES
    x0_t, P_t, index = _template(lay)
    P = P_t.copy()
    EN = np.zeros(len(lay.terms))
    for name, params in term_parameters(robot, scenario).items():
        k, slots = index[name]
        for pname, v in params.items():
            P[slots[pname]] = v
        EN[k] = 1.0
    Rm, Sm, M, Minv = (a.copy() for a in _mechanics(
        robot.L, robot.l, robot.r, tuple(robot.alpha), mass, robot.I_z, robot.I_w))
    return Prepared(x0_t.copy(), rv, P, EN, Rm, Sm, Minv, M, float("nan"))


_TEMPLATES: dict[int, tuple] = {}


def _template(lay: Layout):
    """Initial state and default parameters of a layout, and where each term's parameters sit."""
    cached = _TEMPLATES.get(id(lay))
    if cached is not None and cached[0] is lay:
        return cached[1]
    P = np.zeros(lay.n_params)
    x0 = np.zeros(kernel.NX_FIXED + len(lay.terms) + lay.n_states)
    index: dict[str, tuple[int, dict[str, int]]] = {}
    for k, term in enumerate(lay.terms):
        o = lay.param_offset[k]
        for j, p in enumerate(term.params):
            P[o + j] = p.default
        s0 = kernel.NX_FIXED + len(lay.terms) + lay.state_offset[k]
        x0[s0 : s0 + term.n_states] = term.state_init
        index[term.name] = (k, {p.name: o + j for j, p in enumerate(term.params)})
    _TEMPLATES[id(lay)] = (lay, (x0, P, index))
    return x0, P, index


@functools.lru_cache(maxsize=64)
def _mechanics(L, l, r, alpha, mass, I_z, I_w):
    """R, S, the body-frame mass matrix and its inverse (shared by parameter sets of one robot)."""
    Rm = geometry.inverse_kinematics(L, l, r, alpha)
    Sm = geometry.slip_matrix(L, l, alpha)
    M = np.diag([mass, mass, I_z]) + I_w * Rm.T @ Rm
    return Rm, Sm, M, np.linalg.inv(M)


def stable_substeps(lam: float, dt: float, method: str = DEFAULT_METHOD) -> int:
    """Sub-steps per physics step so that h * lambda <= STABILITY_LIMITS[method]."""
    if method not in STABILITY_LIMITS:
        raise ValueError(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    return max(1, math.ceil(lam * dt / STABILITY_LIMITS[method]))


def signal_names(lay: Layout | None = None) -> list[str]:
    """Names of the kernel's recorded columns (state, then auxiliary signals)."""
    lay = lay or layout()
    names = ["x", "y", "psi", "v1", "v2", "psi_dot", "phi1", "phi2", "phi3", "phi4",
             "phi_dot1_free", "phi_dot2_free", "phi_dot3_free", "phi_dot4_free",
             "E_batt", "E_copper", "E_conversion", "E_quiescent"]
    names += [f"E_{t.name}" for t in lay.terms]
    for t in lay.terms:
        names += [f"{t.name}.x{k}" for k in range(t.n_states)]
    return names + list(kernel.AUX_NAMES)


def _commands(t_cmd, u_cmd, t0: float, dt: float, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
    t_cmd = np.asarray(t_cmd, dtype=float)
    u = np.asarray(u_cmd, dtype=float)
    if u.ndim == 2:
        u = u[None]
    if t_cmd.ndim != 1 or u.shape[1] != t_cmd.shape[0] or u.shape[2] != 4:
        raise ValueError("commands must be t (K,) and duties (K, 4) or (B, K, 4)")
    if np.any(np.diff(t_cmd) < 0):
        raise ValueError("command times must not decrease")
    t_steps = t0 + np.arange(n_steps) * dt
    idx = np.searchsorted(t_cmd, t_steps + 1e-9 * dt, side="right") - 1
    u_full = np.concatenate([np.zeros((u.shape[0], 1, 4)), u], axis=1)  # before the first command: 0
    return (idx + 1).astype(np.int64), np.ascontiguousarray(u_full)


def command_delays(robot: Robot, scenario: Scenario) -> np.ndarray:
    """Latency of each wheel's command (4,), s: the enabled timing terms (omnibench.model.timing)
    plus the recording firmware's known latency (`Scenario.command_delays`); zero unless the
    robot, its world or its firmware carries one."""
    from omnibench.model.timing import wheel_delays

    d = wheel_delays(term_parameters(robot, scenario), scenario.command_order)
    return d + np.asarray(scenario.command_delays, dtype=float) if scenario.command_delays is not None else d


def command_lags(robot: Robot, scenario: Scenario) -> np.ndarray:
    """Actuator time constant of each wheel (4,), s (omnibench.model.timing): zero unless the
    robot or its world carries an actuator lag."""
    from omnibench.model.timing import wheel_lags

    return wheel_lags(term_parameters(robot, scenario))


def _delayed(robots: Sequence[Robot], scenarios: Sequence[Scenario], t_cmd, u_cmd, dt: float,
             t_end: float = 0.0):
    """The duty schedules as the motors receive them: each wheel shifted by its latency, a
    change inside a physics step averaged over it, then through its actuator lag (on the
    physics grid up to t_end); unchanged, the same arrays, when no trajectory has either."""
    from omnibench.model.timing import delay_schedules, lag_schedules

    pairs: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}  # the same objects: computed once
    for r, s in zip(robots, scenarios):
        if (id(r), id(s)) not in pairs:
            pairs[(id(r), id(s))] = (command_delays(r, s), command_lags(r, s))
    delays = np.stack([pairs[(id(r), id(s))][0] for r, s in zip(robots, scenarios)])
    lags = np.stack([pairs[(id(r), id(s))][1] for r, s in zip(robots, scenarios)])
    if not np.any(delays) and not np.any(lags):
        return t_cmd, u_cmd
    t = np.asarray(t_cmd, dtype=float)
    U = np.asarray(u_cmd, dtype=float).reshape(-1, t.shape[0], 4)
    U = np.broadcast_to(U, (len(robots),) + U.shape[1:])
    if np.any(delays):
        t, U = delay_schedules(t, U, delays, dt)
    if np.any(lags):
        t, U = lag_schedules(t, U, lags, dt, t_end)
    return t, U


@dataclass
class BatchResult:
    """Recorded signals of B trajectories: array (B, n_rec, n_signals), times t (n_rec,)."""

    t: np.ndarray
    array: np.ndarray
    columns: list[str]

    def signal(self, name: str) -> np.ndarray:
        return self.array[:, :, self.columns.index(name)]

    def frame(self, b: int = 0) -> pd.DataFrame:
        return _frame(self.t, self.array[b], self.columns)


def _frame(t: np.ndarray, rec: np.ndarray, columns: list[str]) -> pd.DataFrame:
    # pandas only here (~0.3 s to import): the simulated board and the fits' predictions never
    # build a frame, so `omnibench sim serve` starts without it
    import pandas as pd

    df = pd.DataFrame(rec, columns=columns)
    df.insert(0, "t", t)
    free = df[["phi_dot1_free", "phi_dot2_free", "phi_dot3_free", "phi_dot4_free"]].to_numpy()
    return df.drop(columns=["phi_dot1_free", "phi_dot2_free", "phi_dot3_free", "phi_dot4_free"]).assign(
        **{f"phi_dot{j + 1}": free[:, j] for j in range(4)}
    )


def _prepared(robots: Sequence[Robot], scenarios: Sequence[Scenario], lay: Layout) -> list[Prepared]:
    """`_prepare` of every pair; a pair of the same robot and scenario objects (a parameter set
    over many runs of one world: the fit's batches) is prepared once."""
    done: dict[tuple[int, int], Prepared] = {}
    out = []
    for r, s in zip(robots, scenarios):
        key = (id(r), id(s))
        p = done.get(key)
        if p is None:
            p = done[key] = _prepare(r, s, lay)
        out.append(p)
    return out


def simulate_batch(
    robots: Robot | Sequence[Robot],
    scenarios: Scenario | Sequence[Scenario],
    t_cmd,
    u_cmd,
    t_end: float,
    *,
    dt: float = 1e-3,
    record_every: int = 1,
    method: str = DEFAULT_METHOD,
    substeps: int | None = None,
    adaptive: bool = False,
) -> BatchResult:
    """Simulate B (robot, scenario) pairs over [0, t_end] with duties u_cmd ((K,4) shared or (B,K,4)).

    adaptive: on the ground, each physics step takes the fewest sub-steps (never more than the
    fixed count) that keep the step stable at its speeds (kernel.ADAPT_LIMITS): the same
    trajectory to well within measurement noise (tests/model/test_kernel_numerics.py), at a
    fraction of the cost where the speeds stay clear of zero."""
    robots = [robots] if isinstance(robots, Robot) else list(robots)
    scenarios = [scenarios] if isinstance(scenarios, Scenario) else list(scenarios)
    n_cmd_sets = np.asarray(u_cmd, dtype=float).reshape(-1, np.shape(t_cmd)[0], 4).shape[0]
    B = max(len(robots), len(scenarios), n_cmd_sets)
    if len(robots) == 1:
        robots = robots * B
    if len(scenarios) == 1:
        scenarios = scenarios * B
    if len(robots) != B or len(scenarios) != B:
        raise ValueError("robots and scenarios must have the same length (or length 1)")
    lay = layout()
    mod = kernel.load_kernel(lay)
    preps = _prepared(robots, scenarios, lay)
    n_steps = int(round(t_end / dt))
    t_cmd, u_cmd = _delayed(robots, scenarios, t_cmd, u_cmd, dt, n_steps * dt)
    idx, U = _commands(t_cmd, u_cmd, 0.0, dt, n_steps)
    if U.shape[0] not in (1, B):
        raise ValueError(f"{U.shape[0]} command sets for {B} trajectories")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    # sub-steps per trajectory: a stiff parameter set does not slow the others down, and a
    # trajectory's numbers do not depend on the batch it is in (to rounding)
    stack = lambda name: np.ascontiguousarray(np.stack([getattr(p, name) for p in preps]))  # noqa: E731
    X0, RV, P, EN, Rm, Sm, Minv, M = (stack(n) for n in ("x0", "rv", "P", "EN", "Rm", "Sm", "Minv", "M"))
    lam = None
    if substeps:
        sub = np.array([int(substeps)], dtype=np.int64)
    else:
        lam = decay_rates(X0, RV, P, EN, Rm, Sm, Minv, M, lay)
        sub = np.array([stable_substeps(x, dt, method) for x in lam], dtype=np.int64)
    if adaptive and np.any(RV[:, kernel.RV["mode"]] == 0.0):
        if lam is None:
            lam = decay_rates(X0, RV, P, EN, Rm, Sm, Minv, M, lay)
        RV = ground_split(lam, X0, RV, P, EN, Rm, Sm, Minv, M, lay)
    n_rec = n_steps // record_every + 1
    columns = signal_names(lay)
    REC = np.zeros((B, n_rec, len(columns)))
    # the kernel integrates lane groups of kernel.WIDTH trajectories; hand the groups out in
    # small chunks, so that a thread slowed by other work on the machine does not leave the
    # others idle at the end
    args = (X0, RV, P, EN, Rm, Sm, Minv, M, idx, U, 0.0, dt, sub, METHODS[method], record_every, REC)
    groups = -(-B // kernel.WIDTH)
    if groups < 2:
        mod.run_serial(*args)  # one group: waking the worker threads would cost more than it saves
    else:
        previous = numba.get_parallel_chunksize()
        numba.set_parallel_chunksize(max(1, groups // (16 * numba.get_num_threads())))
        try:
            mod.run(*args)
        finally:
            numba.set_parallel_chunksize(previous)
    t = np.arange(n_rec) * record_every * dt
    return BatchResult(t, REC, columns)


def simulate(
    robot: Robot,
    scenario: Scenario,
    t_cmd,
    u_cmd,
    t_end: float,
    *,
    dt: float = 1e-3,
    record_every: int = 1,
    method: str = DEFAULT_METHOD,
) -> pd.DataFrame:
    """One trajectory as a DataFrame (columns in docs/simulate.md); phi_dot from R v on the ground."""
    res = simulate_batch(robot, scenario, t_cmd, u_cmd, t_end, dt=dt, record_every=record_every, method=method)
    df = res.frame(0)
    if scenario.mode == "ground":
        Rm = geometry.inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha)
        phid = df[["v1", "v2", "psi_dot"]].to_numpy() @ Rm.T
        for j in range(4):
            df[f"phi_dot{j + 1}"] = phid[:, j]
    return df


@dataclass(frozen=True)
class SimState:
    """The simulated robot at one instant (SI units)."""

    t: float
    pose: np.ndarray
    velocity: np.ndarray
    phi: np.ndarray
    phi_dot: np.ndarray
    motor_current: np.ndarray
    V_batt: float
    I_batt: float
    E_batt: float


class Simulator:
    """Step-by-step simulation for the simulated board: hold duties for a duration, read state."""

    def __init__(self, robot: Robot, scenario: Scenario | None = None, *, dt: float = 1e-3,
                 method: str = DEFAULT_METHOD) -> None:
        self.robot = robot
        self.dt = dt
        self.method = method
        self._lay = layout()
        self._mod = kernel.load_kernel(self._lay)
        self._steps = 0
        self._columns = signal_names(self._lay)
        self._X: np.ndarray | None = None
        self.set_scenario(scenario or Scenario())

    @property
    def t(self) -> float:
        """Simulated time since start, s."""
        return self._steps * self.dt

    @property
    def scenario(self) -> Scenario:
        return self._scenario

    def set_scenario(self, scenario: Scenario) -> None:
        """Apply an operator action (flip, swap wheels, payload): the robot ends at rest,
        wheel angles and accumulated energy are kept."""
        self._scenario = scenario
        prep = prepare(self.robot, scenario, self._lay)
        X = prep.x0.copy()
        if self._X is not None:
            X[0:3] = self._X[0:3]
            X[6:10] = self._X[6:10]
            X[kernel.X_E_BATT : kernel.NX_FIXED + len(self._lay.terms)] = self._X[
                kernel.X_E_BATT : kernel.NX_FIXED + len(self._lay.terms)]
            X[kernel.NX_FIXED + len(self._lay.terms):] = self._X[kernel.NX_FIXED + len(self._lay.terms):]
        self._X = X
        self._prep = prep
        self._sub = np.array([stable_substeps(prep.substeps_lambda, self.dt, self.method)], dtype=np.int64)
        self._duties = np.zeros(4)
        self._delays = command_delays(self.robot, scenario)
        self._lags = command_lags(self.robot, scenario)
        self._lag_y = np.zeros(4)  # the lagged duty each motor sees (actuator_lag)
        self._history: list[tuple[float, np.ndarray]] = []  # (time issued, duties): latency queue
        self._last = self._advance_steps(np.zeros(4), 0)

    def _advance_steps(self, duties: np.ndarray, n: int) -> np.ndarray:
        assert self._X is not None, "set_scenario sets the state before any step"
        p = self._prep
        REC = np.zeros((1, 2 if n > 0 else 1, len(self._columns)))
        U = np.asarray(duties, dtype=float).reshape(1, 1, 4)
        if n == 0:
            # evaluate the auxiliary signals at the current state without stepping
            idx = np.zeros(1, dtype=np.int64)
            Xc = self._X.copy()
            self._mod.run_serial(Xc[None], p.rv[None], p.P[None], p.EN[None], p.Rm[None], p.Sm[None],
                          p.Minv[None], p.M[None], idx, U, self.t, self.dt, self._sub, METHODS[self.method], 1, REC)
            return REC[0, 0]
        idx = np.zeros(n, dtype=np.int64)
        XF = self._mod.run_serial(self._X[None], p.rv[None], p.P[None], p.EN[None], p.Rm[None], p.Sm[None],
                           p.Minv[None], p.M[None], idx, U, self.t, self.dt, self._sub,
                           METHODS[self.method], n, REC)
        self._X = XF[0]
        self._steps += n
        return REC[0, 1]

    def advance(self, duties, duration: float) -> SimState:
        """Hold `duties` (4, in [-1, 1]) for `duration` seconds (rounded to whole physics steps)."""
        duties = np.clip(np.asarray(duties, dtype=float), -1.0, 1.0)
        if duties.shape != (4,):
            raise ValueError("duties must be 4 values")
        target = int(round((self.t + duration) / self.dt))
        n = max(0, target - self._steps)
        self._duties = duties
        if np.any(self._delays) or np.any(self._lags):
            self._advance_delayed(duties, target)
        elif n:
            self._last = self._advance_steps(duties, n)
        else:
            self._last = self._advance_steps(duties, 0)
        return self.state

    def _advance_delayed(self, duties: np.ndarray, target: int) -> None:
        """`advance` with command latency: each wheel acts on the duties issued delays[j] s
        earlier. Steps in which a delayed command arrives get the step's average duty (as in
        `simulate_batch`); between arrivals the steps run in one call."""
        from omnibench.model.timing import step_average

        # a call that repeats the last command issues none: its arrivals would change no duty, and
        # each would cut the steps between arrivals to one (a realtime board advancing every
        # millisecond held the same duties and fell behind the wall clock, unacknowledged)
        if not self._history or not np.array_equal(self._history[-1][1], duties):
            self._history.append((self.t, duties))
        dt = self.dt
        t_start = self.t
        while self._steps < target and np.any(self._lags):  # a lag changes the duty every step
            self._last = self._advance_steps(self._lagged(step_average(self._history, self._delays, self.t,
                                                                       self.t + dt)), 1)
        while self._steps < target:
            now = self.t
            arrivals = [t_c + d for t_c, _ in self._history for d in self._delays if t_c + d > now + 1e-9 * dt]
            first = min((math.floor(a / dt + 1e-9) for a in arrivals), default=target)
            if first > self._steps:  # no arrival before step `first`: hold the current duties
                n = min(first, target) - self._steps
                self._last = self._advance_steps(step_average(self._history, self._delays, now, now + dt), n)
            else:  # an arrival inside this step: its average duty
                self._last = self._advance_steps(step_average(self._history, self._delays, now, now + dt), 1)
        if self.t == t_start:  # nothing to integrate: the signals at the current state
            u_now = step_average(self._history, self._delays, self.t, self.t + dt)
            self._last = self._advance_steps(self._lag_y if np.any(self._lags) else u_now, 0)
        # forget commands every wheel has moved past (keep the one each wheel still holds)
        done = [k for k, (t_c, _) in enumerate(self._history) if t_c + self._delays.max() <= self.t - dt]
        if done:
            del self._history[: done[-1]]

    def _lagged(self, ubar: np.ndarray) -> np.ndarray:
        """One physics step of the actuator lag fed the step's average command `ubar`: the
        step's average lagged duty (as `lag_schedules`); advances the lag state."""
        from omnibench.model.timing import lag_coefficients

        a, c = lag_coefficients(self._lags, self.dt)
        avg = ubar + (self._lag_y - ubar) * c
        self._lag_y = a * self._lag_y + (1.0 - a) * ubar
        return avg

    @property
    def state(self) -> SimState:
        row = dict(zip(self._columns, self._last))
        v = np.array([row["v1"], row["v2"], row["psi_dot"]])
        if self._scenario.mode == "ground":
            phid = self._prep.Rm @ v
        else:
            phid = np.array([row[f"phi_dot{j}_free"] for j in range(1, 5)])
        return SimState(
            t=self.t,
            pose=np.array([row["x"], row["y"], row["psi"]]),
            velocity=v,
            phi=np.array([row[f"phi{j}"] for j in range(1, 5)]),
            phi_dot=phid,
            motor_current=np.array([row[f"i{j}"] for j in range(1, 5)]),
            V_batt=row["V_batt"],
            I_batt=row["I_batt"],
            E_batt=row["E_batt"],
        )
