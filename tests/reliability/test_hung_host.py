"""A hung host stops the motors by the board's watchdog within its timeout (+ one telemetry
period): nothing but the runner's own loop feeds it (issue 12)."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

import omnibench.bench.runner as runner_mod
from omnibench.bench.session import run_command
from omnibench.errors import BoardError
from tests.simserver import spawn_server

PROC = Path(__file__).parent / "procedures"
WATCHDOG_S, RATE_HZ = 0.5, 240.0


def hang_mid_hold(port: str, out: Path, monkeypatch, released: threading.Event) -> tuple[float, Path]:
    """Run the hung sweep; its runner hangs at the first steady-state check until `released`.
    Returns (board time of the last sample the runner read, the run directory)."""
    real = runner_mod.steady_state
    last: list[float] = []

    def hanging(t, phi, **kw):
        if not last:
            last.append(float(t[-1]))
            released.wait(30)  # the host "hangs" here: no reads, no keepalives
        return real(t, phi, **kw)

    monkeypatch.setattr(runner_mod, "steady_state", hanging)
    with pytest.raises(BoardError, match="WATCHDOG"):
        run_command("upside_down_sweep", port=port, procedure_file=PROC / "hung_sweep.toml", robot_file=None,
                    out=out, echo=lambda line: None, progress=False)
    (run_dir,) = out.iterdir()
    return last[0], run_dir


@pytest.mark.slow
def test_hung_runner_is_stopped_by_the_watchdog_within_its_timeout(tmp_path, monkeypatch) -> None:
    srv = spawn_server(tmp_path, "--clock", "realtime", "--seed", "7")
    released = threading.Event()
    try:
        def release_when_stopped():
            for _ in range(300):
                st = srv.status()
                if st["faults"]:
                    break
                threading.Event().wait(0.02)
            released.set()

        watcher = threading.Thread(target=release_when_stopped, daemon=True)
        watcher.start()
        t_last, run_dir = hang_mid_hold(srv.path, tmp_path / "runs", monkeypatch, released)
        watcher.join(10)
        st = srv.status()
        assert st["motors_stopped"] and st["faults"] == ["WATCHDOG"]
        meta = json.loads((run_dir / "run.json").read_text())
        wd = [e for e in meta["link"]["events"] if e[1] == "WATCHDOG"]
        assert len(wd) == 1
        # the board stopped the motors after the runner's last sample, its host silence (from the
        # runner's last frame, sent before it hung) within the timeout + one telemetry period
        assert wd[0][0] > t_last and wd[0][2] <= 1000 * (WATCHDOG_S + 1.0 / RATE_HZ)
        # (benchmarks/reliability.py measures the same on the host clock: hang -> stop)
        assert meta["status"] == "failed"
    finally:
        released.set()
        srv.stop()
