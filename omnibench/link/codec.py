"""Codec built from a protocol description: messages <-> frame bodies <-> wire bytes.

Host and simulated board both use `Codec`; only the direction they send in differs.
Values are physical (SI, after `scale`) in `encode`/`decode`, raw integers in
`encode_raw`/`decode_raw` (used by the test vectors, which must be exact).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from omnibench.link.framing import Crc, Deframer, FrameError, encode_frame
from omnibench.link.spec import MessageSpec, ProtocolSpec, load_protocol


class CodecError(ValueError):
    """A message that cannot be encoded (unknown name, missing field, value out of range)."""


@dataclass
class Message:
    """A decoded message: its name, the sender's frame sequence number and its fields.

    `fields` maps field name to a value (float for scaled fields, int otherwise) or, for
    fields with count > 1, a tuple of values.
    """

    name: str
    seq: int
    fields: dict[str, Any] = field(default_factory=dict)
    msg_id: int = 0

    def __getitem__(self, key: str) -> Any:
        return self.fields[key]


class Codec:
    """Encode and decode the messages of one protocol description.

    Build it once per link: `Codec(load_protocol("omnibot-board-v2"))`.
    """

    def __init__(self, spec: ProtocolSpec | None = None) -> None:
        self.spec = spec or load_protocol()
        self.crc = Crc(self.spec.crc)
        self._header = self.spec.header_struct

    # ------------------------------------------------------------------ raw level
    def encode_raw(self, name: str, seq: int, raw: Mapping[str, Any]) -> bytes:
        """Frame body (header + payload, no CRC) from raw integer field values."""
        m = self._message(name)
        flat: list[int] = []
        for f in m.fields:
            if f.name not in raw:
                raise CodecError(f"{name}: field {f.name!r} missing")
            vals = raw[f.name]
            vals = list(vals) if f.count > 1 else [vals]
            if len(vals) != f.count:
                raise CodecError(f"{name}.{f.name}: needs {f.count} values, got {len(vals)}")
            lo, hi = f.raw_range
            for v in vals:
                iv = int(v)
                if iv != v or not lo <= iv <= hi:
                    raise CodecError(f"{name}.{f.name}: raw value {v!r} outside {lo}..{hi}")
                flat.append(iv)
        return self._header.pack(m.id, seq & 0xFFFF) + m.struct.pack(*flat)

    def decode_raw(self, body: bytes) -> Message:
        """Message with raw integer field values from a frame body (FrameError if malformed)."""
        if len(body) < self._header.size:
            raise FrameError("frame shorter than its header")
        msg_id, seq = self._header.unpack_from(body)
        m = self.spec.by_id(msg_id)
        if m is None:
            raise FrameError(f"unknown message id 0x{msg_id:02X}")
        payload = body[self._header.size :]
        if len(payload) != m.payload_size:
            raise FrameError(f"{m.name}: payload is {len(payload)} bytes, layout says {m.payload_size}")
        flat = m.struct.unpack(payload)
        fields: dict[str, Any] = {}
        i = 0
        for f in m.fields:
            vals = flat[i : i + f.count]
            i += f.count
            fields[f.name] = tuple(vals) if f.count > 1 else vals[0]
        return Message(m.name, seq, fields, msg_id)

    # ------------------------------------------------------------------ physical level
    def to_raw(self, name: str, values: Mapping[str, Any]) -> dict[str, Any]:
        """Physical field values (SI) to raw integers, rounding to the field's resolution."""
        m = self._message(name)
        raw: dict[str, Any] = {}
        for f in m.fields:
            if f.name not in values:
                raise CodecError(f"{name}: field {f.name!r} missing")
            v = values[f.name]
            vals = list(v) if f.count > 1 else [v]
            conv = []
            for x in vals:
                if f.scale is None:
                    conv.append(int(x))
                else:
                    xf = float(x)
                    if not math.isfinite(xf):
                        raise CodecError(f"{name}.{f.name}: {x!r} is not a finite number")
                    conv.append(int(round(xf / f.scale)))
            raw[f.name] = conv if f.count > 1 else conv[0]
        return raw

    def from_raw(self, msg: Message) -> Message:
        """Raw message to physical values (SI): raw * scale for scaled fields."""
        m = self._message(msg.name)
        out: dict[str, Any] = {}
        for f in m.fields:
            v = msg.fields[f.name]
            if f.scale is None:
                out[f.name] = v
            elif f.count > 1:
                out[f.name] = tuple(x * f.scale for x in v)
            else:
                out[f.name] = v * f.scale
        return Message(msg.name, msg.seq, out, msg.msg_id)

    def encode(self, name: str, seq: int, values: Mapping[str, Any] | None = None) -> bytes:
        """Frame body from physical values (CodecError if a value is out of range)."""
        return self.encode_raw(name, seq, self.to_raw(name, values or {}))

    def decode(self, body: bytes) -> Message:
        """Physical message from a frame body (FrameError if malformed)."""
        return self.from_raw(self.decode_raw(body))

    # ------------------------------------------------------------------ wire level
    def frame(self, name: str, seq: int, values: Mapping[str, Any] | None = None) -> bytes:
        """Wire bytes (COBS + CRC + delimiter) of a message with physical values."""
        return encode_frame(self.encode(name, seq, values), self.crc)

    def frame_raw(self, name: str, seq: int, raw: Mapping[str, Any]) -> bytes:
        """Wire bytes of a message with raw integer values."""
        return encode_frame(self.encode_raw(name, seq, raw), self.crc)

    def deframer(self) -> Deframer:
        """A fresh stream splitter for this protocol's CRC and frame size limit."""
        sizes = {self._header.size + m.payload_size + self.crc.size for m in self.spec.messages}
        return Deframer(self.crc, self.spec.max_frame_bytes, sizes)

    def wire_size(self, name: str) -> int:
        """Bytes on the wire of one `name` frame (worst case COBS overhead + delimiter)."""
        n = self._header.size + self._message(name).payload_size + self.crc.size
        return n + (n + 253) // 254 + 1

    def _message(self, name: str) -> MessageSpec:
        try:
            return self.spec.message(name)
        except KeyError:
            raise CodecError(f"protocol {self.spec.name} v{self.spec.version} has no message {name!r}") from None
