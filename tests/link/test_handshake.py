"""The handshake against a board that reboots as the port opens (Arduino DTR reset into the
stock stk500v2 bootloader), modelled in wall time with shortened timings; the real bootloader
in simavr is tests/firmware/test_boot.py."""

from __future__ import annotations

import os
import socket
import threading
import time

import pytest

from omnibench.errors import BoardError
from omnibench.link import board as board_mod
from omnibench.link.board import Board
from omnibench.sim.board import SimBoard
from omnibench.sim.world import World

WAIT_S = 0.25      # the bootloader's wait for a first byte (0.83 s on the Mega)
SILENCE_S = 0.6    # ... and for silence once it got one (5.0 s on the Mega)


def _resetting_board(stop: threading.Event, log: dict) -> int:
    """A TCP port whose board resets when the connection opens (as ser2net opening a Mega's
    port does): the stk500v2 hand-over rule, then a simulated board in real time."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]
    firmware = SimBoard(World(seed=3))  # built ahead (the first one takes a while): its clock
                                        # starts, and its boot HELLO goes out, at the hand-over

    def run() -> None:
        srv.settimeout(10)
        conn, _ = srv.accept()
        conn.settimeout(0.002)
        t0 = time.monotonic()
        last_rx: float | None = None
        board: SimBoard | None = None
        with conn, srv:
            while not stop.is_set():
                now = time.monotonic()
                if board is None and ((last_rx is None and now - t0 > WAIT_S)
                                      or (last_rx is not None and now - last_rx > SILENCE_S)):
                    board = firmware
                    log["handover"] = now - t0
                    t_boot = now
                if board is not None:
                    board.advance_to(int((now - t_boot) * 1e6))
                    out = board.take_output()
                    if out:
                        conn.sendall(out)
                try:
                    data = conn.recv(4096)
                except (TimeoutError, BlockingIOError):
                    continue
                if not data:
                    return
                if board is None:
                    log["to_bootloader"] = log.get("to_bootloader", 0) + len(data)
                    last_rx = time.monotonic()             # a programming session: wait for silence
                else:
                    board.feed(data)

    threading.Thread(target=run, daemon=True).start()
    return port


@pytest.fixture
def short_bootloader(monkeypatch):
    monkeypatch.setattr(board_mod, "BOOT_QUIET_S", SILENCE_S + 0.15)
    monkeypatch.setattr(board_mod, "QUIET_RESERVE_S", 0.3)


def test_a_board_that_resets_as_the_port_opens_gets_its_silence_and_answers(short_bootloader) -> None:
    """One HELLO_REQ goes into the bootloader; the host then stays silent until the firmware
    runs, which its boot HELLO shows: the bootloader received nothing but that one request."""
    stop, log = threading.Event(), {}
    port = _resetting_board(stop, log)
    try:
        t0 = time.monotonic()
        with Board.open(f"socket://127.0.0.1:{port}", timeout=3.0) as b:
            took = time.monotonic() - t0
            assert b.hello.counts_per_rev == 980
    finally:
        stop.set()
    request = len(b.codec.frame("HELLO_REQ", 0))
    assert log["to_bootloader"] == request, log            # one request, then silence
    assert SILENCE_S <= log["handover"] < SILENCE_S + 0.3, log
    assert took < log["handover"] + 0.4                    # the boot HELLO ended the silence


def test_the_old_retrying_handshake_keeps_that_board_in_its_bootloader(short_bootloader, monkeypatch) -> None:
    """Control: re-sending every ACK_TIMEOUT_S (never silent) never lets the firmware start."""
    monkeypatch.setattr(board_mod, "BOOT_QUIET_S", 0.0)
    stop, log = threading.Event(), {}
    port = _resetting_board(stop, log)
    try:
        with pytest.raises(BoardError, match="no HELLO"):
            Board.open(f"socket://127.0.0.1:{port}", timeout=2.0)
    finally:
        stop.set()
    assert "handover" not in log and log["to_bootloader"] > 10 * 9


def test_a_board_that_answers_opens_at_once() -> None:
    """The fast path: the simulator answers the first request, no silence is waited."""
    t0 = time.monotonic()
    for seed in range(5):
        with Board.open(f"sim://?seed={seed}") as b:
            assert b.version_ok
    assert time.monotonic() - t0 < 2.5  # one silent wait would be 5.5 s


def test_no_answer_with_a_short_timeout_names_the_bootloader() -> None:
    """A port where nothing answers (a pty nobody serves): one line, naming the bootloader's
    5 s and the default timeout that covers it."""
    master, slave = os.openpty()
    try:
        with pytest.raises(BoardError, match="no HELLO") as exc:
            Board.open(os.ttyname(slave), timeout=0.4)
    finally:
        os.close(master)
        os.close(slave)
    msg = str(exc.value)
    assert "\n" not in msg and "bootloader" in msg and f"{board_mod.HANDSHAKE_TIMEOUT_S:g} s" in msg
