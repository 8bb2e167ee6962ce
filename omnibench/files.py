"""Reading the tool's TOML input files with one-line errors naming the file; writing its outputs
atomically, never over a file it did not write."""

from __future__ import annotations

import io
import os
import tempfile
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


# ----------------------------------------------------------------------------- writing outputs
#: The first line of every model file the tool writes: only a file starting with it (or with the
#: header older versions wrote) is overwritten without --force.
MARKER = "# written by omnibench"
_OLD_MARKER = "# omnibench model file"


def written_by_tool(path: str | Path) -> bool:
    """True when `path` is a model file this tool wrote (its first line carries the marker)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            first = fh.readline()
    except OSError:
        return False
    if first.startswith(MARKER) or first.startswith(_OLD_MARKER):
        return True
    return first.startswith("# ") and "extended by `omnibench diagnose`" in first


def check_writable_folder(folder: str | Path, option: str = "--out") -> None:
    """Prove, before any work starts and without creating anything, that `folder` can be created
    or written: a probe file in it (or in its nearest existing parent); UserError naming `option`."""
    d = Path(folder)
    if d.exists() and not d.is_dir():
        raise UserError(f"{option} {d}: is a file, not a folder")
    base = d.absolute()
    while not base.exists() and base != base.parent:
        base = base.parent
    try:
        if not base.is_dir():
            raise NotADirectoryError(20, "Not a directory")
        fd, probe = tempfile.mkstemp(prefix=".omnibench-probe-", dir=base)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise UserError(f"{option} {d}: cannot write there ({exc.strerror or exc.__class__.__name__})") from None


def check_new_output(path: str | Path, option: str = "--out", *, force: bool = False) -> None:
    """Refuse, before the work starts, an output file the tool would overwrite although it did not
    write it (without `force`), or one whose folder cannot be written."""
    p = Path(path)
    if p.is_dir():
        raise UserError(f"{option} {p}: is a directory; give a file name")
    if p.exists() and not force and not written_by_tool(p):
        raise UserError(f"{option} {p}: exists and was not written by omnibench; give another name, "
                        "or --force to overwrite it")
    check_writable_folder(p.parent, option)


def write_atomic(path: str | Path, data: str | bytes, kind: str = "file") -> Path:
    """Write `data` to a temporary file beside `path`, then rename it over `path`: a reader (or a
    crash) sees the old file or the new one, never half of one. UserError when it cannot."""
    p = Path(path)
    tmp = None
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode("utf-8") if isinstance(data, str) else data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, p)
    except OSError as exc:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
        raise UserError(f"{p}: cannot write the {kind} ({exc.strerror or exc.__class__.__name__})") from None
    return p


def save_figure(fig: Any, path: str | Path, **kwargs: Any) -> Path:
    """Save a matplotlib figure atomically (a temporary file beside `path`, then renamed)."""
    p = Path(path)
    buf = io.BytesIO()
    fig.savefig(buf, format=p.suffix.lstrip(".") or "png", **kwargs)
    return write_atomic(p, buf.getvalue(), "figure")
