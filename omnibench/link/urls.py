"""Opening any pyserial URL: device paths, sim://, socket://, hwgrep://, loop://.

`sim://` is served by omnibench.sim; pyserial imports its handler lazily by package name,
so this layer needs no import of the simulator.
"""

from __future__ import annotations

import serial

from omnibench.errors import BoardError

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
        return serial.serial_for_url(url, baudrate=baudrate, timeout=timeout, write_timeout=1.0)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise BoardError(f"cannot open the {what} port {url}: {exc} (check the name with `omnibench ports` "
                         "and that no other program holds it)") from None
