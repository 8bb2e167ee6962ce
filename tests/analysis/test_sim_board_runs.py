"""End to end through the simulated board: procedures on sim:// write run directories, the fit
reads them back (Observations.from_runs) and recovers the coefficients the board's robot carries."""

from __future__ import annotations

import pytest

from omnibench.analysis.fitting import fit
from omnibench.analysis.observations import Observations
from omnibench.cli import main


@pytest.fixture(scope="module")
def board_runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("simruns")
    for proc in ("sweep", "forward"):
        with pytest.raises(SystemExit) as exc:
            main([proc, "--port", "sim://", "--out", str(out), "--json"])
            raise SystemExit(0)
        assert exc.value.code == 0
    return out


def test_sweep_run_of_the_board_gives_back_its_robot(board_runs, robot):
    obs = Observations.from_runs([board_runs], robot)
    assert len(obs.sweep) == 4 * 32 and obs.has_current
    assert (obs.sweep["omega_se"] > 0).all() and (obs.sweep["current_se"] > 0).all()
    assert set(obs.sweep["wheel_mass"].round(3)) == {0.9, 1.9}
    start = robot.replace(a=0.02, b=0.3, c=0.02, k_e=1.5, R_a=2.0)
    res = fit(start, obs, procedures=["sweep"])
    for p in ("a", "b", "c", "k_e", "R_a"):
        assert res.identifiable[p].status == "identified"
        assert abs(res.values[p] - getattr(robot, p)) < 3.5 * res.se[p], (p, res.values[p], res.se[p])
    assert 0.5 < res.s2 < 2.0


def test_forward_runs_of_the_board_give_back_rolling_resistance(board_runs, robot):
    obs = Observations.from_runs([board_runs], robot)
    assert len(obs.forward) == 12
    assert obs.runs[obs.forward["run"].iloc[0]]["duty_timing"] == "interval_before"
    res = fit(robot.replace(C_r=0.05), obs, ["C_r"], procedures=["forward"])
    assert abs(res.values["C_r"] - robot.C_r) < 3 * res.se["C_r"]
    assert res.se["C_r"] < 0.05 * robot.C_r
