"""The actuation chain of the project's own firmware as data (actuation.toml beside this file):
the duty each wheel's driver is actually given, and the firmware timing a run records.

The arithmetic is the firmware's (firmware/avr/sabertooth.c `sabertooth_set`): the host's duty
goes on the wire as an i16 round(u * 32767), and the board sends the Sabertooth packet-serial
value (|wire| * 127 + 16383) // 32767 with the sign as the command, so 0.3 acts as 38/127.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from omnibench.files import read_toml

ACTUATION_FILE = Path(__file__).with_name("actuation.toml")


@lru_cache(maxsize=1)
def chain() -> dict[str, Any]:
    """The parsed actuation description (driver and timing tables)."""
    data, _ = read_toml(ACTUATION_FILE, "actuation description")
    return data


def packet_s() -> float:
    """Time one driver packet takes on the line, s (4 bytes of 10 bits at 9600 baud: 4.17 ms)."""
    t = chain()["timing"]
    return float(t["packet_bytes"]) * float(t["bits_per_byte"]) / float(t["baud"])


def applied_duty(u: Any, steps: int | None = None, wire_scale: int | None = None) -> np.ndarray:
    """The duty the drivers apply for commanded duties `u` (any shape, clipped to [-1, 1]): the
    wire's i16 rounding, then the driver's nearest step of 1/steps per direction (defaults: the
    description's 32767 and 127; a run replays the values it recorded)."""
    d = chain()["driver"]
    scale = int(wire_scale if wire_scale is not None else d["wire_scale"])
    steps = int(steps if steps is not None else d["steps"])
    wire = np.rint(np.clip(np.asarray(u, dtype=float), -1.0, 1.0) * scale).astype(np.int64)
    value = (np.abs(wire) * steps + scale // 2) // scale
    return np.sign(wire) * value / steps


def wheel_delays(order: Any = None, offset_s: float | None = None, packet: float | None = None) -> list[float]:
    """When each wheel's new duty acts after the board takes SET_DUTIES, s (FL, FR, RL, RR): the
    command offset plus one packet time per packet sent before and including the wheel's, in the
    send order (every wheel changing; a wheel whose duty is unchanged gets no packet)."""
    t = chain()["timing"]
    order = [int(w) for w in (order if order is not None else t["command_order"])]
    off = float(t["command_offset_s"]) if offset_s is None else float(offset_s)
    p = packet_s() if packet is None else float(packet)
    out = [0.0] * 4
    for place, wheel in enumerate(order):
        out[wheel - 1] = off + (place + 1) * p
    return out


def firmware_timing() -> dict[str, Any]:
    """The run record's `firmware_timing` for runs through this firmware (the keys of the 2019
    sketches' records, runs/tfm.py: sketch, command_order, packet_s, command_offset_s), with the
    driver's resolution."""
    t, d = chain()["timing"], chain()["driver"]
    return {"sketch": str(t["sketch"]), "command_order": [int(w) for w in t["command_order"]],
            "commands": str(t["commands"]), "packet_s": packet_s(),
            "command_offset_s": float(t["command_offset_s"]), "wheel_delays_s": wheel_delays(),
            "driver": {"model": str(d["model"]), "steps": int(d["steps"]), "wire_scale": int(d["wire_scale"])},
            "duties": "as commanded; the drivers apply the nearest step (the analysis replays it)",
            "source": "the firmware's actuation description (omnibench/model/actuation.toml)"}
