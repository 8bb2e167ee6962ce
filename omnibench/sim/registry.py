"""Simulated boards open in this process, by name, so a `sim://ammeter?board=NAME` (or a
test) finds the board behind `sim://...&name=NAME`, even after its port was closed.

Named boards are kept (the 64 most recent); the latest board is remembered weakly.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from omnibench.sim.board import SimBoard

KEEP = 64
_lock = threading.Lock()
_boards: "OrderedDict[str, SimBoard]" = OrderedDict()
_latest: "weakref.ref[SimBoard] | None" = None


def register(name: str | None, board: "SimBoard") -> None:
    """Remember `board` (under `name` if given) as the most recently opened board."""
    global _latest
    with _lock:
        if name:
            _boards.pop(name, None)
            _boards[name] = board
            while len(_boards) > KEEP:
                _boards.popitem(last=False)
        _latest = weakref.ref(board)


def get(name: str) -> "SimBoard | None":
    """The board opened last with `name=NAME`, or None."""
    with _lock:
        return _boards.get(name)


def latest() -> "SimBoard | None":
    """The board opened most recently in this process (if it still exists), or None."""
    with _lock:
        return _latest() if _latest is not None else None
