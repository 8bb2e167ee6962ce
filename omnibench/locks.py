"""Exclusive advisory locks (flock) that name the process holding them.

Used for the board's serial port (one process drives a board) and for a run directory (one
process writes a run: a second `--resume` of the same run is refused). The holder is read
from /proc/locks, so the refusal can say which program to stop.
"""

from __future__ import annotations

import os

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: locks are not available
    fcntl = None  # type: ignore[assignment]


class Locked(Exception):
    """The lock is held; `holder` names the process ("process PID (command line)")."""

    def __init__(self, holder: str) -> None:
        super().__init__(holder)
        self.holder = holder


def lock_exclusive(fd: int) -> None:
    """flock(LOCK_EX | LOCK_NB) on `fd`; Locked(holder) if another open file holds it.
    A file system without flock (or a non-POSIX system) is left unlocked."""
    if fcntl is None:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise Locked(lock_holder(fd)) from None
    except OSError:
        return


def lock_holder(fd: int) -> str:
    """'process PID (command line)' holding a lock on the file open as `fd` (from /proc/locks)."""
    st = os.fstat(fd)
    key = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino)
    try:
        with open("/proc/locks", encoding="ascii", errors="replace") as fh:
            lines = fh.read().splitlines()
    except OSError:
        return "another process"
    for line in lines:
        parts = line.split()
        if len(parts) < 6 or parts[1] == "->":
            continue
        try:
            pid = int(parts[4])
            maj, mnr, ino = parts[5].split(":")
            if (int(maj, 16), int(mnr, 16), int(ino)) != key:
                continue
        except ValueError:
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                cmd = fh.read().replace(b"\0", b" ").decode(errors="replace").strip()
        except OSError:
            cmd = ""
        return f"process {pid}" + (f" ({cmd[:120]})" if cmd else "")
    return "another process"


def lock_directory(path: str | os.PathLike) -> int:
    """Open and lock directory `path` (nothing is written); returns the fd (close to release).
    Locked(holder) if another process holds it."""
    fd = os.open(path, os.O_RDONLY)
    try:
        lock_exclusive(fd)
    except BaseException:
        os.close(fd)
        raise
    return fd
