"""docs/protocol.md and docs/simulator.md stay in step with the description and the code."""

from __future__ import annotations

import re
from dataclasses import fields
from pathlib import Path

from omnibench.link.codec import Codec
from omnibench.link.spec import WIRE_TYPES, load_protocol
from omnibench.sim.world import FaultConfig, SensorConfig

DOCS = Path(__file__).resolve().parents[2] / "docs"
SPEC = load_protocol()


def test_protocol_doc_has_every_message_with_its_layout() -> None:
    text = (DOCS / "protocol.md").read_text()
    assert SPEC.crc.name in text and f"0x{SPEC.crc.check:X}" in text
    codec = Codec(SPEC)
    for m in SPEC.messages:
        section = text.split(f"### 0x{m.id:02X} {m.name}", 1)
        assert len(section) == 2, f"{m.name} missing from docs/protocol.md"
        body = section[1].split("\n### ", 1)[0]
        assert f"Payload {m.payload_size} bytes" in body and f"{codec.wire_size(m.name)} bytes on the wire" in body
        offsets = [int(x) for x in re.findall(r"^\| (\d+) \|", body, flags=re.M)]
        expected, off = [], 0
        for f in m.fields:
            for _ in range(f.count):
                expected.append(off)
                off += WIRE_TYPES[f.type][1]
        assert offsets == expected, m.name
    for table in ("status", "event"):
        for name, value in SPEC.enums[table].items():
            assert f"| {value} | {name} |" in text


def test_simulator_doc_lists_every_setting() -> None:
    text = (DOCS / "simulator.md").read_text()
    for f in fields(SensorConfig) + fields(FaultConfig):
        assert f.name in text, f.name
    for key in ("world", "seed", "clock", "speed", "name", "robot", "mode", "payload", "wheel_mass", "effects."):
        assert f"`{key}" in text, key
