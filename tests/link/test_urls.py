"""Any pyserial URL: socket:// to a board bridged over TCP, and clear errors for the rest."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from omnibench.errors import BoardError
from omnibench.link.board import Board
from omnibench.sim.board import SimBoard
from omnibench.sim.world import World


def _tcp_board(stop: threading.Event) -> int:
    """A simulated board behind a TCP socket (real time), like a serial-to-network bridge."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]

    def run() -> None:
        board = SimBoard(World(seed=8))
        srv.settimeout(10)
        conn, _ = srv.accept()
        conn.settimeout(0.002)
        t0 = time.monotonic()
        with conn, srv:
            while not stop.is_set():
                board.advance_to(int((time.monotonic() - t0) * 1e6))
                out = board.take_output()
                if out:
                    conn.sendall(out)
                try:
                    data = conn.recv(4096)
                except (TimeoutError, BlockingIOError):
                    continue
                if not data:
                    return
                board.feed(data)

    threading.Thread(target=run, daemon=True).start()
    return port


def test_board_over_socket_url() -> None:
    stop = threading.Event()
    port = _tcp_board(stop)
    try:
        with Board.open(f"socket://127.0.0.1:{port}") as b:
            assert b.hello.counts_per_rev == 980
            b.configure(telemetry_hz=100)
            s = b.wait(0.2)
            assert len(s) >= 20 and b.stats.lost == 0
    finally:
        stop.set()


@pytest.mark.parametrize("url, match", [
    ("loop://", "no HELLO"),                       # a port with no board on it
    ("hwgrep://no-such-device-anywhere", "cannot open"),
    ("/dev/does-not-exist", "cannot open"),
])
def test_unusable_urls_give_one_line_errors(url: str, match: str) -> None:
    with pytest.raises(BoardError, match=match) as exc:
        Board.open(url, timeout=0.3)
    assert "\n" not in str(exc.value)
