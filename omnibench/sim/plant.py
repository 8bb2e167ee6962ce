"""The physics behind the simulated board: omnibench.model's Simulator, stepped on demand.

Keeps a single-threaded numba kernel call per advance: the model's kernel is compiled
with `parallel=True` for batches, and waking a thread pool for one trajectory costs
milliseconds per call, far more than the physics of a 5 ms telemetry period.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numba
import numpy as np

from omnibench.model import Scenario, Simulator
from omnibench.model.scenario import operator_change


@contextmanager
def _one_thread() -> Iterator[None]:
    """numba.set_num_threads(1) for the calling thread while the plant integrates, then back to
    what it was: the setting is thread-local, and the thread that drives an in-process board
    (`sim://`) goes on to analyse the runs (a campaign's fit and diagnose ran on one core)."""
    previous = numba.get_num_threads()
    if previous == 1:
        yield
        return
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(previous)


#: With the motors off and every wheel slower than REST_TOL rad/s, spans longer than REST_SKIP_S
#: are skipped rather than integrated (the robot stays where it is).
REST_TOL = 1e-4
REST_SKIP_S = 1.0


class Plant:
    """The simulated robot in its world. Time is the board's time in s.

    `advance_to(t, duties)` integrates with the duties held; `state` is the model's state
    at the last time reached; `set_world` applies an operator action (robot at rest).
    """

    def __init__(self, robot, scenario: Scenario, dt: float = 1e-3) -> None:
        self.robot = robot
        with _one_thread():
            self.sim = Simulator(robot, scenario, dt=dt)
        self.t0 = 0.0  # board time at which the simulator's t was 0
        self.state = self.sim.state

    @property
    def scenario(self) -> Scenario:
        """The current world (mode, payload, wheel masses, hidden effects)."""
        return self.sim.scenario

    def advance_to(self, t: float, duties: np.ndarray) -> None:
        """Integrate up to board time `t` (s) holding `duties` (4, in [-1, 1])."""
        dur = t - self.t0 - self.sim.t
        if dur > REST_SKIP_S and not np.any(duties) and self.at_rest(REST_TOL):
            # motors off and every wheel stopped (Coulomb friction holds it): a fixed point of the
            # model, so a long quiet spell (a person at a prompt for minutes) costs no integration
            self.t0 += dur
            return
        if dur >= 0.5 * self.sim.dt:
            with _one_thread():  # see the module docstring
                self.state = self.sim.advance(duties, dur)

    def set_world(self, mode: str | None = None, payload: float | None = None,
                  wheel_mass: tuple[float, float, float, float] | None = None) -> None:
        """Operator action: flip the robot, add payload, swap wheels (ends at rest)."""
        self.sim.set_scenario(operator_change(self.sim.scenario, mode, payload, wheel_mass))
        self.state = self.sim.state

    def at_rest(self, tol: float = 1e-3) -> bool:
        """True if every wheel turns slower than `tol` rad/s."""
        return bool(np.all(np.abs(self.state.phi_dot) < tol))
