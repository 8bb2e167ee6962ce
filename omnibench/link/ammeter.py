"""The battery ammeter: the board's own sensor, or a bench instrument on its own serial port.

A separate instrument speaks SCPI lines (`MEAS:CURR:DC?` -> "+1.234E+00"). Attach it to a
board with `Board.attach_ammeter(open_ammeter(url))`: the client then reads it while it
reads telemetry and stores each reading in the `Sample.ammeter_current` of the telemetry
sample that triggered it, so readings are aligned to the board's clock. Without an
instrument, `Sample.battery_current` (the board's sensor, when HELLO lists the
BATTERY_CURRENT capability) is the battery current.
"""

from __future__ import annotations

import time

import serial

from omnibench.errors import BoardError
from omnibench.link.urls import open_url

DEFAULT_BAUDRATE = 9600


class ScpiAmmeter:
    """A SCPI ammeter on a serial URL (real instrument or `sim://ammeter?board=NAME`)."""

    def __init__(self, port: serial.SerialBase, url: str, timeout: float) -> None:
        self._port = port
        self.url = url
        self.timeout = timeout
        self.idn = ""

    def query(self, command: str) -> str:
        """Send one command line and return the reply line (BoardError if none in time)."""
        try:
            self._port.write((command + "\n").encode("ascii"))
            deadline = time.monotonic() + self.timeout
            buf = bytearray()
            while not buf.endswith(b"\n"):
                if time.monotonic() > deadline:
                    raise BoardError(f"ammeter on {self.url} did not answer {command!r} within "
                                     f"{self.timeout:g} s (check its cable, baud rate and remote mode)")
                buf += self._port.read(max(1, self._port.in_waiting))
        except (serial.SerialException, OSError) as exc:
            raise BoardError(f"lost the ammeter on {self.url}: {exc}") from None
        return buf.decode("ascii", "replace").strip()

    def identify(self) -> str:
        """The instrument's *IDN? string."""
        self.idn = self.query("*IDN?")
        return self.idn

    def measure(self) -> float:
        """One DC current reading, A."""
        reply = self.query("MEAS:CURR:DC?")
        try:
            return float(reply)
        except ValueError:
            raise BoardError(f"ammeter on {self.url} answered {reply!r} to MEAS:CURR:DC?") from None

    def close(self) -> None:
        """Close the instrument's port."""
        try:
            self._port.close()
        except (serial.SerialException, OSError):
            pass

    def __enter__(self) -> "ScpiAmmeter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_ammeter(url: str, *, timeout: float = 1.0, baudrate: int = DEFAULT_BAUDRATE) -> ScpiAmmeter:
    """Open a SCPI ammeter on `url` and check it answers *IDN? (BoardError otherwise)."""
    port = open_url(url, baudrate=baudrate, timeout=0.05, what="ammeter")
    meter = ScpiAmmeter(port, url, timeout)
    try:
        meter.identify()
    except BoardError:
        meter.close()
        raise
    return meter
