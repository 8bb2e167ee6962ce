"""The Omnibot physics model: robot description, geometry, terms, simulator.

Knows nothing of serial ports, run files or fitting.
"""

from omnibench.model.robot import Robot, default_robot, load_robot
from omnibench.model.scenario import Scenario
from omnibench.model.simulator import Simulator, simulate, simulate_batch

__all__ = [
    "Robot",
    "Scenario",
    "Simulator",
    "default_robot",
    "load_robot",
    "simulate",
    "simulate_batch",
]
