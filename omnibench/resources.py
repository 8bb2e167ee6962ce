"""Find the protocol and procedure folders, in a source checkout or an installed wheel, and the
user's cache folder."""

from __future__ import annotations

import os
from pathlib import Path

_PKG = Path(__file__).resolve().parent


def data_dir(name: str) -> Path:
    """Folder `protocols` or `procedures`: the repo's top-level one, else the wheel's copy."""
    for candidate in (_PKG.parent / name, _PKG / "_data" / name):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"omnibench data folder {name!r} is missing from the installation")


def cache_root() -> Path:
    """omnibench's cache folder: $OMNIBENCH_CACHE, else $XDG_CACHE_HOME/omnibench, else
    ~/.cache/omnibench (not created here; callers fall back to a temporary folder when it cannot
    be written)."""
    return Path(os.environ.get("OMNIBENCH_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.join(Path.home(), ".cache")), "omnibench"))
