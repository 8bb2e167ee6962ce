"""The simulated Omnibot board behind a serial port.

`register()` makes `sim://` URLs work with `serial.serial_for_url` in this process; the
pseudo-terminal server (`omnibench sim serve`) lets other processes talk to it. The board
speaks the protocol built from protocols/*.toml and runs omnibench.model's physics.
See docs/simulator.md.
"""

from __future__ import annotations

import serial

PACKAGE = "omnibench.sim"


def register() -> None:
    """Add this package to pyserial's URL handlers (idempotent): enables `sim://...`."""
    if PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(PACKAGE)
