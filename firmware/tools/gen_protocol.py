#!/usr/bin/env python3
"""Generate the firmware's C header from the protocol description (protocols/*.toml).

One description drives host codec, simulated board and firmware: this script turns it into
`protocol_gen.h` (message ids, enums, flags, payload sizes, packed structs with pack/unpack
functions, field limits and scales, CRC parameters, board constants). A protocol change is a
regeneration, not an edit of C code; a change the firmware's logic depends on (a renamed
field) shows up as a compile error that names it.

Usage: gen_protocol.py PROTOCOL OUT.h
PROTOCOL is a .toml file or a folder: from a folder, the description with the highest
[protocol].version among `*.toml` is used (so a new `omnibot-board-v2.toml` is picked up).
Standard library only (Python >= 3.11), so `make` needs no virtualenv.
"""

from __future__ import annotations

import sys
import tomllib
from fractions import Fraction
from pathlib import Path

#: C type, byte size and wire accessor suffix of each description type.
C_TYPES = {
    "u8": ("uint8_t", 1), "i8": ("int8_t", 1),
    "u16": ("uint16_t", 2), "i16": ("int16_t", 2),
    "u32": ("uint32_t", 4), "i32": ("int32_t", 4),
}
HEADER = [("msg_id", "u8"), ("seq", "u16")]  # never changes between versions (docs/protocol.md)


def load(path: Path) -> dict:
    """The description as a dict; a clear one-line exit if it is not valid TOML."""
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        sys.exit(f"gen_protocol: {path}: {exc}")


def pick_description(path: Path) -> Path:
    """The .toml itself, or the highest-version description in a folder."""
    if path.is_file():
        return path
    found = []
    for p in sorted(path.glob("*.toml")):
        found.append((int(load(p)["protocol"]["version"]), p))
    if not found:
        sys.exit(f"gen_protocol: no protocol description (*.toml) in {path}")
    return max(found)[1]


def scale_of(value: object) -> Fraction | None:
    """The description's scale as an exact fraction ("1/32767", 0.001, 1e-6; None = raw)."""
    if value is None:
        return None
    if isinstance(value, str):
        num, _, den = value.partition("/")
        return Fraction(int(num), int(den or 1))
    return Fraction(str(value))


def ident(name: str) -> str:
    return name.upper().replace("-", "_")


def field_lines(msg: str, field: dict) -> list[str]:
    """#defines of one field: limits and scale."""
    out = []
    pre = f"MSG_{ident(msg)}_{ident(field['name'])}"
    if "min" in field:
        out.append(f"#define {pre}_MIN ({int(field['min'])})")
    if "max" in field:
        out.append(f"#define {pre}_MAX ({int(field['max'])})")
    s = scale_of(field.get("scale"))
    if s is not None:
        out.append(f"#define {pre}_SCALE ({float(s)!r})  /* physical = raw * scale, {field.get('unit', '')} */")
        if (1 / s).denominator == 1:
            out.append(f"#define {pre}_PER_UNIT ({(1 / s).numerator}L)  /* raw per {field.get('unit', '')} */")
    return out


def pack_functions(msg: dict) -> list[str]:
    """Struct typedef and inline pack/unpack (byte by byte, little-endian, no padding)."""
    lname = msg["name"].lower()
    fields = msg.get("fields", [])
    out = []
    if fields:
        out.append("typedef struct {")
        for f in fields:
            ctype, _ = C_TYPES[f["type"]]
            n = int(f.get("count", 1))
            out.append(f"    {ctype} {f['name']}{f'[{n}]' if n > 1 else ''};")
        out.append(f"}} msg_{lname}_t;")
    else:
        out.append(f"typedef struct {{ uint8_t unused; }} msg_{lname}_t;  /* no payload */")
    pack = [f"static inline void msg_{lname}_pack(uint8_t *p, const msg_{lname}_t *m) {{"]
    unpack = [f"static inline void msg_{lname}_unpack(const uint8_t *p, msg_{lname}_t *m) {{"]
    off = 0
    for f in fields:
        ctype, size = C_TYPES[f["type"]]
        for i in range(int(f.get("count", 1))):
            ref = f"m->{f['name']}" + (f"[{i}]" if int(f.get("count", 1)) > 1 else "")
            pack.append(f"    wire_put_{f['type']}(p + {off}, {ref});")
            unpack.append(f"    {ref} = wire_get_{f['type']}(p + {off});")
            off += size
    if not fields:
        pack.append("    (void)p; (void)m;")
        unpack.append("    (void)p; (void)m;")
    return out + pack + ["}"] + unpack + ["}"]


def payload_size(msg: dict) -> int:
    return sum(C_TYPES[f["type"]][1] * int(f.get("count", 1)) for f in msg.get("fields", []))


def test_helpers(messages: list[dict]) -> list[str]:
    """Host-only: pack/unpack any message from/to a flat list of integers (for the vector test)."""
    out = ["#ifdef PROTO_TEST_HELPERS",
           "/* Pack flat raw values (field order, arrays expanded) with the typed packer; returns the payload size or -1. */",
           "static inline int proto_test_pack(uint8_t id, const long long *v, uint8_t *p) {",
           "    switch (id) {"]
    for m in messages:
        lname = m["name"].lower()
        out.append(f"    case MSG_{ident(m['name'])}: {{ msg_{lname}_t m; int k = 0; (void)k; (void)v;")
        for f in m.get("fields", []):
            n = int(f.get("count", 1))
            for i in range(n):
                ref = f"m.{f['name']}" + (f"[{i}]" if n > 1 else "")
                out.append(f"        {ref} = ({C_TYPES[f['type']][0]})v[k++];")
        if not m.get("fields"):
            out.append("        m.unused = 0;")
        out.append(f"        msg_{lname}_pack(p, &m); return MSG_{ident(m['name'])}_SIZE; }}")
    out += ["    default: return -1;", "    }", "}",
            "/* Unpack a payload into flat raw values with the typed unpacker; returns the count or -1. */",
            "static inline int proto_test_unpack(uint8_t id, const uint8_t *p, long long *v) {",
            "    switch (id) {"]
    for m in messages:
        lname = m["name"].lower()
        out.append(f"    case MSG_{ident(m['name'])}: {{ msg_{lname}_t m; int k = 0; (void)v;")
        out.append(f"        msg_{lname}_unpack(p, &m);")
        for f in m.get("fields", []):
            n = int(f.get("count", 1))
            for i in range(n):
                ref = f"m.{f['name']}" + (f"[{i}]" if n > 1 else "")
                out.append(f"        v[k++] = {ref};")
        out.append("        return k; }")
    out += ["    default: return -1;", "    }", "}", "#endif /* PROTO_TEST_HELPERS */"]
    return out


def generate(desc_path: Path) -> str:
    d = load(desc_path)
    header = [(h["name"], h["type"]) for h in d["framing"]["header"]]
    if header != HEADER:
        sys.exit(f"gen_protocol: {desc_path.name}: header must be {HEADER} (docs/protocol.md, Versioning)")
    crc = d["crc"]
    width = int(crc["width"])
    if width not in (8, 16, 32):
        sys.exit(f"gen_protocol: {desc_path.name}: CRC width {width} is not supported (8, 16 or 32)")
    board = d.get("board", {})
    L = [f"/* Generated by firmware/tools/gen_protocol.py from protocols/{desc_path.name}. Do not edit:",
         "   change the description and run make. */",
         "#ifndef PROTOCOL_GEN_H", "#define PROTOCOL_GEN_H", "",
         "#include <stdint.h>", '#include "wire.h"', "",
         f'#define PROTO_NAME "{d["protocol"]["name"]}"',
         f'#define PROTO_FILE "{desc_path.name}"',
         f"#define PROTO_VERSION {int(d['protocol']['version'])}",
         f"#define PROTO_MAX_FRAME {int(d['framing']['max_frame_bytes'])}  /* decoded bytes: header + payload + CRC */",
         "#define PROTO_HEADER_SIZE 3  /* msg_id u8, seq u16 */", "",
         f"/* {crc.get('name', 'CRC')}: {crc.get('covers', '')} */",
         f"#define PROTO_CRC_WIDTH {width}",
         f"#define PROTO_CRC_BYTES {width // 8}",
         f"#define PROTO_CRC_POLY 0x{int(crc['poly']):X}UL",
         f"#define PROTO_CRC_INIT 0x{int(crc['init']):X}UL",
         f"#define PROTO_CRC_REFIN {int(bool(crc['refin']))}",
         f"#define PROTO_CRC_REFOUT {int(bool(crc['refout']))}",
         f"#define PROTO_CRC_XOROUT 0x{int(crc['xorout']):X}UL",
         f"#define PROTO_CRC_CHECK 0x{int(crc['check']):X}UL  /* CRC of ASCII 123456789 */",
         f"#define PROTO_CRC_LITTLE_ENDIAN {int(crc.get('byte_order', 'little') == 'little')}", "",
         f"#define PROTO_BAUDRATE {int(board.get('baudrate', 115200))}UL",
         f"#define PROTO_DEFAULT_WATCHDOG_MS {round(float(board.get('default_watchdog_s', 0.5)) * 1000)}",
         f"#define PROTO_MIN_WATCHDOG_MS {round(float(board.get('min_watchdog_s', 0.02)) * 1000)}",
         f"#define PROTO_MAX_WATCHDOG_MS {round(float(board.get('max_watchdog_s', 10.0)) * 1000)}",
         f"#define PROTO_MAX_TELEMETRY_HZ {int(board.get('max_telemetry_hz', 1000))}", ""]
    for table, values in d.get("enums", {}).items():
        L += [f"#define {ident(table)}_{ident(k)} {int(v)}" for k, v in values.items()] + [""]
    for table, bits in d.get("flags", {}).items():
        L += [f"#define {ident(table)}_{ident(k)} (1u << {int(v)})" for k, v in bits.items()] + [""]
    messages = d["message"]
    for m in messages:
        n = ident(m["name"])
        L += [f"/* 0x{int(m['id']):02X} {m['name']}: {m.get('doc', '')} */",
              f"#define MSG_{n} 0x{int(m['id']):02X}",
              f"#define MSG_{n}_SIZE {payload_size(m)}"]
        for f in m.get("fields", []):
            L += field_lines(m["name"], f)
        L += pack_functions(m) + [""]
    L += ["#define PROTO_DIR_UNKNOWN 0", "#define PROTO_DIR_HOST_TO_BOARD 1", "#define PROTO_DIR_BOARD_TO_HOST 2", "",
          "/* Payload size of a message id, -1 if the id is unknown. */",
          "static inline int16_t proto_payload_size(uint8_t id) {", "    switch (id) {"]
    L += [f"    case MSG_{ident(m['name'])}: return MSG_{ident(m['name'])}_SIZE;" for m in messages]
    L += ["    default: return -1;", "    }", "}", "",
          "/* PROTO_DIR_* of a message id. */",
          "static inline uint8_t proto_direction(uint8_t id) {", "    switch (id) {"]
    for m in messages:
        dirn = "HOST_TO_BOARD" if m["direction"] == "host_to_board" else "BOARD_TO_HOST"
        L.append(f"    case MSG_{ident(m['name'])}: return PROTO_DIR_{dirn};")
    L += ["    default: return PROTO_DIR_UNKNOWN;", "    }", "}", "",
          "/* 1 if only the simulator implements the message (real firmware answers UNSUPPORTED). */",
          "static inline uint8_t proto_sim_only(uint8_t id) {", "    switch (id) {"]
    L += [f"    case MSG_{ident(m['name'])}: return 1;" for m in messages if m.get("sim_only")]
    L += ["    default: return 0;", "    }", "}", ""]
    L += test_helpers(messages)
    L += ["", "#endif /* PROTOCOL_GEN_H */", ""]
    return "\n".join(L)


def main(argv: list[str]) -> int:
    if len(argv) != 3:
        print("usage: gen_protocol.py PROTOCOL(.toml or folder) OUT.h", file=sys.stderr)
        return 2
    src = pick_description(Path(argv[1]))
    text = generate(src)
    out = Path(argv[2])
    out.parent.mkdir(parents=True, exist_ok=True)
    if not out.exists() or out.read_text() != text:  # keep the timestamp: no needless rebuilds
        out.write_text(text)
    print(f"gen_protocol: {out} from {src.name} (version {load(src)['protocol']['version']})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
