"""Progress on the terminal for long work: a spinner with the elapsed time, the latest progress
line of the work under it and an ETA when those lines count their way through (`k/N`).

On a terminal only: a pipe or a log file gets nothing from the spinner, so scripted output stays
clean (the work's own progress lines still reach stderr; see `TeeStream`).
"""

from __future__ import annotations

import contextlib
import io
import re
import sys
import time
from collections.abc import Iterator
from typing import Any

#: a count in a progress line: "(3/12)" or "candidate 3 of 12"
_COUNT = re.compile(r"\((\d+)/(\d+)\)|\b(\d+) of (\d+)\b")
_active = 0  #: nesting depth of `working` (rich allows one live display at a time)


class StageStatus:
    """What the spinner says: `label`, the elapsed seconds, the latest progress line and, when
    that line carries a count (`(k/N)` or `k of N`), the seconds left at the rate the count has
    gone so far."""

    def __init__(self, label: str, clock: Any = time.monotonic) -> None:
        self.label, self.clock = label, clock
        self.t0 = clock()
        self.line = ""
        self._count_start: tuple[str, int, float] | None = None  # (series, k, time) of the first count seen
        self._eta: tuple[float, float] | None = None  # (seconds left, at what time)

    def update(self, line: str) -> None:
        """A progress line from the work (a count `(k/N)` in it feeds the ETA)."""
        line = line.strip()
        if not line:
            return
        self.line = line
        m = _COUNT.search(line)
        if m is None:
            return
        k, n = (int(m.group(1)), int(m.group(2))) if m.group(1) else (int(m.group(3)), int(m.group(4)))
        series = line[:m.start()].rsplit(":", 1)[0] + f"/{n}"  # "round 1/12": a new round restarts the rate
        now = self.clock()
        if self._count_start is None or self._count_start[0] != series or k < self._count_start[1]:
            self._count_start, self._eta = (series, k, now), None
            return
        _, k0, t_k0 = self._count_start
        if k > k0:
            self._eta = ((now - t_k0) / (k - k0) * (n - k + 1), now)

    def eta(self) -> float | None:
        """Seconds left in the counted work now (None until two counts were seen)."""
        if self._eta is None:
            return None
        left, at = self._eta
        return max(left - (self.clock() - at), 0.0)

    def text(self) -> str:
        eta = self.eta()
        parts = [f"{self.label}, {self.clock() - self.t0:.0f} s"]
        if self.line:
            parts.append(self.line)
        if eta is not None:
            parts.append(f"ETA {eta:.0f} s")
        return ": ".join(parts[:2]) + ("".join(f", {p}" for p in parts[2:]))

    def __rich__(self) -> str:  # redrawn by the spinner, so the elapsed time runs on
        return self.text()


@contextlib.contextmanager
def working(label: str) -> Iterator[StageStatus]:
    """Show `label` with a spinner while the block runs, then `label: N s` (stderr, tty only).

    The yielded StageStatus takes the work's progress lines (`update`). Nested inside another
    `working` block (a command that has its own spinner, run by the campaign), nothing more is
    drawn: the outer spinner keeps the screen."""
    global _active
    status = StageStatus(label)
    if not sys.stderr.isatty() or _active:
        _active += 1
        try:
            yield status
        finally:
            _active -= 1
        return
    from rich.console import Console

    # the terminal itself, fixed now: Console(stderr=True) would look sys.stderr up at each write,
    # and under a stage that is the TeeStream feeding this very spinner (its frames fed back in)
    console = Console(file=sys.stderr)
    _active += 1
    try:
        with console.status(status):
            yield status
    finally:
        _active -= 1
    console.print(f"   {label}: {time.monotonic() - status.t0:.0f} s", highlight=False)


class TeeStream(io.TextIOBase):
    """A text stream that passes every write on to `stream` (the terminal, live) and keeps a copy
    (`getvalue()`); each complete line also goes to `on_line` (e.g. StageStatus.update).

    It answers isatty() and fileno() as `stream` does, so rich and click treat it as the terminal."""

    def __init__(self, stream: Any, on_line: Any = None) -> None:
        super().__init__()
        self.stream, self.on_line = stream, on_line
        self._copy = io.StringIO()
        self._partial = ""

    def write(self, s: str) -> int:
        if not isinstance(s, str):
            raise TypeError(f"write() argument must be str, not {type(s).__name__}")
        self._copy.write(s)
        if self.stream is not None:
            self.stream.write(s)
        if self.on_line is not None:
            *done, self._partial = (self._partial + s).split("\n")
            for line in done:
                self.on_line(line)
        return len(s)

    def flush(self) -> None:
        if self.stream is not None:
            self.stream.flush()

    def writable(self) -> bool:
        return True

    def isatty(self) -> bool:
        return bool(self.stream is not None and self.stream.isatty())

    def fileno(self) -> int:
        if self.stream is None:
            raise io.UnsupportedOperation("fileno")
        return self.stream.fileno()

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return getattr(self.stream, "encoding", None) or "utf-8"

    @property
    def errors(self) -> str | None:  # type: ignore[override]
        return getattr(self.stream, "errors", None)

    def getvalue(self) -> str:
        return self._copy.getvalue()
