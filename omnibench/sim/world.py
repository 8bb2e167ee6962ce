"""The simulated Omnibot's configuration: the world file and the `sim://` URL parameters.

A world file (TOML) says what the operator has set up and what the simulation hides from
the fitted model (undeclared effects). URL parameters override the file. All fields and
defaults are documented in docs/simulator.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from omnibench.errors import UserError

MODES = ("ground", "upside_down")
PLANTS = ("model", "independent")
CLOCKS = ("fast", "realtime")
#: how the board's duties reach the motors: "firmware" (as the project's firmware does: each duty
#: rounded to the driver's packet-serial step and sent one packet per wheel, in order,
#: omnibench/model/actuation.toml) or "ideal" (every duty exact and at once: model-only studies)
ACTUATIONS = ("firmware", "ideal")


@dataclass(frozen=True)
class SensorConfig:
    """Sensor models of the simulated board (SI units, noise is one standard deviation)."""

    current_noise: float = 0.01          #: A, motor current sensor noise
    current_lsb: float = 0.001           #: A, motor current resolution (>= the protocol's 1 mA)
    voltage_noise: float = 0.005         #: V, battery voltage noise
    voltage_lsb: float = 0.001           #: V, battery voltage resolution
    battery_current_noise: float = 0.01  #: A, board's battery current sensor noise
    battery_current_lsb: float = 0.001   #: A
    battery_current_sensor: bool = True  #: False: telemetry battery_current reads 0 (use an ammeter)
    motor_current_sensor: bool = True    #: False: telemetry motor_current reads 0


@dataclass(frozen=True)
class FaultConfig:
    """Faults the simulator injects (rates are per byte on the wire, times are board time, s)."""

    drop: float = 0.0             #: probability that a byte is lost
    corrupt: float = 0.0          #: probability that a byte is replaced by a random byte
    garbage: float = 0.0          #: probability, per byte, that a burst of 1-16 random bytes is inserted
    direction: str = "both"       #: "both", "to_host" (board -> host) or "to_board"
    disconnect_at: float | None = None  #: board time at which the port disappears (cable pulled)
    reset_at: float | None = None       #: board time at which the board reboots (new boot id)
    wrong_baud: bool = False      #: every byte arrives garbled, as if the baud rate were wrong
    protocol_version: int | None = None  #: report this protocol version in HELLO (mismatch tests)
    overcurrent_limit: float | None = None   #: A: a motor current above this latches OVERCURRENT
    undervoltage_limit: float | None = None  #: V: battery voltage below this latches UNDERVOLTAGE
    driver_fault_at: float | None = None     #: board time at which the motor driver reports a fault


@dataclass(frozen=True)
class World:
    """Everything the simulated board needs: robot, operator setup, sensors, faults, clock."""

    robot_file: str | None = None        #: robot TOML (None: the default Omnibot)
    mode: str = "ground"                 #: "ground" or "upside_down"
    payload: float = 0.0                 #: kg on top of the robot
    wheel_mass: tuple[float, float, float, float] | None = None  #: kg per wheel (None: the robot's)
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)  #: undeclared effects
    sensors: SensorConfig = SensorConfig()
    faults: FaultConfig = FaultConfig()
    seed: int = 0                        #: seeds sensor noise, faults and the boot ids
    clock: str = "fast"                  #: "fast" (as fast as the host reads) or "realtime"
    speed: float = 1.0                   #: realtime clock: simulated seconds per wall second
    dt: float = 1e-3                     #: physics step, s
    board_id: int = 0x0B0B0001           #: reported in HELLO
    firmware_version: tuple[int, int, int] = (1, 0, 0)
    protocol: str = "omnibot-board-v2"   #: protocol description (name in protocols/ or path)
    baudrate: int = 115200               #: the board's UART speed; a host at another speed reads noise
    name: str | None = None              #: registry name, so `sim://ammeter?board=NAME` finds it
    plant: str = "model"                 #: "model" (omnibench.model) or "independent" (omnibench.worlds.independent)
    #: mis-wiring: board motor channel k (FL FR RL RR order) drives wheel |wiring[k]| (1-based),
    #: reversed when negative; its current sensor follows the motor
    wiring: tuple[int, int, int, int] = (1, 2, 3, 4)
    #: board encoder channel k reads wheel |encoder_wiring[k]|, counting backwards when negative
    #: (None: the same as `wiring`, i.e. the encoder travels with its motor's connector)
    encoder_wiring: tuple[int, int, int, int] | None = None
    #: "firmware" (the default: the board behaves as the firmware it stands in for): duties
    #: rounded and delayed per wheel as the firmware's drivers take them; "ideal": exact and
    #: instantaneous, for model-only studies (ACTUATIONS)
    actuation: str = "firmware"

    def robot(self):  # -> omnibench.model.Robot
        """The Robot this world simulates (default Omnibot or `robot_file`)."""
        from omnibench.model import default_robot, load_robot

        return load_robot(self.robot_file) if self.robot_file else default_robot()

    def scenario(self):  # -> omnibench.model.Scenario
        """The model Scenario for the current operator setup and hidden effects."""
        from omnibench.model import Scenario

        delays = None
        if self.actuation == "firmware":
            from omnibench.model.actuation import wheel_delays

            delays = tuple(wheel_delays())
        return Scenario(mode=self.mode, payload=self.payload, wheel_mass=self.wheel_mass,
                        effects={k: dict(v) for k, v in self.effects.items()}, command_delays=delays)


def _float(v: Any, what: str) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise UserError(f"{what} must be a number, not {v!r}") from None
    if not math.isfinite(x):
        raise UserError(f"{what} must be a finite number, not {v!r}")
    return x


def _bool(v: Any, what: str) -> bool:
    if isinstance(v, bool):
        return v
    s = str(v).strip().lower()
    if s in ("1", "true", "yes", "on", ""):
        return True
    if s in ("0", "false", "no", "off"):
        return False
    raise UserError(f"{what} must be true or false, not {v!r}")


def _rate(v: Any, what: str) -> float:
    x = _float(v, what)
    if not 0.0 <= x <= 1.0:
        raise UserError(f"{what} is a probability per byte: use a number in 0..1, not {v!r}")
    return x


_SENSOR_KEYS = {f.name for f in fields(SensorConfig)}
_FAULT_KEYS = {f.name for f in fields(FaultConfig)}


def _known_settings_hint(name: str) -> str:
    """'did you mean X?' for a mistyped simulator setting, else the settings it knows."""
    import difflib

    known = sorted({f.name for f in fields(World)} | _SENSOR_KEYS | _FAULT_KEYS | {"world", "baudrate"})
    close = difflib.get_close_matches(name, known, n=1)
    return f"did you mean {close[0]!r}?" if close else f"known: {', '.join(known)}"


def _sensors(base: SensorConfig, d: Mapping[str, Any], where: str) -> SensorConfig:
    changes: dict[str, Any] = {}
    for k, v in d.items():
        if k not in _SENSOR_KEYS:
            raise UserError(f"{where}: unknown sensor setting {k!r}; known: {', '.join(sorted(_SENSOR_KEYS))}")
        if k.endswith("_sensor"):
            changes[k] = _bool(v, f"{where} {k}")
        else:
            x = _float(v, f"{where} {k}")
            if x < 0:
                raise UserError(f"{where}: {k} must not be negative")
            changes[k] = x
    return replace(base, **changes)


def _faults(base: FaultConfig, d: Mapping[str, Any], where: str) -> FaultConfig:
    changes: dict[str, Any] = {}
    for k, v in d.items():
        if k not in _FAULT_KEYS:
            raise UserError(f"{where}: unknown fault {k!r}; known: {', '.join(sorted(_FAULT_KEYS))}")
        if k in ("drop", "corrupt", "garbage"):
            changes[k] = _rate(v, f"{where} {k}")
        elif k == "direction":
            if v not in ("both", "to_host", "to_board"):
                raise UserError(f"{where}: direction must be both, to_host or to_board, not {v!r}")
            changes[k] = v
        elif k in ("disconnect_at", "reset_at", "driver_fault_at"):
            x = _float(v, f"{where} {k}")
            if x < 0:
                raise UserError(f"{where}: {k} is a board time in s and must not be negative")
            changes[k] = x
        elif k in ("overcurrent_limit", "undervoltage_limit"):
            x = _float(v, f"{where} {k}")
            if x <= 0:
                raise UserError(f"{where}: {k} must be positive ({'A' if k == 'overcurrent_limit' else 'V'})")
            changes[k] = x
        elif k == "wrong_baud":
            changes[k] = _bool(v, f"{where} {k}")
        elif k == "protocol_version":
            changes[k] = int(_float(v, f"{where} {k}"))
        else:  # pragma: no cover - a FaultConfig field without its parser
            raise AssertionError(f"fault setting {k!r} has no parser")
    return replace(base, **changes)


MAX_PAYLOAD_KG = 1000.0  #: heaviest payload a world may put on the robot
MAX_SPEED = 1000.0       #: fastest realtime clock (simulated s per wall s)


def _apply(world: World, d: Mapping[str, Any], where: str, base_dir: Path | None) -> World:
    """World with the settings in `d` (from a file or a URL) applied."""
    changes: dict[str, Any] = {}
    for k, v in d.items():
        if k == "robot":
            p = Path(str(v))
            if base_dir is not None and not p.is_absolute():
                p = base_dir / p
            changes["robot_file"] = str(p)
        elif k == "mode":
            if v not in MODES:
                raise UserError(f"{where}: mode must be ground or upside_down, not {v!r}")
            changes["mode"] = v
        elif k == "payload":
            x = _float(v, f"{where} payload")
            if not 0 <= x <= MAX_PAYLOAD_KG:
                raise UserError(f"{where}: payload must be a mass in [0, {MAX_PAYLOAD_KG:g}] kg, not {x:g}")
            changes["payload"] = x
        elif k == "wheel_mass":
            vals = v if isinstance(v, (list, tuple)) else str(v).split(",")
            masses = tuple(_float(x, f"{where} wheel_mass") for x in vals)
            if len(masses) != 4 or min(masses) <= 0:
                raise UserError(f"{where}: wheel_mass needs 4 positive masses in kg (FL, FR, RL, RR)")
            changes["wheel_mass"] = masses
        elif k == "effects":
            if not isinstance(v, Mapping) or not all(isinstance(p, Mapping) for p in v.values()):
                raise UserError(f"{where}: [effects] must be tables {{effect name: {{param: value}}}}")
            from omnibench.effects.library import EFFECTS, effect_names

            unknown = [n for n in v if n not in effect_names()]
            if unknown:
                raise UserError(f"{where}: unknown effect {unknown[0]!r}; known: {', '.join(effect_names())}")
            for n, p in v.items():
                known = set(EFFECTS[n].term.defaults())
                bad = sorted(set(p) - known)
                if bad:
                    raise UserError(f"{where}: effect {n} has no parameter {bad[0]!r}; "
                                    f"it has {', '.join(sorted(known))}")
            changes["effects"] = {n: {pk: _float(pv, f"{where} effects.{n}.{pk}") for pk, pv in p.items()}
                                  for n, p in v.items()}
        elif k == "sensors":
            changes["sensors"] = _sensors(world.sensors, v, where)
        elif k == "faults":
            changes["faults"] = _faults(world.faults, v, where)
        elif k == "seed":
            x = _float(v, f"{where} seed")
            if x != int(x):
                raise UserError(f"{where}: seed must be a whole number, not {v!r}")
            changes["seed"] = int(x)
        elif k == "clock":
            if v not in CLOCKS:
                raise UserError(f"{where}: clock must be fast or realtime, not {v!r}")
            changes["clock"] = v
        elif k == "speed":
            x = _float(v, f"{where} speed")
            if not 0 < x <= MAX_SPEED:
                raise UserError(f"{where}: speed must be in (0, {MAX_SPEED:g}] simulated s per wall s, not {x:g}")
            changes["speed"] = x
        elif k == "dt":
            x = _float(v, f"{where} dt")
            if not 1e-5 <= x <= 0.01:
                raise UserError(f"{where}: dt must be between 1e-5 and 0.01 s")
            changes["dt"] = x
        elif k == "board_id":
            changes["board_id"] = int(_float(v, f"{where} board_id")) & 0xFFFFFFFF
        elif k == "firmware_version":
            vals = v if isinstance(v, (list, tuple)) else str(v).split(".")
            changes["firmware_version"] = tuple(int(x) for x in vals)
        elif k == "plant":
            if v not in PLANTS:
                raise UserError(f"{where}: plant must be model or independent, not {v!r}")
            changes["plant"] = v
        elif k == "actuation":
            if v not in ACTUATIONS:
                raise UserError(f"{where}: actuation must be firmware or ideal, not {v!r}")
            changes["actuation"] = v
        elif k in ("protocol", "name"):
            changes[k] = str(v)
        elif k in ("wiring", "encoder_wiring"):
            vals = v if isinstance(v, (list, tuple)) else str(v).split(",")
            try:
                w = tuple(int(str(x).strip()) for x in vals)
            except ValueError:
                raise UserError(f"{where}: {k} needs four signed wheel numbers, e.g. 2,1,3,-4") from None
            if len(w) != 4 or sorted(abs(x) for x in w) != [1, 2, 3, 4]:
                raise UserError(f"{where}: {k} must name each wheel 1-4 once (negative: reversed), e.g. 2,1,3,-4")
            changes[k] = w
        elif k == "baudrate":
            changes["baudrate"] = int(_float(v, f"{where} baudrate"))
        else:
            raise UserError(f"{where}: unknown setting {k!r}; {_known_settings_hint(k)} (see docs/simulator.md)")
    return replace(world, **changes)


def load_world(path: str | Path, base: World | None = None) -> World:
    """Read a world file (TOML); UserError naming the file and the problem."""
    p = Path(path)
    from omnibench.files import read_toml

    doc, _ = read_toml(p, "world file")
    return _apply(base or World(), doc, f"world file {p}", p.parent)


def world_from_url(url: str) -> tuple[str, World, dict[str, str]]:
    """Parse `sim://[omnibot|ammeter]?k=v&...`: returns (device, World, ammeter options).

    `world=FILE` is read first; other parameters override it. Fault parameters may be
    given bare (`drop=0.01`) or with a prefix (`faults.drop=0.01`), sensor settings as
    `sensors.current_noise=0.02`, effects as `effects.NAME.PARAM=value`.
    """
    parts = urlsplit(url)
    if parts.scheme.lower() != "sim":
        raise UserError(f"{url}: not a sim:// URL")
    device = (parts.netloc or parts.path.strip("/") or "omnibot").lower()
    query = {k: v[-1] for k, v in parse_qs(parts.query, keep_blank_values=True).items()}
    world = World()
    if "world" in query:
        world = load_world(query.pop("world"))
    flat: dict[str, Any] = {}
    faults: dict[str, Any] = {}
    sensors: dict[str, Any] = {}
    effects: dict[str, dict[str, Any]] = {k: dict(v) for k, v in world.effects.items()}
    extra: dict[str, str] = {}
    for k, v in query.items():
        if k.startswith("faults."):
            faults[k[7:]] = v
        elif k in _FAULT_KEYS:
            faults[k] = v
        elif k.startswith("sensors."):
            sensors[k[8:]] = v
        elif k in _SENSOR_KEYS:
            sensors[k] = v
        elif k.startswith("effects."):
            name, _, param = k[8:].partition(".")
            if not param:
                raise UserError(f"{url}: write effects as effects.NAME.PARAM=value, not {k!r}")
            effects.setdefault(name, {})[param] = v
        elif device == "ammeter" and k in ("board", "noise", "lsb", "seed"):
            extra[k] = v
        else:
            flat[k] = v
    if faults:
        flat["faults"] = faults
    if sensors:
        flat["sensors"] = sensors
    if effects != world.effects:
        flat["effects"] = effects
    if device not in ("omnibot", "ammeter"):
        raise UserError(f"{url}: unknown simulated device {device!r}; use sim://omnibot or sim://ammeter")
    return device, _apply(world, flat, url, None), extra
