"""Find the protocol and procedure folders, in a source checkout or an installed wheel."""

from __future__ import annotations

from pathlib import Path

_PKG = Path(__file__).resolve().parent


def data_dir(name: str) -> Path:
    """Folder `protocols` or `procedures`: the repo's top-level one, else the wheel's copy."""
    for candidate in (_PKG.parent / name, _PKG / "_data" / name):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"omnibench data folder {name!r} is missing from the installation")
