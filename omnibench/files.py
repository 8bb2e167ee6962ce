"""Reading the tool's TOML input files with one-line errors naming the file."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from omnibench.errors import UserError


def read_text(path: str | Path, kind: str) -> str:
    """The text of a `kind` file ("robot file", "model file", ...); UserError if unreadable."""
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{p}: {kind} not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: cannot read {kind} ({exc.__class__.__name__})") from None


def read_toml(path: str | Path, kind: str) -> tuple[dict[str, Any], str]:
    """(parsed tables, text) of a TOML `kind` file; UserError on a missing file or bad TOML."""
    text = read_text(path, kind)
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{Path(path)}: not valid TOML: {exc}") from None
