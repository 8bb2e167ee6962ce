"""One process per board: a second one is refused at open, with the holder named (issue 12)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from omnibench.errors import BoardError
from omnibench.link.board import Board
from tests.simserver import spawn_server


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    s = spawn_server(tmp_path_factory.mktemp("lock"), "--seed", "8")
    yield s
    s.stop()


def test_second_process_is_refused_and_the_first_run_goes_on(served) -> None:
    with Board.open(served.path) as first:
        first.configure(telemetry_hz=100, watchdog_s=10.0)
        first.set_duties([0.3] * 4)
        res = subprocess.run([sys.executable, "-m", "omnibench", "board", "info", "--port", served.path],
                             capture_output=True, text=True, timeout=120)
        assert res.returncode != 0
        err = res.stderr.strip().splitlines()
        assert len(err) == 1 and f"in use by process {os.getpid()}" in err[0], res.stderr
        # the second process sent nothing: the board still runs the first one's command
        st = served.status()
        assert st["last_command"] == "SET_DUTIES" and not st["faults"] and st["telemetry_hz"] == 100
        first.read_samples()
        first.set_duties([0.1] * 4)
        s = first.wait(0.3)
        assert len(s) >= 5 and s[-1].duty == pytest.approx((0.1,) * 4, abs=1e-4)
        first.stop()
    with Board.open(served.path) as again:  # released on close
        assert again.hello is not None


def test_second_open_in_the_same_process_is_refused_too(served) -> None:
    with Board.open(served.path):
        with pytest.raises(BoardError, match="in use by process"):
            Board.open(served.path, timeout=0.5)
