"""Benchmark of the board firmware (firmware/) on a simulated ATmega2560 (simavr), issues 14 and 33.

Builds the firmware with its defaults (the 2019 wiring: Sabertooth packets from the Timer2
software UART on pin 6 at 9600 baud) plus Hall current sensors (the heaviest build) and runs
it in the firmware-in-the-loop rig wired as the robot (robots/omnibot-2019-hall.toml). All
times are board time, read off the simulated wire (the chip's cycle counter), not the wall
clock. Printed:

- the highest telemetry rate sustained at 115200 baud with zero lost frames (1 s per rate),
- CPU load at 200 Hz telemetry and idle (cycles awake / cycles, from simavr's cycle count),
- command-to-driver latency per wheel: end of a SET_DUTIES frame on UART0 to the end of that
  wheel's Sabertooth packet as the driver decoded it on pin 6 (4 bytes at 9600 = 4.17 ms each,
  sent one after the other in the order FL, FR, RL, RR),
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

    r = FirmwareBoard(World(seed=1), elf, "omnibot-2019-hall")  # its 2 s driver start-up is over
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
        if rate:
            d = 6000
            r.feed(r.codec.frame_raw("SET_DUTIES", 1, {"duty": [d, -d, d, -d]}))  # wheels running: packets flow
        c0, s0 = r.cpu_load()
        r.advance_to(r.clock_us + 1_000_000)
        c1, s1 = r.cpu_load()
        return 1 - (s1 - s0) / (c1 - c0)
    finally:
        r.close()


WHEELS = ("FL", "FR", "RL", "RR")


def latency(elf: Path, n: int = 20) -> dict[str, list[float]]:
    """SET_DUTIES frame in -> each wheel's motor packet through, ms; and the send order seen."""
    r = rig(elf)
    per: dict[str, list[float]] = {w: [] for w in WHEELS}
    orders: list[str] = []
    wheel_of = {(a, c): w for w, (a, c, _) in enumerate(r.motor_map)}
    try:
        r.feed(r.codec.frame_raw("CONFIGURE", 0, {"watchdog": 10000, "telemetry_rate": 0}))
        r.advance_to(r.clock_us + 20_000)
        for k in range(n):
            d = 3000 + 500 * k
            wire = r.codec.frame_raw("SET_DUTIES", k + 1, {"duty": [d, -d, d, -d]})
            r.wire_packets.clear()
            r.feed(wire)
            t_in = r.clock_us * 1e-6 + len(wire) * HOST_BYTE_S
            r.advance_to(r.clock_us + 40_000)
            got = [(t, wheel_of[(a, 1 if c < 4 else 2)]) for t, a, c, v in r.wire_packets if c in (0, 1, 4, 5) and v]
            seen = []
            for t, w in got:
                if WHEELS[w] not in seen:
                    seen.append(WHEELS[w])
                    per[WHEELS[w]].append((t - t_in) * 1e3)
            orders.append(",".join(seen))
            r.advance_to(r.clock_us + 70_000 + 1_300 * (k % 7))  # past the next refresh; vary the phase
    finally:
        r.close()
    per["order"] = orders  # type: ignore[assignment]
    return per


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
                if t_low is None and not r.drivers_enabled:
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
    lat = latency(elf)
    orders = lat.pop("order")
    res["send_order"] = statistics.mode(orders)
    res["send_order_share"] = orders.count(res["send_order"]) / len(orders)
    res["latency_ms"] = {w: {"median": statistics.median(v), "max": max(v), "n": len(v)} for w, v in lat.items()}
    wf, wl, we = watchdog(elf)
    res["watchdog_first_ms"], res["watchdog_last_ms"], res["watchdog_enable_ms"] = max(wf), max(wl), max(we)
    print(f"highest telemetry rate with zero lost frames: {best} Hz (of the rates tried)")
    print(f"CPU load (ATmega2560, 16 MHz): {100 * res['cpu_load_200hz']:.1f} % at 200 Hz telemetry, "
          f"{100 * res['cpu_load_idle']:.1f} % idle")
    print(f"SET_DUTIES -> Sabertooth packet through, per wheel at {9600} baud (send order {res['send_order']}, "
          f"{100 * res['send_order_share']:.0f} % of {len(orders)} commands): "
          + ", ".join(f"{w} {x['median']:.2f} ms (max {x['max']:.2f})" for w, x in res["latency_ms"].items()))
    print(f"watchdog: timeout -> enable line low <= {max(we):.2f} ms, first stop packet <= {max(wf):.2f} ms, "
          f"last stop packet <= {max(wl):.2f} ms ({len(wf)} trials)")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
