"""The motor line and the enable line of the default build, measured on the pins themselves.

pinrec (firmware/sim/pinrec.c) runs the .elf on a bare simulated ATmega2560 with nothing
attached and records the levels the firmware writes to pin 6 (PH3, Sabertooth S1) and pin 7
(PH4, the drivers' enable), with the cycle of each change. This file decodes that waveform
itself as 9600 baud 8N1 (no code of the project's rig is used) and checks what a Sabertooth
in packet-serial mode at its factory rate needs: the library's start-up timing, valid packets
for addresses 128 and 129, and the enable line high.
"""

from __future__ import annotations

import bisect
import subprocess
from pathlib import Path

import pytest

BAUD = 9600
RUN_S = 3.2


def record(build: Path, seconds: float = RUN_S, *pins: str) -> tuple[float, dict[str, list[tuple[int, int]]], dict]:
    """(clock Hz, per pin the (cycle, level) changes, per pin (ddr, port) at the end)."""
    r = subprocess.run([str(build / "pinrec"), str(build / "omnibot.elf"), str(seconds), *(pins or ("H3", "H4"))],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    hz, changes, final = 0.0, {}, {}
    for line in r.stdout.splitlines():
        p = line.split()
        if p[0] == "F":
            hz = float(p[1])
        elif p[0] == "I":
            changes[p[1]] = [(0, int(p[2]))]
        elif p[0] == "C":
            changes[p[2]].append((int(p[1]), int(p[3])))
        elif p[0] == "D":
            final[p[1]] = (int(p[2]), int(p[3]))
    return hz, changes, final


def decode_uart(changes: list[tuple[int, int]], hz: float, baud: float, tolerance: float = 0.1) -> list[tuple[float, int]]:
    """8N1 bytes (start time s, value) from the pin's level changes; AssertionError on a framing
    error or an edge more than `tolerance` (10 %) of a bit away from a bit boundary (a receiver samples
    mid-bit; the firmware's edges carry up to about 6 % of a bit of interrupt latency at 9600)."""
    cycles = [c for c, _ in changes]
    bit = hz / baud

    def level(c: float) -> int:
        return changes[bisect.bisect_right(cycles, c) - 1][1]

    out, k = [], 1
    while k < len(changes):
        c, lv = changes[k]
        if lv != 0:
            k += 1
            continue
        assert level(c - 1) == 1, f"falling edge at cycle {c} from a low line"
        bits = [level(c + (j + 0.5) * bit) for j in range(10)]
        assert bits[0] == 0 and bits[9] == 1, f"framing error in the byte at {c / hz:.6f} s: bits {bits}"
        end = c + 9.5 * bit
        j = k + 1
        while j < len(changes) and changes[j][0] < end:
            off = (changes[j][0] - c) / bit
            assert abs(off - round(off)) < tolerance, f"edge {off:.2f} bits into the byte at {c / hz:.6f} s"
            j += 1
        out.append((c / hz, sum(bits[1 + i] << i for i in range(8))))
        k = j
    return out


@pytest.fixture(scope="module")
def recorded(default_build):
    return record(default_build)


def test_pin6_carries_sabertooth_packets_at_9600_8n1_after_the_librarys_startup(recorded) -> None:
    hz, changes, final = recorded
    assert final["H3"] == (1, 1), "pin 6 must be an output idling high (UART mark)"
    line = decode_uart(changes["H3"], hz, BAUD)
    assert line, "nothing on pin 6"
    t_aa, first = line[0]
    assert first == 0xAA and t_aa >= 1.5, f"first byte 0x{first:02x} at {t_aa:.4f} s"
    # Sabertooth::autobaud(): 0xAA, then 0.5 s of silence before any packet
    assert line[1][0] - t_aa >= 0.5, f"next byte {line[1][0] - t_aa:.4f} s after 0xAA"
    # after it: packets (address 128 or 129, command, value, checksum), 0xAA alone between them
    packets, i = [], 1
    while i < len(line):
        if line[i][1] == 0xAA:
            i += 1
            continue
        assert i + 4 <= len(line), f"truncated packet at {line[i][0]:.4f} s"
        (t, a), (_, c), (_, v), (_, s) = line[i:i + 4]
        assert a in (128, 129), f"address {a} at {t:.4f} s"
        assert c < 128 and v < 128 and s == (a + c + v) & 0x7F, f"bad packet {a} {c} {v} {s} at {t:.4f} s"
        packets.append((t, a, c, v))
        i += 4
    # the serial timeout (command 14: 300 ms = 3) to both drivers, then a stop to each of the
    # four channels (2019 map: 128/2 FL, 128/1 FR, 129/1 RL, 129/2 RR), resent every 100 ms
    timeouts = [(a, v) for _, a, c, v in packets if c == 14]
    assert (128, 3) in timeouts and (129, 3) in timeouts
    motor = [(a, c, v) for _, a, c, v in packets if c in (0, 1, 4, 5)]
    assert {(a, c) for a, c, _ in motor} == {(128, 0), (128, 4), (129, 0), (129, 4)}
    assert all(v == 0 for _, _, v in motor), "nothing commanded a motor: every packet is a stop"
    # the timeout packets come back (a driver power cycle forgets them)
    t_timeouts = [t for t, a, c, _ in packets if c == 14 and a == 128]
    assert len(t_timeouts) >= 2 and t_timeouts[1] - t_timeouts[0] == pytest.approx(1.0, abs=0.01)


def test_pin7_enables_the_drivers(recorded) -> None:
    hz, changes, final = recorded
    assert final["H4"] == (1, 1), "pin 7 must be an output driven high"
    t_high = next(c for c, lv in changes["H4"] if lv == 1) / hz
    assert t_high < 0.1


def test_a_38400_baud_build_is_not_read_as_9600(tmp_path) -> None:
    """The decoder is not lenient: the same firmware at 38400 baud fails at 9600 8N1."""
    from omnibench.sim.firmware.build import make

    from .conftest import need

    need("avr", "fil")
    build = make("all", tmp_path, SABERTOOTH_BAUD="38400")
    make("pinrec", build)
    hz, changes, _ = record(build, 2.2, "H3")
    with pytest.raises(AssertionError, match="framing error|edge"):
        decode_uart(changes["H3"], hz, BAUD)
    # (a bit is 417 cycles there: the same ~90 cycles of interrupt latency are 22 % of it)
    assert decode_uart(changes["H3"], hz, 38400, tolerance=0.3)[0][1] == 0xAA
