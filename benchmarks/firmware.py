"""Benchmark of the board firmware (firmware/) on a simulated ATmega2560 (simavr), issue 14.

Builds the firmware (with Hall current sensors, the heaviest build) and runs it in the
firmware-in-the-loop rig with the plant as its robot. All times are board time, read off the
simulated wire (the chip's cycle counter), not the wall clock. Printed:

- the highest telemetry rate sustained at 115200 baud with zero lost frames (1 s per rate),
- CPU load at 200 Hz telemetry and idle (cycles awake / cycles, from simavr's cycle count),
- command-to-driver latency: end of a SET_DUTIES frame on UART0 to the end of the first and
  of the last of the four Sabertooth packets on the motor UART,
- watchdog stop time: host silent; timeout to the first / last Sabertooth stop packet.

    .venv/bin/python benchmarks/firmware.py [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

HOST_BYTE_S = 10 / 115200  # the rig feeds host bytes at this rate (8N1)


def rig(elf: Path):
    from omnibench.sim.firmware.board import FirmwareBoard
    from omnibench.sim.world import World

    r = FirmwareBoard(World(seed=1), elf)
    r.record_packets = True
    r.advance_to(50_000)
    r.take_output()
    return r


def telemetry(elf: Path, rate: int) -> tuple[int, int, float]:
    """(frames received in 1 s, frames lost by seq, time-stamp spacing error max µs)."""
    from omnibench.link.framing import Deframer

    r = rig(elf)
    try:
        r.feed(r.codec.frame_raw("CONFIGURE", 0, {"watchdog": 10000, "telemetry_rate": rate}))
        r.advance_to(r.clock_us + 20_000)
        r.take_output()
        r.advance_to(r.clock_us + 1_000_000)
        msgs = [r.codec.decode_raw(b) for b in Deframer(r.codec.crc, 64).feed(r.take_output())]
        tel = [m for m in msgs if m.name == "TELEMETRY"][1:]
        seqs = [m.seq for m in msgs]
        lost = sum((b - a - 1) % 65536 for a, b in zip(seqs, seqs[1:]))
        dts = [b["time"] - a["time"] for a, b in zip(tel, tel[1:])]
        jitter = max(abs(d - round(1e6 / rate)) for d in dts) if dts else float("nan")
        return len(tel), lost, jitter
    finally:
        r.close()


def cpu_load(elf: Path, rate: int) -> float:
    r = rig(elf)
    try:
        if rate:
            r.feed(r.codec.frame_raw("CONFIGURE", 0, {"watchdog": 10000, "telemetry_rate": rate}))
        r.advance_to(r.clock_us + 50_000)
        c0, s0 = r.cpu_load()
        r.advance_to(r.clock_us + 1_000_000)
        c1, s1 = r.cpu_load()
        return 1 - (s1 - s0) / (c1 - c0)
    finally:
        r.close()


def latency(elf: Path, n: int = 20) -> tuple[list[float], list[float]]:
    """SET_DUTIES frame in -> first / last of the four motor packets out, ms."""
    r = rig(elf)
    first, last = [], []
    try:
        r.feed(r.codec.frame_raw("CONFIGURE", 0, {"watchdog": 10000, "telemetry_rate": 0}))
        r.advance_to(r.clock_us + 20_000)
        for k in range(n):
            d = 3000 + 500 * k
            wire = r.codec.frame_raw("SET_DUTIES", k + 1, {"duty": [d, -d, d, -d]})
            r.wire_packets.clear()
            r.feed(wire)
            t_in = r.clock_us * 1e-6 + len(wire) * HOST_BYTE_S
            r.advance_to(r.clock_us + 15_000)
            motor = [t for t, _, c, v in r.wire_packets if c in (0, 1, 4, 5) and v]
            first.append((motor[0] - t_in) * 1e3)
            last.append((motor[3] - t_in) * 1e3)
            r.advance_to(r.clock_us + 7_000 + 1_300 * (k % 7))  # vary the phase against the ticks
    finally:
        r.close()
    return first, last


def watchdog(elf: Path, n: int = 5) -> tuple[list[float], list[float], list[float]]:
    """Timeout -> first / last stop packet, and -> enable line low, ms beyond the timeout."""
    first, last, enable = [], [], []
    for k in range(n):
        r = rig(elf)
        try:
            r.advance_to(r.clock_us + 1_700 * k)
            r.feed(r.codec.frame_raw("CONFIGURE", 0, {"watchdog": 100, "telemetry_rate": 200}))
            r.advance_to(r.clock_us + 5_000)
            wire = r.codec.frame_raw("SET_DUTIES", 1, {"duty": [9000] * 4})
            r.feed(wire)
            t_in = r.clock_us * 1e-6 + len(wire) * HOST_BYTE_S
            r.advance_to(r.clock_us + 50_000)
            r.wire_packets.clear()
            t_low = None
            while r.clock_us * 1e-6 < t_in + 0.2:
                r.advance_to(r.clock_us + 100)
                if t_low is None and not r.chip.drivers_enabled:
                    t_low = r.clock_us * 1e-6
            stops = [t for t, _, c, v in r.wire_packets if c in (0, 1, 4, 5) and v == 0]
            first.append((stops[0] - t_in - 0.1) * 1e3)
            last.append((stops[3] - t_in - 0.1) * 1e3)
            enable.append((t_low - t_in - 0.1) * 1e3)
        finally:
            r.close()
    return first, last, enable


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", help="also write the figures to this file")
    args = ap.parse_args(argv)
    from omnibench.errors import UserError
    from omnibench.sim.firmware.build import make, missing_tools

    miss = missing_tools("avr", "fil")
    if miss:
        print(f"benchmarks/firmware.py: tools missing: {', '.join(miss)}", file=sys.stderr)
        return 2
    try:
        build = make("all", Path(tempfile.mkdtemp(prefix="fw-bench-")), BATTERY_CURRENT="hall", MOTOR_CURRENT="hall")
        make("fil", build)
    except UserError as exc:
        print(exc, file=sys.stderr)
        return 1
    elf = build / "omnibot.elf"
    res: dict = {"rates": {}}
    best = 0
    for rate in (100, 200, 205, 210, 220, 240, 300, 500):
        got, lost, jitter = telemetry(elf, rate)
        ok = lost == 0 and abs(got - rate) <= 1
        res["rates"][rate] = {"frames": got, "lost": lost, "stamp_error_us": jitter}
        print(f"telemetry {rate:4d} Hz: {got:4d} frames in 1 s, lost {lost}, time-stamp error <= {jitter:.0f} µs"
              + ("" if ok else "   <- not sustained"))
        if ok:
            best = rate
    res["max_rate_hz"] = best
    res["cpu_load_200hz"] = cpu_load(elf, 200)
    res["cpu_load_idle"] = cpu_load(elf, 0)
    first, last = latency(elf)
    res["latency_first_ms"], res["latency_last_ms"] = statistics.median(first), statistics.median(last)
    res["latency_first_max_ms"], res["latency_last_max_ms"] = max(first), max(last)
    wf, wl, we = watchdog(elf)
    res["watchdog_first_ms"], res["watchdog_last_ms"], res["watchdog_enable_ms"] = max(wf), max(wl), max(we)
    print(f"highest telemetry rate with zero lost frames: {best} Hz (of the rates tried)")
    print(f"CPU load (ATmega2560, 16 MHz): {100 * res['cpu_load_200hz']:.1f} % at 200 Hz telemetry, "
          f"{100 * res['cpu_load_idle']:.1f} % idle")
    print(f"SET_DUTIES -> Sabertooth packets: first {res['latency_first_ms']:.2f} ms (max {max(first):.2f}), "
          f"all four {res['latency_last_ms']:.2f} ms (max {max(last):.2f}), median of {len(first)}")
    print(f"watchdog: timeout -> enable line low <= {max(we):.2f} ms, first stop packet <= {max(wf):.2f} ms, "
          f"last stop packet <= {max(wl):.2f} ms ({len(wf)} trials)")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
