"""Recognise a board that prints text lines instead of protocol frames: the 2019 logging sketches
of the Omnibot (one tab-separated line per loop, `command millis 0 enc1 enc2 enc3 enc4`, at
9600 baud). A board that answers that way is not broken: it runs the old sketch."""

from __future__ import annotations

import re
import time

SKETCH_BAUD = 9600  #: the 2019 sketches printed at this speed
_NUMBERS = re.compile(r"^\s*-?\d+(?:\.\d+)?(?:[\t ,;]+-?\d+(?:\.\d+)?)+\s*$")


def looks_like_text_log(data: bytes) -> bool:
    """At least two complete lines, printable ASCII, most of them rows of numbers."""
    lines = [ln for ln in data.replace(b"\r", b"\n").split(b"\n")[1:-1] if ln.strip()]  # drop partial ends
    if len(lines) < 2:
        return False
    printable = sum(32 <= c < 127 or c in (9, 10, 13) for c in data) / max(len(data), 1)
    numeric = sum(bool(_NUMBERS.match(ln.decode("ascii", "replace"))) for ln in lines) / len(lines)
    return printable > 0.95 and numeric >= 0.5


def sketch_message(url: str, baud: int) -> str:
    return (f"the board on {url} prints text lines ({baud} baud) instead of protocol frames: this looks like "
            "the 2019 logging sketch (command, millis, four encoder counts per line); flash the omnibench "
            "firmware from firmware/ (see docs/firmware.md) to drive it with omnibench")


def sniff_sketch(url: str, received: bytes, baud: int, listen_s: float = 1.5) -> str | None:
    """A message if the board is running a 2019 sketch, else None: first the bytes already
    received at `baud`, then (if `baud` is not the sketch's) what the port says at 9600 baud."""
    if looks_like_text_log(received):
        return sketch_message(url, baud)
    if baud == SKETCH_BAUD or not received:
        return None  # silent boards are not sketches; a sketch at another baud sends garbage
    try:
        from omnibench.link.urls import open_url

        port = open_url(url, baudrate=SKETCH_BAUD, timeout=0.05)
    except Exception:  # noqa: BLE001 - only a hint: never hide the original error
        return None
    data = b""
    try:
        end = time.monotonic() + listen_s
        while time.monotonic() < end and len(data) < 4096:
            data += port.read(port.in_waiting or 1)
    except Exception:  # noqa: BLE001
        return None
    finally:
        try:
            port.close()
        except Exception:  # noqa: BLE001
            pass
    return sketch_message(url, SKETCH_BAUD) if looks_like_text_log(data) else None
