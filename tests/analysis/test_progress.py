"""The spinner of long phases (fit, diagnose, kernel compile): on a terminal only."""

from __future__ import annotations

import io
import sys

from omnibench.progress import working


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_gets_the_phase_and_its_elapsed_time(monkeypatch) -> None:
    err = _Tty()
    monkeypatch.setattr(sys, "stderr", err)
    with working("fitting"):
        pass
    assert "fitting: 0 s" in err.getvalue() and "⠋" in err.getvalue()  # the spinner, then the time


def test_a_pipe_gets_nothing(monkeypatch) -> None:
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    with working("fitting"):
        pass
    assert err.getvalue() == ""
