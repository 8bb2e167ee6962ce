"""A board still running the 2019 logging sketch (text lines at 9600 baud) is named as such."""

from __future__ import annotations

import os
import termios
import threading
import time
import tty

import pytest

from omnibench.errors import BoardError
from omnibench.link.board import Board
from omnibench.link.sniff import looks_like_text_log


class FakeSketch:
    """A pty that behaves like the 2019 sketch: a tab-separated line per loop at 9600 baud; a host
    at another speed reads garbage (as a real UART would give it)."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        k = 0
        while not self.stop.is_set():
            k += 1
            line = f"100\t{20 * k}\t0\t{3 * k}\t{-3 * k}\t{3 * k}\t{-3 * k}\r\n".encode()
            try:
                host_9600 = termios.tcgetattr(self.slave)[5] == termios.B9600
                os.write(self.master, line if host_9600 else bytes((b * 37 + 128) & 0xFF for b in line))
            except OSError:
                return
            time.sleep(0.02)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(1)
        for fd in (self.master, self.slave):
            os.close(fd)


def test_text_lines_are_recognised() -> None:
    assert looks_like_text_log(b"12\t3\n100\t2000\t0\t5\t-5\t5\t-5\r\n100\t2020\t0\t8\t-8\t8\t-8\r\n100\t")
    assert not looks_like_text_log(bytes(range(256)) * 4)
    assert not looks_like_text_log(b"")


def test_a_board_running_the_2019_sketch_is_named() -> None:
    sketch = FakeSketch()
    try:
        with pytest.raises(BoardError, match=r"looks like the 2019 logging sketch.*flash the omnibench firmware"):
            Board.open(sketch.path, timeout=1.0)
    finally:
        sketch.close()
