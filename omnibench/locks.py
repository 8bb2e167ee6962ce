"""Exclusive advisory locks (flock) that name the process holding them.

Used for the board's serial port (one process drives a board) and for a run directory (one
process writes a run: a second `--resume` of the same run is refused). The holder is read
from /proc/locks, so the refusal can say which program to stop.
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])

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


@contextlib.contextmanager
def waiting_lock(path: str | os.PathLike) -> Iterator[None]:
    """Hold an exclusive lock on file `path` (created), waiting while another process holds it:
    one process at a time does the work behind it (the physics kernel's compile). Where the file
    cannot be made or locked, the work runs unlocked."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        yield
        return
    try:
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX)
            except OSError:
                pass
        yield
    finally:
        os.close(fd)


LOCK_FILE = "omnibench.lock"


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, what: str = "a campaign") -> Iterator[Path]:
    """Hold `folder`/omnibench.lock (created, holding our PID) while a process writes into the
    folder: a second writer is refused with UserError naming the first's PID and command line.
    The lock file is removed on exit (checked by inode, so a waiting opener never locks a stale one)."""
    from omnibench.errors import UserError

    folder = Path(folder)
    made = not folder.exists()
    path = folder / LOCK_FILE
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out {folder}: cannot make the folder ({exc.strerror or exc})") from None
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise UserError(f"--out {folder}: cannot write {path.name} there ({exc.strerror or exc})") from None
        try:
            lock_exclusive(fd)
        except Locked as exc:
            os.close(fd)
            raise UserError(f"{folder}: {what} is writing into this folder ({exc.holder}); wait for it to end, "
                            "or give another --out") from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the holder removed it as we opened it: take the new one
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
    except OSError:
        pass  # the flock holds; the PID in the file is only for a person looking
    try:
        yield path
    finally:
        try:
            path.unlink()
            if made:
                folder.rmdir()  # a refused or failed run into a new folder leaves nothing behind
        except OSError:
            pass
        os.close(fd)


def holds_out_folder(what: str) -> Callable[[F], F]:
    """Decorator: `fn(port, out, ...)` runs holding `folder_lock(out, what)`."""
    def deco(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(port: Any, out: Any, *args: Any, **kwargs: Any) -> Any:
            with folder_lock(out, what):
                return fn(port, out, *args, **kwargs)
        return wrapper  # type: ignore[return-value]
    return deco
