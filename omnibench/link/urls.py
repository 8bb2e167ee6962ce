"""Opening any pyserial URL: device paths, sim://, socket://, hwgrep://, loop://.

`sim://` is served by omnibench.sim; pyserial imports its handler lazily by package name,
so this layer needs no import of the simulator.
"""

from __future__ import annotations

import serial

from omnibench import locks
from omnibench.errors import BoardError, UserError

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
        if getattr(exc, "bad_input", False):  # a simulator URL with a wrong setting: bad input, not a fault
            raise UserError(str(exc)) from None
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
    if not isinstance(fd, int):
        return
    try:
        locks.lock_exclusive(fd)
    except locks.Locked as exc:
        raise BoardError(f"the {what} port {url} is in use by {exc.holder}: stop that program first "
                         "(one process drives a board at a time)") from None
