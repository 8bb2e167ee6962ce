"""A spinner with the elapsed time for a long phase, on a terminal only (a pipe or log file
gets nothing, so scripted output stays clean)."""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Iterator


@contextlib.contextmanager
def working(label: str) -> Iterator[None]:
    """Show `label` with a spinner while the block runs, then `label: N s` (stderr, tty only)."""
    if not sys.stderr.isatty():
        yield
        return
    from rich.console import Console

    console = Console(stderr=True)
    t0 = time.monotonic()
    with console.status(label):
        yield
    console.print(f"   {label}: {time.monotonic() - t0:.0f} s", highlight=False)
