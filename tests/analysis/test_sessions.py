"""A gain that differs between measurement days: a run's own supply re-estimated against the
sweep's (analysis/sessions.py)."""

from __future__ import annotations

import pytest

from omnibench.analysis.diagnosis.campaign import SquareWave, simulated_campaign
from omnibench.analysis.observations import Observations
from omnibench.analysis.sessions import fit_with_run_supplies


def test_a_session_at_a_lower_supply_gets_its_own_voltage(robot):
    sweep = simulated_campaign(robot, seed=2, procedures=("sweep",), current=False)
    day2 = simulated_campaign(robot.replace(V_batt=22.5), seed=3, procedures=(),
                              step_response=SquareWave(duties=(0.6, -0.6), half_period=0.5, duration=1.0))
    obs = Observations.concat([sweep, day2])
    sf = fit_with_run_supplies(robot.replace(a=0.02), obs, ["a", "b"], ["sweep", "step_response"])
    run = next(r for r in obs.run_ids if "step_response" in r)
    v, se = sf.supplies[run]
    assert sf.reference != run and v == pytest.approx(22.5, abs=max(3 * se, 0.05))
    assert sf.fit.values["a"] == pytest.approx(robot.a, rel=0.2)
