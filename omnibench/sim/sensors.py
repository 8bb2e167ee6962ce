"""Sensor models of the simulated board: encoder quantisation, current and voltage noise.

All noise is seeded (numpy Generator) so a simulated run is reproducible.
"""

from __future__ import annotations

import math

import numpy as np

from omnibench.sim.world import SensorConfig


def _quantise(x: np.ndarray | float, lsb: float) -> np.ndarray | float:
    return np.round(np.asarray(x) / lsb) * lsb if lsb > 0 else x


class Sensors:
    """Turns the model's true state into what the board's sensors read (SI units)."""

    def __init__(self, config: SensorConfig, counts_per_rev: int, rng: np.random.Generator) -> None:
        self.config = config
        self.counts_per_rev = int(counts_per_rev)
        self.rng = rng
        # Where each code wheel's first edge sits relative to the wheel's zero angle (rad):
        # random per wheel per boot, as on a real robot, so quantisation errors are random
        # across wheels and boots rather than identical on symmetric wheels.
        self.encoder_phase = rng.uniform(0.0, 2 * math.pi / self.counts_per_rev, 4)

    def encoder_counts(self, phi: np.ndarray) -> np.ndarray:
        """Absolute quadrature counts for wheel angles `phi` (rad): floor, like a counter."""
        return np.floor((np.asarray(phi) + self.encoder_phase) * self.counts_per_rev / (2 * math.pi)).astype(np.int64)

    def motor_current(self, i: np.ndarray) -> np.ndarray | float:
        """Measured motor currents, A (zeros if the board has no such sensor)."""
        c = self.config
        if not c.motor_current_sensor:
            return np.zeros(4)
        return _quantise(np.asarray(i) + self.rng.normal(0.0, c.current_noise, 4), c.current_lsb)

    def battery_voltage(self, v: float) -> float:
        """Measured battery voltage, V."""
        c = self.config
        return float(_quantise(v + self.rng.normal(0.0, c.voltage_noise), c.voltage_lsb))

    def battery_current(self, i: float) -> float:
        """Board's battery current sensor, A (0 if absent)."""
        c = self.config
        if not c.battery_current_sensor:
            return 0.0
        return float(_quantise(i + self.rng.normal(0.0, c.battery_current_noise), c.battery_current_lsb))
