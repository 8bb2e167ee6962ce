"""Opening any pyserial URL: device paths, sim://, socket://, hwgrep://, loop://.

`sim://` is served by omnibench.sim; pyserial imports its handler lazily by package name,
so this layer needs no import of the simulator.
"""

from __future__ import annotations

import os

import serial

from omnibench.errors import BoardError

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no lock (pyserial's own handling applies)
    fcntl = None  # type: ignore[assignment]

SIM_HANDLER_PACKAGE = "omnibench.sim"


def register_sim_handler() -> None:
    """Let `serial.serial_for_url` open `sim://...` URLs (idempotent)."""
    if SIM_HANDLER_PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(SIM_HANDLER_PACKAGE)


def open_url(url: str, *, baudrate: int, timeout: float, what: str = "board") -> serial.SerialBase:
    """Open `url` with pyserial; BoardError with a one-line hint if it cannot be opened."""
    if url.lower().startswith("sim://"):
        register_sim_handler()
    try:
        port = serial.serial_for_url(url, baudrate=baudrate, timeout=timeout, write_timeout=1.0)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise BoardError(f"cannot open the {what} port {url}: {exc} (check the name with `omnibench ports` "
                         "and that no other program holds it)") from None
    try:
        lock_exclusive(port, url, what)
    except BaseException:
        port.close()
        raise
    return port


def lock_exclusive(port: serial.SerialBase, url: str, what: str = "board") -> None:
    """Take an exclusive advisory lock (flock) on a device port, so a second omnibench (or any
    program that locks, e.g. minicom, pyserial's exclusive=True) cannot open it and reconfigure
    the board under a running procedure. BoardError naming the holding process if taken.
    URL ports without a file descriptor (sim://, socket://) need none."""
    fd = getattr(port, "fd", None)
    if fcntl is None or not isinstance(fd, int):
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise BoardError(f"the {what} port {url} is in use by {lock_holder(fd)}: stop that program first "
                         "(one process drives a board at a time)") from None
    except OSError:
        return  # a file system without flock: nothing to lock with


def lock_holder(fd: int) -> str:
    """'process PID (command line)' holding a flock on the file open as `fd` (from /proc/locks)."""
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
