"""A frame whose board time jumps or runs backwards is a link fault, never passage of time,
and no such frame can extend a hold (issue 12)."""

from __future__ import annotations

import pytest

import omnibench.bench.runner as runner_mod
from omnibench.link.board import Board


def _forge(board: Board, dt_us: int) -> None:
    """Make the simulated board send one TELEMETRY frame with its time moved by `dt_us`."""
    sim = board._port.board
    raw = sim.telemetry_raw()
    raw["time"] = (raw["time"] + dt_us) & 0xFFFFFFFF
    sim.out += sim.encode_tx("TELEMETRY", raw)


@pytest.mark.parametrize("dt_us", [30_000_000, -50_000])
def test_jumped_or_backward_frame_is_dropped_and_counted(dt_us) -> None:
    with Board.open("sim://?seed=2") as b:
        b.configure(telemetry_hz=100)
        b.set_duties([0.45] * 4)
        before = b.wait(0.1)
        _forge(b, dt_us)
        after = b.wait(0.2)
        b.stop()
    ts = [s.t for s in before + after]
    assert b.stats.time_faults == 1
    assert all(0 < y - x < 0.0151 for x, y in zip(ts, ts[1:]))  # 100 Hz, nothing forged got through
    assert b.board_time < ts[-1] + 0.02


def test_hold_limit_is_enforced_on_the_host_clock(tmp_path, monkeypatch) -> None:
    """Board time that stops advancing cannot hold a duty beyond the phase's time + slack."""
    import sys
    import time
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "bench"))
    from fakeboard import FakeBoard

    from omnibench.procedures import load_plan
    from omnibench.runs import RunWriter, read_run

    class Frozen(FakeBoard):
        driving = 0

        def read(self, timeout):
            s = super().read(timeout)
            time.sleep(0.002)
            self.driving = self.driving + 1 if any(self.duties) else 0
            if self.driving > 5:
                return type(s)(**{**s.__dict__, "t": self.t_stuck})  # board time stuck
            self.t_stuck = s.t
            return s

    monkeypatch.setattr(runner_mod, "HOST_SLACK_S", 0.3)
    board = FakeBoard()
    robot = board.robot
    plan = load_plan(Path(__file__).parent / "procedures" / "stall_sweep.toml", robot, expect="upside_down_sweep")
    board = Frozen(robot)
    from omnibench.bench.operator import SimulatedOperator

    w = RunWriter.create(tmp_path, "upside_down_sweep", counts_per_rev=robot.counts_per_rev)
    r = runner_mod.Runner(plan, robot, board, w, SimulatedOperator(board, noise=0.0, seed=1))
    rec = r.run(plan.steps[:1])[0]
    w.finish("complete")
    assert rec["steady"] is False  # ended by the host clock (board time never reached the window)
    ev = read_run(w.path).events
    assert "host_time_limit" in set(ev["kind"])
    assert board.duties.tolist() == [0.0] * 4
