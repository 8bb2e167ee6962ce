"""The robot around the simulated chip: its wiring, described apart from any firmware build,
and its Sabertooth drivers as Dimension Engineering documents them.

A robot file (robots/*.toml, or any path) says which Arduino pin carries the drivers' S1 line,
at which rate the drivers listen (stored rate, or autobaud from the first 0xAA), which driver
channel turns which wheel and in which sense, on which chip-select pin each wheel's LS7366R
sits and which way it counts, and what the analog inputs measure. The rig (board.py) wires
the simulated ATmega2560 to that robot; a firmware built for another wiring then fails, as it
would on the robot.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omnibench.errors import UserError
from omnibench.files import read_toml

ROBOTS_DIR = Path(__file__).parent / "robots"
DEFAULT_ROBOT = "omnibot-2019"
WHEELS = ("FL", "FR", "RL", "RR")

#: Arduino Mega pin -> (port letter, bit) for the pins a robot file may name
MEGA_PINS: dict[int, tuple[str, int]] = {
    2: ("E", 4), 3: ("E", 5), 4: ("G", 5), 5: ("E", 3), 6: ("H", 3), 7: ("H", 4), 8: ("H", 5),
    9: ("H", 6), 10: ("B", 4), 11: ("B", 5), 12: ("B", 6), 13: ("B", 7), 14: ("J", 1), 16: ("H", 1),
    18: ("D", 3), **{p: ("L", 49 - p) for p in range(42, 50)},
}


@dataclass(frozen=True)
class WheelWiring:
    """One wheel: the driver channel that turns it and the counter that reads it."""

    driver: int          #: driver address (128..135)
    channel: int         #: 1 or 2
    sense: int           #: +1: the driver's "forward" turns the wheel forward
    encoder_cs: int      #: Arduino pin of its LS7366R's chip select (42..49)
    encoder_sense: int   #: +1: the raw count rises as the wheel turns forward


@dataclass(frozen=True)
class RobotWiring:
    """What the rig connects to the chip (see the module docstring)."""

    name: str
    s1_pin: int
    enable_pin: int
    addresses: tuple[int, ...]
    model: str
    baud: int            #: the drivers' stored rate (ignored with autobaud)
    autobaud: bool
    wheels: tuple[WheelWiring, ...]
    battery_divider: float
    battery_current: str  #: "none" | "hall"
    motor_current: str
    hall_mv_per_a: float
    hall_zero_mv: float
    source: str = field(default="", compare=False)


def _merged(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The file's tables over those of the file it `extends` (by name in robots/ or a path)."""
    if path in seen:
        raise UserError(f"{path}: 'extends' loops back to itself")
    d, _ = read_toml(path, "robot wiring")
    base = d.pop("extends", None)
    if base is None:
        return d
    merged = _merged(_robot_path(str(base), path.parent), (*seen, path))
    for k, v in d.items():
        merged[k] = {**merged[k], **v} if isinstance(v, dict) and isinstance(merged.get(k), dict) else v
    return merged


def _robot_path(name_or_path: str, here: Path = ROBOTS_DIR) -> Path:
    p = Path(name_or_path)
    if p.suffix == ".toml":
        return p
    for folder in (here, ROBOTS_DIR):
        if (folder / f"{name_or_path}.toml").exists():
            return folder / f"{name_or_path}.toml"
    known = ", ".join(sorted(x.stem for x in ROBOTS_DIR.glob("*.toml")))
    raise UserError(f"no robot wiring {name_or_path!r} (known: {known}; or give a .toml path)")


def load_robot(name_or_path: str | Path | None = None) -> RobotWiring:
    """The robot file by name (robots/NAME.toml) or path; UserError naming a bad entry."""
    path = _robot_path(str(name_or_path or DEFAULT_ROBOT))
    d = _merged(path)
    where = str(path)
    try:
        st, an, wh = d["sabertooth"], d["analog"], d["wheels"]
        wheels = []
        for w in WHEELS:
            x = wh[w]
            ww = WheelWiring(int(x["driver"]), int(x["channel"]), int(x["sense"]), int(x["encoder_cs"]),
                             int(x["encoder_sense"]))
            if ww.channel not in (1, 2) or ww.sense not in (1, -1) or ww.encoder_sense not in (1, -1) \
                    or not 42 <= ww.encoder_cs <= 49:
                raise UserError(f"{where}: wheels.{w}: channel 1|2, sense and encoder_sense 1|-1, encoder_cs 42..49")
            wheels.append(ww)
        robot = RobotWiring(
            name=str(d.get("name", path.stem)), s1_pin=int(st["s1_pin"]), enable_pin=int(st["enable_pin"]),
            addresses=tuple(int(a) for a in st["addresses"]), model=str(st.get("model", "")),
            baud=int(st["baud"]), autobaud=bool(st["autobaud"]), wheels=tuple(wheels),
            battery_divider=float(an["battery_divider"]), battery_current=str(an["battery_current"]),
            motor_current=str(an["motor_current"]), hall_mv_per_a=float(an["hall_mv_per_a"]),
            hall_zero_mv=float(an["hall_zero_mv"]), source=where)
    except KeyError as exc:
        raise UserError(f"{where}: missing {exc}") from None
    except (TypeError, ValueError) as exc:
        raise UserError(f"{where}: {exc}") from None
    for pin in (robot.s1_pin, robot.enable_pin):
        if pin not in MEGA_PINS:
            raise UserError(f"{where}: pin {pin} is not one the rig knows ({sorted(MEGA_PINS)})")
    return robot


class Sabertooth:
    """One Sabertooth in packet-serial mode (Dimension Engineering's 2x12/2x25/2x60 guides).

    Packet: address, command, value, (address + command + value) & 0x7F. Commands 0/1: motor 1
    forward/backward, 4/5: motor 2, value 0..127; 14: serial timeout, value x 100 ms (0 = off):
    no valid packet for that long stops both motors. A packet with a bad checksum is ignored.
    The timeout is not stored: a power cycle clears it (and the outputs)."""

    def __init__(self, address: int) -> None:
        self.address = address
        self.out = {1: 0.0, 2: 0.0}        #: channel output, [-1, 1] of the motor supply
        self.timeout_s: float | None = None
        self.last_packet_s: float | None = None
        self.timed_out = 0                  #: times the serial timeout stopped the motors

    def packet(self, t: float, command: int, value: int) -> None:
        self.last_packet_s = t
        if command in (0, 1, 4, 5):
            self.out[1 if command < 4 else 2] = (-1 if command in (1, 5) else 1) * min(value, 127) / 127
        elif command == 14:
            self.timeout_s = value * 0.1 if value else None

    def expire(self, t: float) -> None:
        if self.timeout_s is not None and self.last_packet_s is not None and t - self.last_packet_s > self.timeout_s:
            if any(self.out.values()):
                self.timed_out += 1
            self.out = {1: 0.0, 2: 0.0}

    def power_cycle(self) -> None:
        self.__init__(self.address)  # type: ignore[misc]


class SabertoothLine:
    """The drivers on one S1 line: bytes in (as the rig decoded them), packets to each driver."""

    def __init__(self, addresses: tuple[int, ...]) -> None:
        self.drivers = {a: Sabertooth(a) for a in addresses}
        self._pk: list[int] = []
        self.bad_checksum = 0
        self.other_address: dict[int, int] = {}   #: packets for addresses no driver has
        self.packets = 0

    def byte(self, t: float, b: int) -> tuple[int, int, int] | None:
        """Feed one byte; the (address, command, value) of a valid packet it completes."""
        if b & 0x80:                         # an address byte starts a packet
            self._pk = [b]
            return None
        if not self._pk:
            return None
        self._pk.append(b)
        if len(self._pk) < 4:
            return None
        a, c, v, s = self._pk
        self._pk = []
        if (a + c + v) & 0x7F != s:
            self.bad_checksum += 1
            return None
        if a not in self.drivers:
            self.other_address[a] = self.other_address.get(a, 0) + 1
            return None
        self.packets += 1
        self.drivers[a].packet(t, c, v)
        return a, c, v

    def expire(self, t: float) -> None:
        for d in self.drivers.values():
            d.expire(t)

    def output(self, address: int, channel: int) -> float:
        d = self.drivers.get(address)
        return d.out[channel] if d else 0.0
