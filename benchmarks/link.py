"""Link benchmark: wire bytes per telemetry sample, sustained telemetry rate with zero loss
over sim:// and over the pseudo-terminal server, and command round-trip latency.

    .venv/bin/python benchmarks/link.py [--seconds 2] [--json]

Rates are checked in real time (the board's clock follows the wall clock), so "zero loss at
N Hz" means the host kept up with N frames per second for the whole window. The fast clock
line shows how many samples per wall second the in-process simulator delivers to a
procedure (that is what makes simulated runs quicker than the robot).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the test helpers (simserver.py)

from simserver import spawn_server

from omnibench.link.board import Board
from omnibench.link.codec import Codec

RATES = (200, 500, 1000)
BAUD = 115200


def wire_bytes() -> dict:
    """Wire bytes of one TELEMETRY frame, from the description and measured on a stream."""
    codec = Codec()
    with Board.open("sim://?seed=1") as b:
        b.configure(telemetry_hz=200)
        b.read_samples()
        before_bytes, before_n = b.stats.bytes_in, b.stats.telemetry
        b.configure(telemetry_hz=200, watchdog_s=10.0)  # few PINGs in the window
        b.wait(5.0)
        n = b.stats.telemetry - before_n
        per_sample = (b.stats.bytes_in - before_bytes) / n
    size = codec.wire_size("TELEMETRY")
    return {"telemetry_frame_bytes": size, "bytes_per_sample_measured": round(per_sample, 2),
            "max_rate_at_115200_baud_hz": round(BAUD / 10 / size, 1)}


def sustained(url: str, seconds: float) -> dict:
    """Highest of RATES with zero lost frames over `seconds` of real time, per rate the counts."""
    out: dict = {}
    with Board.open(url) as b:
        for hz in RATES:
            b.configure(telemetry_hz=hz)
            b.read_samples()
            lost0, n0 = b.stats.lost, b.stats.telemetry
            w0 = time.monotonic()
            b.wait(seconds)
            out[hz] = {"samples": b.stats.telemetry - n0, "lost": b.stats.lost - lost0,
                       "wall_s": round(time.monotonic() - w0, 2)}
        b.configure(telemetry_hz=0)
    ok = [hz for hz in RATES if out[hz]["lost"] == 0]
    return {"zero_loss_max_hz": max(ok) if ok else 0, "per_rate": out}


def fast_throughput(seconds: float) -> dict:
    """Samples per wall second the fast in-process simulator delivers at 200 Hz board rate."""
    with Board.open("sim://?seed=2") as b:
        b.configure(telemetry_hz=200)
        b.set_duties([0.3] * 4)
        w0, c0 = time.monotonic(), time.process_time()
        s = b.wait(seconds * 5)
        wall, cpu = time.monotonic() - w0, time.process_time() - c0
        b.stop()
        return {"board_seconds": seconds * 5, "samples": len(s), "lost": b.stats.lost,
                "samples_per_wall_s": round(len(s) / wall), "speedup_vs_realtime": round(seconds * 5 / wall, 1),
                "cpu_ms_per_sample": round(1e3 * cpu / len(s), 3)}


def latency(url: str, n: int = 200) -> dict:
    """PING -> ACK round trip (ms): median and 95th percentile over `n` commands."""
    with Board.open(url) as b:
        b.configure(telemetry_hz=200)
        rtt = sorted(b.ping() * 1e3 for _ in range(n))
    return {"median_ms": round(statistics.median(rtt), 3), "p95_ms": round(rtt[int(0.95 * n) - 1], 3),
            "n": n, "with_telemetry_hz": 200}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="real-time window per rate")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    res: dict = {"wire": wire_bytes()}
    res["sim_realtime"] = sustained("sim://?clock=realtime&seed=3", args.seconds)
    res["sim_fast"] = fast_throughput(args.seconds)
    res["latency_sim"] = latency("sim://?seed=4")
    with tempfile.TemporaryDirectory() as tmp:
        served = spawn_server(Path(tmp), "--clock", "realtime", "--seed", "5")
        try:
            res["pty_realtime"] = sustained(served.path, args.seconds)
            res["latency_pty"] = latency(served.path)
        finally:
            served.stop()
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    w = res["wire"]
    print(f"telemetry: {w['telemetry_frame_bytes']} wire bytes per sample (target <= 48), "
          f"{w['bytes_per_sample_measured']} measured incl. ACKs/PINGs; "
          f"115200 baud carries {w['max_rate_at_115200_baud_hz']} Hz")
    for key, label in (("sim_realtime", "sim:// (realtime clock)"), ("pty_realtime", "pseudo-terminal (sim serve)")):
        r = res[key]
        per = ", ".join(f"{hz} Hz: {v['samples']} samples, {v['lost']} lost" for hz, v in r["per_rate"].items())
        print(f"{label}: zero loss up to {r['zero_loss_max_hz']} Hz ({per})")
    f = res["sim_fast"]
    print(f"sim:// fast clock: {f['samples']} samples ({f['board_seconds']:g} s of board time at 200 Hz) "
          f"in {f['board_seconds'] / f['speedup_vs_realtime']:.2f} s wall = {f['samples_per_wall_s']} samples/s, "
          f"{f['speedup_vs_realtime']}x real time, {f['lost']} lost; {f['cpu_ms_per_sample']} ms CPU per sample "
          "(board + physics + host, one process)")
    for key, label in (("latency_sim", "sim://"), ("latency_pty", "pseudo-terminal")):
        lt = res[key]
        print(f"command round trip over {label}: median {lt['median_ms']} ms, p95 {lt['p95_ms']} ms "
              f"({lt['n']} PINGs, telemetry at 200 Hz)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
