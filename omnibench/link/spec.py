"""The board protocol as data: load a `protocols/*.toml` description into typed objects.

The same `ProtocolSpec` builds the host codec and the simulated board's codec, so a
different firmware is supported by writing a new description file, not new code.
See protocols/omnibot-board-v2.toml for the schema and docs/protocol.md for the prose.
"""

from __future__ import annotations

import struct
import tomllib
from dataclasses import dataclass, field
from fractions import Fraction
from functools import cached_property
from pathlib import Path

from omnibench.errors import UserError
from omnibench.resources import data_dir

#: struct format character and size of each wire type (all little-endian).
WIRE_TYPES: dict[str, tuple[str, int]] = {
    "u8": ("B", 1),
    "i8": ("b", 1),
    "u16": ("H", 2),
    "i16": ("h", 2),
    "u32": ("I", 4),
    "i32": ("i", 4),
}

DEFAULT_PROTOCOL = "omnibot-board-v2"


@dataclass(frozen=True)
class FieldSpec:
    """One field of a message: `count` consecutive values of wire `type`.

    physical value = raw integer * `scale` (in `unit`, SI). `scale` None means the raw
    integer is the value (ids, counts, flags, enums).
    """

    name: str
    type: str
    count: int = 1
    scale: float | None = None
    unit: str = ""
    enum: str | None = None
    flags: str | None = None
    min: int | None = None
    max: int | None = None
    doc: str = ""

    @property
    def size(self) -> int:
        """Bytes on the (decoded) wire."""
        return WIRE_TYPES[self.type][1] * self.count

    @property
    def raw_range(self) -> tuple[int, int]:
        """Smallest and largest raw integer the field accepts."""
        fmt, size = WIRE_TYPES[self.type]
        if fmt.isupper():
            lo, hi = 0, 2 ** (8 * size) - 1
        else:
            lo, hi = -(2 ** (8 * size - 1)), 2 ** (8 * size - 1) - 1
        if self.min is not None:
            lo = max(lo, self.min)
        if self.max is not None:
            hi = min(hi, self.max)
        return lo, hi


@dataclass(frozen=True)
class MessageSpec:
    """One message: id, direction and the ordered fields of its payload."""

    name: str
    id: int
    direction: str
    fields: tuple[FieldSpec, ...]
    sim_only: bool = False
    reply: str | None = None
    doc: str = ""

    @cached_property
    def struct(self) -> struct.Struct:
        """Little-endian struct of the payload (no header, no CRC)."""
        return struct.Struct("<" + "".join(f"{f.count}{WIRE_TYPES[f.type][0]}" for f in self.fields))

    @property
    def payload_size(self) -> int:
        """Payload bytes (between header and CRC)."""
        return self.struct.size


@dataclass(frozen=True)
class CrcSpec:
    """A CRC variant by catalogue name and parameters (Rocksoft model) with its check value."""

    name: str
    width: int
    poly: int
    init: int
    refin: bool
    refout: bool
    xorout: int
    check: int


@dataclass(frozen=True)
class ProtocolSpec:
    """A whole protocol description: framing, CRC, enums, flags and messages."""

    name: str
    version: int
    path: Path
    crc: CrcSpec
    header: tuple[FieldSpec, ...]
    max_frame_bytes: int
    messages: tuple[MessageSpec, ...]
    enums: dict[str, dict[str, int]] = field(default_factory=dict)
    flags: dict[str, dict[str, int]] = field(default_factory=dict)
    board: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_by_name", {m.name: m for m in self.messages})
        object.__setattr__(self, "_by_id", {m.id: m for m in self.messages})

    def message(self, name: str) -> MessageSpec:
        """The message called `name` (KeyError if this protocol has none)."""
        return self._by_name[name]  # type: ignore[attr-defined]

    def by_id(self, msg_id: int) -> MessageSpec | None:
        """The message with id `msg_id`, or None if unknown."""
        return self._by_id.get(msg_id)  # type: ignore[attr-defined]

    def has(self, name: str) -> bool:
        """True if the protocol defines a message called `name`."""
        return name in self._by_name  # type: ignore[attr-defined]

    @cached_property
    def header_struct(self) -> struct.Struct:
        """Little-endian struct of the frame header (msg_id, seq)."""
        return struct.Struct("<" + "".join(WIRE_TYPES[f.type][0] for f in self.header))

    def enum_name(self, enum: str, value: int) -> str:
        """Name of `value` in enum table `enum` (or the number as text if unknown)."""
        for k, v in self.enums.get(enum, {}).items():
            if v == value:
                return k
        return str(value)

    def flag_names(self, flags: str, value: int) -> list[str]:
        """Names of the bits set in `value` according to flag table `flags`."""
        table = self.flags.get(flags, {})
        names = [k for k, bit in table.items() if value & (1 << bit)]
        known = sum(1 << b for b in table.values())
        if value & ~known:
            names.append(f"0x{value & ~known:x}")
        return names

    def flag_mask(self, flags: str, *names: str) -> int:
        """Integer with the named bits of flag table `flags` set."""
        return sum(1 << self.flags[flags][n] for n in names)


def _scale(value: object, where: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, str):
        try:
            return float(Fraction(value))
        except (ValueError, ZeroDivisionError) as exc:
            raise UserError(f"{where}: scale {value!r} is not a number or a fraction like '1/32767'") from exc
    if isinstance(value, (int, float)):
        return float(value)
    raise UserError(f"{where}: scale must be a number or a string like '1/32767'")


def _field(raw: dict, where: str) -> FieldSpec:
    try:
        name, typ = raw["name"], raw["type"]
    except KeyError as exc:
        raise UserError(f"{where}: every field needs a name and a type") from exc
    if typ not in WIRE_TYPES:
        raise UserError(f"{where}: field {name!r} has type {typ!r}; use one of {', '.join(WIRE_TYPES)}")
    count = int(raw.get("count", 1))
    if count < 1:
        raise UserError(f"{where}: field {name!r} needs count >= 1")
    return FieldSpec(
        name=name,
        type=typ,
        count=count,
        scale=_scale(raw.get("scale"), f"{where} field {name!r}"),
        unit=str(raw.get("unit", "")),
        enum=raw.get("enum"),
        flags=raw.get("flags"),
        min=raw.get("min"),
        max=raw.get("max"),
        doc=str(raw.get("doc", "")),
    )


def load_protocol(name_or_path: str | Path = DEFAULT_PROTOCOL) -> ProtocolSpec:
    """Load a protocol description by name (a file in `protocols/`) or by path.

    Raises UserError naming the file and the problem if it is missing or malformed.
    """
    path = Path(name_or_path)
    if not path.suffix:
        path = data_dir("protocols") / f"{name_or_path}.toml"
    where = str(path)
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError as exc:
        raise UserError(f"protocol description {where} not found") from exc
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"protocol description {where} is not valid TOML: {exc}") from exc
    try:
        proto, framing, crc = doc["protocol"], doc["framing"], doc["crc"]
        if proto.get("byte_order", "little") != "little":
            raise UserError(f"{where}: only byte_order = 'little' is supported")
        if framing.get("encoding", "COBS").upper() != "COBS" or framing.get("delimiter", 0) != 0:
            raise UserError(f"{where}: only COBS framing with a 0x00 delimiter is supported")
        crc_spec = CrcSpec(
            name=str(crc["name"]),
            width=int(crc["width"]),
            poly=int(crc["poly"]),
            init=int(crc["init"]),
            refin=bool(crc["refin"]),
            refout=bool(crc["refout"]),
            xorout=int(crc["xorout"]),
            check=int(crc["check"]),
        )
        if crc_spec.width not in (8, 16, 32):
            raise UserError(f"{where}: CRC width must be 8, 16 or 32")
        header = tuple(_field(f, f"{where} [framing].header") for f in framing["header"])
        if [f.name for f in header] != ["msg_id", "seq"]:
            raise UserError(f"{where}: [framing].header must be the fields msg_id then seq")
        messages = []
        for m in doc.get("message", []):
            mw = f"{where} message {m.get('name', '?')!r}"
            direction = m.get("direction")
            if direction not in ("host_to_board", "board_to_host"):
                raise UserError(f"{mw}: direction must be host_to_board or board_to_host")
            messages.append(
                MessageSpec(
                    name=str(m["name"]),
                    id=int(m["id"]),
                    direction=direction,
                    fields=tuple(_field(f, mw) for f in m.get("fields", [])),
                    sim_only=bool(m.get("sim_only", False)),
                    reply=m.get("reply"),
                    doc=str(m.get("doc", "")),
                )
            )
    except KeyError as exc:
        raise UserError(f"protocol description {where} lacks {exc.args[0]!r}") from exc
    ids = [m.id for m in messages]
    if len(set(ids)) != len(ids):
        raise UserError(f"{where}: two messages share an id")
    names = {m.name for m in messages}
    for m in messages:
        if m.reply is not None and m.reply not in names:
            raise UserError(f"{where}: message {m.name!r} replies with unknown {m.reply!r}")
    spec = ProtocolSpec(
        name=str(proto["name"]),
        version=int(proto["version"]),
        path=path,
        crc=crc_spec,
        header=header,
        max_frame_bytes=int(framing.get("max_frame_bytes", 254)),
        messages=tuple(messages),
        enums={k: dict(v) for k, v in doc.get("enums", {}).items()},
        flags={k: dict(v) for k, v in doc.get("flags", {}).items()},
        board=dict(doc.get("board", {})),
    )
    return spec
