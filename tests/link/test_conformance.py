"""One board conformance class, run unchanged on `sim://` and on `omnibench sim serve` (a pty).

Every test talks through the public Board client only; `target.status()` reads the
simulated board's own state (registry in-process, status file for the server) so a test
can check what the motors really do.
"""

from __future__ import annotations

import time
import uuid

import pytest

from omnibench.errors import BoardError, UserError
from omnibench.link.board import Board
from omnibench.sim import registry
from tests.simserver import spawn_server

WATCHDOG_RESOLUTION_S = 0.0005  #: how often a board checks its watchdog (the firmware: its 500 µs tick)


class SimTarget:
    """The in-process simulator behind `sim://`."""

    kind = "sim"

    def __init__(self) -> None:
        self.name = f"conf-{uuid.uuid4().hex[:8]}"
        self.url = f"sim://omnibot?seed=11&name={self.name}"

    def status(self) -> dict:
        return registry.get(self.name).status()


class PtyTarget:
    """`omnibench sim serve` in another process, on a pseudo-terminal."""

    kind = "pty"

    def __init__(self, served) -> None:
        self.served = served
        self.url = served.path

    def status(self) -> dict:
        """The server's status as written after this call (Served.status)."""
        return self.served.status()


def _server(tmp_path_factory, clock: str):
    served = spawn_server(tmp_path_factory.mktemp("pty"), "--seed", "11", "--clock", clock)
    yield served
    served.stop()
    assert served.status()["motors_stopped"] is True and served.status()["serving"] is False


@pytest.fixture(scope="module")
def pty_fast(tmp_path_factory):
    yield from _server(tmp_path_factory, "fast")


@pytest.fixture(scope="module")
def pty_realtime(tmp_path_factory):
    yield from _server(tmp_path_factory, "realtime")


@pytest.fixture(params=["sim", "pty-fast", "pty-realtime"])
def target(request):
    """sim:// in this process; `omnibench sim serve` with its fast and its real-time clock."""
    if request.param == "sim":
        return SimTarget()
    return PtyTarget(request.getfixturevalue(request.param.replace("-", "_")))


class TestBoardConformance:
    """What every board (simulated in-process, served on a pty, real) must do."""

    def test_hello_identity(self, target) -> None:
        with Board.open(target.url) as b:
            h = b.hello
            assert h.protocol_version == 2 and b.version_ok
            assert h.counts_per_rev == 980
            assert h.boot_id != 0 and h.is_simulator
            assert "BATTERY_CURRENT" in h.capabilities

    def test_telemetry_at_configured_rate_on_board_clock(self, target) -> None:
        with Board.open(target.url) as b:
            b.configure(telemetry_hz=100)
            s = b.wait(0.5)
            assert len(s) >= 50
            dts = [b2.t - b1.t for b1, b2 in zip(s, s[1:])]
            assert all(abs(dt - 0.01) < 2e-6 for dt in dts)
            assert b.stats.lost == 0 and b.stats.crc_errors == 0

    def test_duties_applied_echoed_and_stopped(self, target) -> None:
        with Board.open(target.url) as b:
            b.clear_faults()
            b.sim_set_world(mode="upside_down")
            b.configure(telemetry_hz=200)
            b.reset_encoders()
            u = [0.4, -0.4, 0.2, -0.2]
            b.set_duties(u)
            s = b.wait(0.3)[-1]
            # once the board has had the time to apply them (the firmware's motor drivers take
            # their packets at 9600 baud: on a fast clock that time passes only while the host reads)
            assert not target.status()["motors_stopped"]
            assert all(abs(a - e) < 1e-4 for a, e in zip(s.duty, u))
            assert s.encoder[0] > 0 and s.encoder[1] < 0 and s.encoder[2] > 0 and s.encoder[3] < 0
            assert s.motor_current[0] > 0 and s.motor_current[1] < 0
            b.stop()
            after = b.wait(0.05)[-1]
            assert after.duty == (0.0, 0.0, 0.0, 0.0)
            assert target.status()["motors_stopped"]
            b.sim_set_world(mode="ground")

    def test_reset_encoders(self, target) -> None:
        with Board.open(target.url) as b:
            b.clear_faults()
            b.sim_set_world(mode="upside_down")
            b.configure(telemetry_hz=100)
            b.set_duties([0.5] * 4)
            b.wait(0.2)
            b.stop()
            b.wait(0.5)  # coast to rest
            b.reset_encoders()
            s = b.wait(0.1)[-1]
            assert all(abs(c) <= 1 for c in s.encoder)
            b.sim_set_world(mode="ground")

    def test_silent_host_watchdog_stops_motors(self, target) -> None:
        with Board.open(target.url, heartbeat=False) as b:
            b.clear_faults()
            b.configure(telemetry_hz=200, watchdog_s=0.1)
            retries = b.stats.retries
            b.set_duties([0.3] * 4)
            t_cmd = b.board_time
            s = b.wait(0.3)
            stopped = [x for x in s if x.t > t_cmd and x.duty == (0.0, 0.0, 0.0, 0.0)]
            assert stopped, "motors still running after the watchdog timeout"
            silences = [arg for _, code, arg in b.stats.events if code == "WATCHDOG"]
            assert silences and 100 <= silences[-1] <= 101  # the timeout, to the board's 0.5 ms tick
            # within the timeout, the board's check interval and one telemetry period of the
            # command; a resend (sent once the ACK is 30 ms + a period of board time late)
            # restarts the timeout, and is allowed for
            late = (b.stats.retries - retries) * (0.03 + 0.005 + 0.002)
            assert stopped[0].t <= t_cmd + 0.1 + WATCHDOG_RESOLUTION_S + 0.005 + late + 1e-6
            assert b.stats.time_faults == 0  # board time never ran backwards (a sample sent after a later ACK or EVENT)
            assert "WATCHDOG" in b.fault_names(stopped[0].faults)
            assert target.status()["motors_stopped"]
            with pytest.raises(BoardError, match="WATCHDOG"):
                b.set_duties([0.3] * 4)
            b.clear_faults()
            b.set_duties([0.1] * 4)
            b.stop()

    def test_heartbeat_keeps_motors_running(self, target) -> None:
        with Board.open(target.url) as b:
            b.clear_faults()
            b.configure(telemetry_hz=100, watchdog_s=0.3)
            b.set_duties([0.2] * 4)
            t_cmd = b.board_time
            s = [x for x in b.wait(0.9) if x.t > t_cmd]  # three watchdog timeouts
            assert s and all(x.duty[0] > 0.19 and x.faults == 0 for x in s)

    def test_simulated_operator_and_tape_measure(self, target) -> None:
        with Board.open(target.url) as b:
            b.clear_faults()
            b.sim_set_world(mode="ground", payload=1.0)
            b.configure(telemetry_hz=100)
            p0 = b.sim_truth()
            assert p0.mode == "ground"
            b.set_duties([0.4] * 4)
            b.wait(0.5)
            with pytest.raises(BoardError, match="stop the motors"):
                b.sim_set_world(mode="upside_down")
            b.stop()
            p1 = b.sim_truth()
            assert p1.x - p0.x > 0.05 and abs(p1.y - p0.y) < 0.01
            b.sim_set_world(payload=0.0)

    def test_commands_round_trip(self, target) -> None:
        with Board.open(target.url) as b:
            rtts = [b.ping() for _ in range(3)]
            assert all(r > 0 for r in rtts)
            # a clean link loses and corrupts nothing (a resend after 0.1 s of a loaded host is
            # not a link error, so retries are not asserted)
            assert b.stats.lost == 0 and b.stats.crc_errors == 0 and b.stats.time_faults == 0

    def test_bad_duties_refused_before_sending(self, target) -> None:
        with Board.open(target.url) as b:
            sent = b.stats.bytes_out
            with pytest.raises(UserError, match=r"\[-1, 1\]"):
                b.set_duties([1.5, 0, 0, 0])
            with pytest.raises(UserError):
                b.set_duties([0.1, 0.1, 0.1])
            assert b.stats.bytes_out == sent

    def test_exception_in_block_stops_motors(self, target) -> None:
        with pytest.raises(RuntimeError):
            with Board.open(target.url) as b:
                b.clear_faults()
                b.set_duties([0.3] * 4)
                assert not _once_stopped(target, until_stopped=False)["motors_stopped"]
                raise RuntimeError("procedure failed")
        st = _once_stopped(target)
        assert st["motors_stopped"] and st["last_command"] == "STOP" and st["faults"] == []


def _once_stopped(target, wall_s: float = 5.0, until_stopped: bool = True) -> dict:
    """The target's status once its motors have stopped (`until_stopped=False`: started), or
    after `wall_s` s of wall time: the firmware acknowledges STOP and SET_DUTIES before their
    packets have crossed the 9600-baud driver line (up to 21.7 ms of board time,
    benchmarks/firmware.py), as on the robot; a busy host may read the status in between."""
    deadline = time.monotonic() + wall_s
    st = target.status()
    while st["motors_stopped"] != until_stopped and time.monotonic() < deadline:
        time.sleep(0.05)
        st = target.status()
    return st


def test_reopening_drops_the_previous_sessions_telemetry(pty_fast) -> None:
    """A session that left telemetry running does not leak samples into the next one."""
    b1 = Board.open(pty_fast.path)
    b1.configure(telemetry_hz=500)
    b1.wait(0.1)
    b1.close()  # no stop, telemetry still streaming into the pty
    with Board.open(pty_fast.path) as b2:
        assert b2.read_samples() == []
        assert b2.hello.boot_id == b1.hello.boot_id  # same board, no reset
