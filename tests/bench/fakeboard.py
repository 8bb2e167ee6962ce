"""An in-process board on the model's Simulator, for fast runner unit tests (no bytes).

End-to-end tests use the real link over sim:// instead; this one lets a test interrupt the
run at an exact sample.
"""

from __future__ import annotations

import math

import numpy as np

from omnibench.bench.board import Telemetry
from omnibench.model import Scenario, Simulator, default_robot


class FakeBoard:
    is_simulator = True
    has_battery_current = True
    has_motor_current = True

    def __init__(self, robot=None, interrupt_after: int | None = None):
        self.robot = robot or default_robot()
        self.sim = Simulator(self.robot, Scenario())
        self.hello = {"board_id": 1, "boot_id": 7, "counts_per_rev": self.robot.counts_per_rev,
                      "protocol_version": 1}
        self.hz = 100.0
        self.duties = np.zeros(4)
        self.seq = 0
        self.offset = np.zeros(4)
        self.reads = 0
        self.interrupt_after = interrupt_after
        self.stops = 0

    def configure(self, *, telemetry_hz, watchdog_s):
        self.hz = telemetry_hz

    def reset_encoders(self):
        self.offset = self.sim.state.phi.copy()

    def set_duties(self, duties):
        self.duties = np.asarray(duties, dtype=float)
        return float(self.sim.state.t)  # applied now: the next sample is later

    def stop(self):
        self.stops += 1
        self.duties = np.zeros(4)
        return float(self.sim.state.t)

    def keepalive(self):
        pass

    def discard_pending(self):
        return 0

    def read(self, timeout):
        self.reads += 1
        if self.interrupt_after is not None and self.reads == self.interrupt_after:
            raise KeyboardInterrupt
        st = self.sim.advance(self.duties, 1.0 / self.hz)
        self.seq += 1
        enc = tuple(int(math.floor(v)) for v in (st.phi - self.offset) * self.robot.counts_per_rev / (2 * math.pi))
        return Telemetry(t=st.t, seq=self.seq, encoder=enc, motor_current=tuple(st.motor_current),
                         battery_voltage=st.V_batt, battery_current=st.I_batt, faults=0,
                         duty=tuple(self.duties))

    def sim_set_world(self, *, mode=None, payload=None, wheel_mass=None):
        sc = self.sim.scenario
        self.sim.set_scenario(Scenario(mode=mode or sc.mode, payload=sc.payload if payload is None else payload,
                                       wheel_mass=sc.wheel_mass if wheel_mass is None else tuple(wheel_mass)))

    def sim_truth(self):
        return tuple(float(v) for v in self.sim.state.pose)
