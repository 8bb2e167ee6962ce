"""Regenerate tests/link/vectors.json: one hex frame per message of omnibot-board-v2.

Run `python tests/link/make_vectors.py` only when the protocol changes on purpose; the
committed file is what firmware authors and both codecs are checked against.
"""

from __future__ import annotations

import json
from pathlib import Path

from omnibench.link.codec import Codec
from omnibench.link.spec import load_protocol

# Raw field values per message: negative numbers, zeros (COBS must stuff them), extremes.
RAW = {
    "HELLO_REQ": {},
    "PING": {},
    "SET_DUTIES": {"duty": [32767, -32767, 0, 16384]},
    "STOP": {},
    "CONFIGURE": {"watchdog": 500, "telemetry_rate": 200},
    "RESET_ENCODERS": {},
    "CLEAR_FAULTS": {},
    "ACK": {"cmd_id": 0x10, "cmd_seq": 258, "status": 0, "time": 1234567},
    "HELLO": {"protocol_version": 2, "firmware_version": [1, 2, 3], "board_id": 0x0B0B0001,
              "boot_id": 0xDEADBEEF, "counts_per_rev": 980, "max_telemetry_rate": 1000, "capabilities": 0b111},
    "TELEMETRY": {"time": 4_000_000_000, "encoder": [0, -1, 32767, -32768],
                  "motor_current": [1500, -1500, 0, 32767], "battery_voltage": 24700,
                  "battery_current": -250, "faults": 0b1, "duty": [16384, -16384, 0, -32767]},
    "EVENT": {"code": 2, "arg": 512, "time": 500000},
    "SIM_SET_WORLD": {"mask": 0b111, "mode": 1, "payload": 2500, "wheel_mass": [9000, 9000, 12000, 12000]},
    "SIM_GET_TRUTH": {},
    "SIM_TRUTH": {"x": 1_234_567, "y": -7_654_321, "psi": 1_570_796, "mode": 0, "time": 2_000_000},
}


def build() -> list[dict]:
    spec = load_protocol("omnibot-board-v2")
    codec = Codec(spec)
    out = []
    for seq, m in enumerate(spec.messages):
        raw = RAW[m.name]
        body = codec.encode_raw(m.name, seq * 257, raw)  # seq with both bytes non-zero
        out.append({
            "message": m.name,
            "id": m.id,
            "direction": m.direction,
            "seq": seq * 257,
            "raw": raw,
            "body_hex": body.hex(),
            "wire_hex": codec.frame_raw(m.name, seq * 257, raw).hex(),
        })
    return out


if __name__ == "__main__":
    path = Path(__file__).with_name("vectors.json")
    doc = {"protocol": "omnibot-board-v2", "crc": "CRC-32/ISO-HDLC", "crc_check": "0xCBF43926",
           "note": "wire = COBS(body + CRC32 little-endian) + 00; body = id u8, seq u16 LE, payload",
           "vectors": build()}
    path.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {len(doc['vectors'])} vectors to {path}")
