"""Procedures end to end against the firmware in simavr, and its safety on the simulated wire.

The sweep and the forward runs go through `omnibench sweep/forward --port /dev/pts/N` to
`sim serve --firmware`; the watchdog and line-noise checks drive the rig in process and read
the Sabertooth packets the chip put on its motor UART, stamped with the chip's cycle count.
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import numpy as np
import pytest

from omnibench.link.codec import Codec
from omnibench.model import default_robot
from omnibench.runs import read_run
from tests.simserver import spawn_server
from omnibench.sim.world import World
from tests.bench.test_end_to_end import FILES, PROC, check_run, closed_form, omnibench

HERE = Path(__file__).parent


@pytest.fixture(scope="module")
def fil_served(fil_elf, tmp_path_factory):
    srv = spawn_server(tmp_path_factory.mktemp("fil-proc"), "--clock", "fast", "--seed", "3", "--firmware", str(fil_elf),
                      "--robot", "omnibot-2019-hall")
    yield srv
    srv.stop()


def test_sweep_and_forward_over_the_firmware(capsys, tmp_path, fil_served) -> None:
    for command, proc in (("sweep", HERE / "procedures" / "fil_sweep.toml"), ("forward", PROC / FILES["forward"])):
        code, out, err = omnibench(capsys, command, "--port", fil_served.path, "--procedure",
                                   str(proc), "--out", str(tmp_path), "--json")
        assert code == 0, err
        run_dir = json.loads(out)["run"]
        if command == "forward":
            check_run(command, run_dir)
            continue
        # The drivers take 127 steps per direction: the wheels run at the quantised duty.
        run = read_run(run_dir)
        assert run.status == "complete" and run.steps["steady"].all()
        robot = default_robot()
        for _, s in run.steps.iterrows():
            expect = closed_form(robot, round(s["duty"] * 127) / 127, s["wheel_mass1"])
            for j in range(1, 5):
                assert s[f"w{j}"] == pytest.approx(expect, abs=0.05), (s["label"], j)
    assert fil_served.status()["motors_stopped"]


def _rig(fil_elf):
    from omnibench.sim.firmware.board import FirmwareBoard

    rig = FirmwareBoard(World(seed=4), fil_elf, "omnibot-2019-hall")  # started: the drivers' 2 s are over
    rig.record_packets = True
    rig.advance_to(rig.clock_us + 20_000)
    return rig, Codec(rig.spec)


def _wheel_commands(rig) -> dict[int, list[tuple[float, int]]]:
    """Per wheel: (time s, signed driver value) of every motor packet on the wire."""
    out: dict[int, list[tuple[float, int]]] = {w: [] for w in range(4)}
    for t, addr, cmd, val in rig.wire_packets:
        if cmd in (0, 1, 4, 5):
            ch = 1 if cmd < 4 else 2
            for w, (a, c, _) in enumerate(rig.motor_map):
                if (a, c) == (addr, ch):
                    out[w].append((t, -val if cmd in (1, 5) else val))
    return out


def test_silent_host_gets_stop_packets_within_watchdog_plus_one_period(fil_elf) -> None:
    rig, codec = _rig(fil_elf)
    try:
        rig.feed(codec.frame_raw("CONFIGURE", 0, {"watchdog": 100, "telemetry_rate": 200}))
        rig.advance_to(rig.clock_us + 5000)
        wire = codec.frame_raw("SET_DUTIES", 1, {"duty": [9000, -9000, 9000, -9000]})
        rig.feed(wire)
        t_last = rig.clock_us * 1e-6 + len(wire) * 10 / 115200  # the host's last frame is in; then silence
        rig.advance_to(rig.clock_us + 300_000)
        cmds = _wheel_commands(rig)
        # one 4-byte packet on pin 6 at 9600 baud; ahead of the stops at most the byte on the wire
        # and the once-a-second setup (0xAA + two timeout packets, 9 bytes)
        period, packet, setup = 1 / 200, 4 * 10 / 9600, 10 * 10 / 9600
        firsts = []
        for w in range(4):
            running = [t for t, v in cmds[w] if v != 0]
            # four packets one after the other: the last wheel's is through 4 x 4.2 ms after the frame
            assert running and running[0] < t_last + setup + 4 * packet + 2e-3, "the duties never reached the wire"
            stop = [t for t, v in cmds[w] if v == 0 and t > running[0]]
            assert stop, f"wheel {w}: no stop packet after the watchdog"
            assert t_last + 0.100 <= stop[0] <= t_last + 0.100 + period + setup + 4 * packet, (w, stop[0] - t_last)
            firsts.append(stop[0])
        # the first stop packet is through within timeout + one period + its own 4.2 ms (+ a setup
        # ahead of it); the other three follow back to back (4.2 ms each at 9600 baud)
        assert min(firsts) <= t_last + 0.100 + period + setup + packet
        assert max(firsts) - min(firsts) <= 3 * packet + 1e-3
        assert not rig.drivers_enabled  # the enable line drops with the latched fault
    finally:
        rig.close()


def test_garbage_and_bit_flips_on_uart0_never_move_a_motor(fil_elf) -> None:
    rig, codec = _rig(fil_elf)
    rng = random.Random(14)
    frames = [codec.frame_raw(n, i, r) for i, (n, r) in enumerate([
        ("STOP", {}), ("PING", {}), ("CONFIGURE", {"watchdog": 500, "telemetry_rate": 100}),
        ("SET_DUTIES", {"duty": [0, 0, 0, 0]}), ("CLEAR_FAULTS", {}), ("HELLO_REQ", {})])]
    try:
        for k in range(150):
            if k % 3 == 0:
                data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 60)))
            else:
                data = bytearray(rng.choice(frames))
                for _ in range(rng.randint(1, 3)):
                    data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
            rig.feed(bytes(data))
            rig.advance_to(rig.clock_us + 5000)
        moved = [(t, a, c, v) for t, a, c, v in rig.wire_packets if c in (0, 1, 4, 5) and v != 0]
        assert moved == [] and rig.line.bad_checksum == 0 and rig.wiring_findings() == []
        assert np.all(np.abs(rig.plant.state.phi_dot) < 1e-6)
        assert any(c in (0, 4) and v == 0 for _, _, c, v in rig.wire_packets)  # the wire was alive
    finally:
        rig.close()


def test_serve_with_a_missing_firmware_file_says_so(capsys, fil_elf) -> None:
    code, _, err = omnibench(capsys, "sim", "serve", "--firmware", str(fil_elf.parent / "nope.elf"))
    assert code != 0 and "no firmware at" in err and "make -C firmware" in err and "Traceback" not in err
