"""`omnibench sim serve`: signals stop the motors; an interrupted client stops them too; fast clock."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

import pytest

from omnibench.link.board import Board
from tests.simserver import sigint_as_in_a_terminal, spawn_server


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """One realtime server for the tests that leave it with the motors stopped."""
    s = spawn_server(tmp_path_factory.mktemp("serve"), "--seed", "4", "--ammeter", lines=2)
    yield s
    s.stop()


def test_sigint_to_server_stops_motors_and_says_so(tmp_path) -> None:
    served = spawn_server(tmp_path, "--seed", "3")
    try:
        b = Board.open(served.path, heartbeat=True)
        b.set_duties([0.3] * 4)
        time.sleep(0.2)
        assert served.status()["motors_stopped"] is False
        assert served.stop(signal.SIGINT) == 0
        st = served.status()
        assert st["serving"] is False and st["motors_stopped"] is True and st["duties"] == [0.0] * 4
        b.close()
    finally:
        served.stop()


def test_interrupted_client_leaves_motors_stopped(served) -> None:
    """Ctrl-C in a procedure: the `with Board.open(...)` exit path sends STOP."""
    client = textwrap.dedent(f"""
        import sys, time
        from omnibench.link.board import Board
        with Board.open({served.path!r}) as b:
            b.configure(telemetry_hz=50)
            b.set_duties([0.3, 0.3, 0.3, 0.3])
            print("driving", flush=True)
            for s in b.samples(60.0):
                pass
    """)
    proc = subprocess.Popen([sys.executable, "-c", client], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=sigint_as_in_a_terminal)
    try:
        assert proc.stdout.readline().strip() == "driving"
        time.sleep(0.3)
        assert served.status()["motors_stopped"] is False
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
        time.sleep(0.1)
        st = served.status()
        assert st["motors_stopped"] is True and st["last_command"] == "STOP"
        assert st["faults"] == []  # stopped by the client, not by the watchdog
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stdout.close()
        proc.stderr.close()


def test_fast_clock_on_pty_loses_nothing(tmp_path) -> None:
    served = spawn_server(tmp_path, "--clock", "fast", "--seed", "5")
    try:
        with Board.open(served.path) as b:
            b.configure(telemetry_hz=200)
            s = b.wait(2.0)
            assert len(s) >= 400 and b.stats.lost == 0
            assert all(abs(y.t - x.t - 0.005) < 2e-6 for x, y in zip(s, s[1:]))
    finally:
        served.stop()


def test_caller_silent_for_a_watchdog_timeout_lets_the_board_stop_the_motors(served) -> None:
    """No thread feeds the watchdog: a caller that stops calling the client is a hung host."""
    with Board.open(served.path) as b:
        # 1 s, not less: on a loaded CI machine reading a fresh status file took longer than a 0.3 s
        # watchdog, which had (rightly) fired before the "still driving" check could see the motors run.
        b.configure(watchdog_s=1.0)
        b.set_duties([0.2] * 4)
        time.sleep(0.1)
        assert served.status()["motors_stopped"] is False
        time.sleep(2.0)  # two watchdog timeouts without a client call
        st = served.status()
        assert st["motors_stopped"] is True and st["faults"] == ["WATCHDOG"]
        b.clear_faults()


def test_ammeter_served_on_its_own_pty(served) -> None:
    from omnibench.link.ammeter import open_ammeter

    assert len(served.lines) == 2
    with Board.open(served.path) as b, open_ammeter(served.lines[1]) as meter:
        assert meter.idn.startswith("OMNIBENCH,SIM-AMMETER")
        b.clear_faults()
        b.configure(telemetry_hz=100)
        b.attach_ammeter(meter, period_s=0.05)
        b.set_duties([0.5] * 4)
        s = [x for x in b.wait(0.5) if x.ammeter_current == x.ammeter_current]
        b.stop()
    assert len(s) >= 5 and max(x.ammeter_current for x in s) > 0.5


def test_wrong_baud_on_pty_is_reported(tmp_path) -> None:
    """The server reads the speed the host set on the pty; another speed garbles the link.

    A server of its own, so the board's power-on output is still in play: its boot HELLO,
    encoded before any host's speed was known, reached a 9600 baud open intact under load (this
    stop's CI) until output not yet sent was garbled at the new speed too (next test)."""
    from omnibench.errors import BoardError

    served = spawn_server(tmp_path, "--seed", "4")
    try:
        with pytest.raises(BoardError, match=r"baud rate \(board expects 115200, opened at 9600\)"):
            Board.open(served.path, baudrate=9600, timeout=0.5)
        with Board.open(served.path) as b:  # and at the right speed it works again
            assert b.hello.counts_per_rev == 980
    finally:
        served.stop()


def test_the_fast_clock_counts_bytes_still_on_their_way_to_the_host_as_unread() -> None:
    # The fast clock emits the next frame only when the host has read everything (`_Pty.unread`).
    # A write to the pty master reaches the slave's read queue later, from a kernel worker: on a
    # busy machine FIONREAD alone read 0 for frames still in flight, the board ran ahead of a host
    # that was feeding its watchdog, and the watchdog fired (tests/bench/test_person.py failed under
    # load, 2 runs of 3). Right after every write the frame must count as unread.
    import os
    import select as _select

    from omnibench.sim.pty_server import _Pty

    p = _Pty()
    try:
        frame = b"\x7e" + bytes(range(41))
        missed = 0
        for _ in range(20000):
            os.write(p.master, frame)
            missed += p.unread() != len(frame)
            while _select.select([p.slave], [], [], 0)[0]:
                os.read(p.slave, 4096)
        assert missed == 0
    finally:
        p.close()


def test_a_host_at_another_speed_does_not_read_the_boot_hello_intact() -> None:
    """The board's power-on HELLO is encoded before any host speed is known; if it has not gone
    out when the host's speed turns out wrong, it goes out garbled like everything after it.
    (CI: a 9600 baud open read it intact, took it for the handshake and lost the board at STOP.)"""
    from omnibench.link.framing import Deframer
    from omnibench.sim.board import SimBoard
    from omnibench.sim.world import World

    def frames(board: SimBoard) -> list[bytes]:
        return Deframer(board.codec.crc, board.spec.max_frame_bytes).feed(board.take_output())

    right = SimBoard(World(seed=4))
    right.set_host_baud(115200)
    assert len(frames(right)) == 2  # HELLO and the BOOT event
    wrong = SimBoard(World(seed=4))
    wrong.set_host_baud(9600)
    assert frames(wrong) == []
