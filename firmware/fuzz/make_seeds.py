"""Seed corpus of the protocol-core fuzzer from the protocol's test vectors (tests/link/vectors.json).

Each seed is the harness's 4-byte generator seed and then host-link bytes: every host-to-board
vector alone, a session (CONFIGURE, SET_DUTIES, PING, STOP, CLEAR_FAULTS...) in one stream,
the same after garbage, and every vector with one byte changed.
Usage: make_seeds.py VECTORS.json OUT_DIR
"""

import json
import sys
from pathlib import Path


def main() -> None:
    """Write the seeds into OUT_DIR."""
    vectors = json.loads(Path(sys.argv[1]).read_text())["vectors"]
    out = Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    host = [bytes.fromhex(v["wire_hex"]) for v in vectors if v["direction"] == "host_to_board"]
    seeds: list[bytes] = []
    for k, w in enumerate(host):
        seeds.append(bytes([k + 1, 0, 0, 0]) + w)
        bad = bytearray(w)
        bad[len(bad) // 2] ^= 0x01 if bad[len(bad) // 2] != 0x01 else 0x03
        seeds.append(bytes([k + 1, 1, 0, 0]) + bytes(bad))
    session = b"".join(host)
    seeds.append(b"\x07\x00\x00\x00" + session)
    seeds.append(b"\x09\x00\x00\x00" + b"\x55\xaa\x13" + session + session[::-1] + session)
    for k, s in enumerate(seeds):
        (out / f"seed-{k:03d}").write_bytes(s)
    print(f"fuzz seeds: {len(seeds)} from {len(host)} host-to-board vectors in {out}")


if __name__ == "__main__":
    main()
