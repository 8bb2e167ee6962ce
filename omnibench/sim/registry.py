"""Simulated boards open in this process, by name, so a `sim://ammeter?board=NAME` finds its robot.

Weak references: a board disappears from the registry when its port is gone.
"""

from __future__ import annotations

import threading
import weakref
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from omnibench.sim.board import SimBoard

_lock = threading.Lock()
_boards: "weakref.WeakValueDictionary[str, SimBoard]" = weakref.WeakValueDictionary()
_latest: "weakref.ref[SimBoard] | None" = None


def register(name: str | None, board: "SimBoard") -> None:
    """Remember `board` (under `name` if given) as the most recently opened board."""
    global _latest
    with _lock:
        if name:
            _boards[name] = board
        _latest = weakref.ref(board)


def get(name: str) -> "SimBoard | None":
    """The board opened with `name=NAME`, or None."""
    with _lock:
        return _boards.get(name)


def latest() -> "SimBoard | None":
    """The board opened most recently in this process, or None."""
    with _lock:
        return _latest() if _latest is not None else None
