"""The robot's wiring as `omnibench commission` found it, and the board seen through it.

A wiring file (TOML, written by `commission`, read by every procedure) says, for each wheel in
the model's order FL, FR, RL, RR, which board channel drives it (motor_channel, 1-based) and
with which sign, which encoder channel reads it and with which sign, and which sensors work:

    board_id = "0B0B0001"
    motor_channel = [2, 1, 3, 4]
    motor_sign = [1, 1, 1, -1]
    encoder_channel = [2, 1, 3, 4]
    encoder_sign = [1, 1, 1, 1]
    motor_current_sensor = true
    battery_current_sensor = true
    battery_voltage_V = 24.1

`WiredBoard` wraps a BenchBoard so that the runner's duties, encoders and currents are per wheel.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from omnibench.bench.board import Telemetry
from omnibench.errors import UserError
from omnibench.files import read_toml

WHEELS = ("FL", "FR", "RL", "RR")
DEFAULT_FILE = Path("wiring.toml")


@dataclass(frozen=True)
class Wiring:
    """Per wheel (FL FR RL RR): board motor/encoder channel (1-based) and sign."""

    motor_channel: tuple[int, int, int, int] = (1, 2, 3, 4)
    motor_sign: tuple[int, int, int, int] = (1, 1, 1, 1)
    encoder_channel: tuple[int, int, int, int] = (1, 2, 3, 4)
    encoder_sign: tuple[int, int, int, int] = (1, 1, 1, 1)
    board_id: str | None = None          #: as the board's HELLO reports it (hex)
    motor_current_sensor: bool = True
    battery_current_sensor: bool = True
    battery_voltage_V: float | None = None
    date: str = ""

    @property
    def identity(self) -> bool:
        return (self.motor_channel == self.encoder_channel == (1, 2, 3, 4)
                and self.motor_sign == self.encoder_sign == (1, 1, 1, 1))

    def describe(self) -> str:
        """'FL on motor 2 reversed, encoder 2; ...' (channels that differ from straight wiring)."""
        parts = []
        for w in range(4):
            m, ms, e, es = (self.motor_channel[w], self.motor_sign[w], self.encoder_channel[w], self.encoder_sign[w])
            if (m, ms, e, es) != (w + 1, 1, w + 1, 1):
                parts.append(f"{WHEELS[w]} on motor {m}{' reversed' if ms < 0 else ''}, "
                             f"encoder {e}{' reversed' if es < 0 else ''}")
        return "; ".join(parts) or "straight (channel k drives and reads wheel k)"

    def to_toml(self) -> str:
        import tomli_w

        d = {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items() if v is not None}
        return ("# omnibench commission: which board channel drives and reads each wheel (FL FR RL RR)\n"
                + tomli_w.dumps(d))


def _perm(d: dict, key: str, where: str) -> tuple[int, int, int, int]:
    v = d.get(key, [1, 2, 3, 4])
    if not isinstance(v, list) or sorted(v) != [1, 2, 3, 4]:
        raise UserError(f"{where}: {key} must list the channels 1-4 once each, got {v!r}")
    return tuple(int(x) for x in v)  # type: ignore[return-value]


def _signs(d: dict, key: str, where: str) -> tuple[int, int, int, int]:
    v = d.get(key, [1, 1, 1, 1])
    if not isinstance(v, list) or len(v) != 4 or any(x not in (1, -1) for x in v):
        raise UserError(f"{where}: {key} must be four signs 1 or -1, got {v!r}")
    return tuple(int(x) for x in v)  # type: ignore[return-value]


def load_wiring(path: str | Path) -> Wiring:
    """Read a wiring file; UserError naming it on any problem."""
    p = Path(path)
    if not p.is_file() and not p.exists():
        raise UserError(f"wiring file {p} not found (write it with omnibench commission)")
    d, _ = read_toml(p, "wiring file")
    where = f"wiring file {p}"
    if "motor_channel" not in d:
        raise UserError(f"{where}: no motor_channel (not a file written by omnibench commission)")
    return Wiring(motor_channel=_perm(d, "motor_channel", where), motor_sign=_signs(d, "motor_sign", where),
                  encoder_channel=_perm(d, "encoder_channel", where),
                  encoder_sign=_signs(d, "encoder_sign", where),
                  board_id=None if d.get("board_id") is None else str(d["board_id"]),
                  motor_current_sensor=bool(d.get("motor_current_sensor", True)),
                  battery_current_sensor=bool(d.get("battery_current_sensor", True)),
                  battery_voltage_V=d.get("battery_voltage_V"), date=str(d.get("date", "")))


def wiring_for(path: str | Path | None) -> tuple[Wiring | None, str | None]:
    """The wiring file to use: `path`, else ./wiring.toml when it exists, else none."""
    if path is not None:
        return load_wiring(path), str(path)
    if DEFAULT_FILE.is_file():
        return load_wiring(DEFAULT_FILE), str(DEFAULT_FILE.resolve())
    return None, None


class WiredBoard:
    """A BenchBoard whose duties, encoders, currents and duty echo are per wheel (FL FR RL RR)."""

    def __init__(self, board: Any, wiring: Wiring) -> None:
        self._board, self.wiring = board, wiring
        hid = (getattr(board, "hello", {}) or {}).get("board_id")
        if wiring.board_id is not None and hid is not None and str(hid) != str(wiring.board_id):
            raise UserError(f"the wiring file was commissioned on board {wiring.board_id}, this is board "
                            f"{hid}: run omnibench commission on this robot first")
        self.has_motor_current = bool(getattr(board, "has_motor_current", True) and wiring.motor_current_sensor)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._board, name)

    def set_duties(self, duties: Sequence[float]) -> None:
        ch = [0.0] * 4
        for w, u in enumerate(duties):
            ch[self.wiring.motor_channel[w] - 1] = self.wiring.motor_sign[w] * float(u)
        self._board.set_duties(ch)

    def _per_wheel(self, values: Sequence[Any] | None, channel: tuple[int, ...], sign: tuple[int, ...]) -> Any:
        if values is None:
            return None
        return tuple(type(values[0])(sign[w] * values[channel[w] - 1]) for w in range(4))

    def read(self, timeout: float) -> Telemetry:
        s = self._board.read(timeout)
        w = self.wiring
        return Telemetry(t=s.t, seq=s.seq, encoder=self._per_wheel(s.encoder, w.encoder_channel, w.encoder_sign),
                         motor_current=self._per_wheel(s.motor_current, w.motor_channel, w.motor_sign),
                         battery_voltage=s.battery_voltage, battery_current=s.battery_current, faults=s.faults,
                         duty=self._per_wheel(s.duty, w.motor_channel, w.motor_sign))
