"""Faults on the link: garbled bytes, silent host, disconnect, board reset, version mismatch, baud."""

from __future__ import annotations

import time
import uuid

import pytest

from omnibench.errors import BoardError
from omnibench.link.board import Board
from omnibench.link.codec import Codec
from omnibench.sim import registry
from tests.simserver import spawn_server


def _name() -> str:
    return f"fault-{uuid.uuid4().hex[:8]}"


@pytest.mark.parametrize("seed", [1, 2])
def test_one_percent_garbled_no_corrupt_frame_accepted_and_resync_within_one_frame(seed: int) -> None:
    """0.5 % bytes dropped + 0.5 % corrupted + garbage bursts, both directions."""
    name = _name()
    url = f"sim://omnibot?seed={seed}&name={name}&drop=0.005&corrupt=0.005&garbage=0.0005"
    with Board.open(url, timeout=5.0) as b:
        sim = registry.get(name)
        b.configure(telemetry_hz=200)
        b.set_duties([0.3, -0.2, 0.1, 0.25])
        sim.record = sim.to_host.record = True
        got = b.wait(10.0)
        b.stop()
    sent = {f.seq: f for f in sim.sent if f.name == "TELEMETRY"}
    touched = sorted(sim.to_host.touched)
    assert sim.to_host.dropped + sim.to_host.corrupted > 100  # the faults really happened

    # 1. nothing corrupt is accepted: each received sample is exactly what the board sent
    codec = Codec()
    received = {s.seq: s for s in got if s.seq in sent}
    assert len(received) > 1000  # (0.99 ** 48: about 60 % of 48-byte frames arrive intact)
    for seq, s in received.items():
        raw = sent[seq].raw
        phys = codec.from_raw(codec.decode_raw(codec.encode_raw("TELEMETRY", seq, raw)))
        assert s.encoder == tuple(raw["encoder"])
        assert s.duty == phys["duty"] and s.motor_current == phys["motor_current"]
        assert round(s.t * 1e6) % 2**32 == raw["time"]

    # 2. resync within one frame: every frame whose own bytes were untouched is accepted,
    #    however damaged the frame just before it was
    import bisect

    def hit(f) -> bool:
        i = bisect.bisect_left(touched, f.start)
        return i < len(touched) and touched[i] < f.end

    clean = {seq for seq, f in sent.items() if not hit(f)}
    damaged = set(sent) - clean
    assert damaged, "no telemetry frame was damaged: the test would prove nothing"
    last = max(received)
    assert {s for s in clean if s <= last} <= set(received)
    after_damage = {seq + 1 for seq in damaged} & clean
    assert after_damage and after_damage <= set(received) | {s for s in after_damage if s > last}
    assert b.stats.lost >= len([s for s in damaged if s <= last])
    assert b.stats.crc_errors + b.stats.framing_errors > 0


def test_silent_host_sees_motors_stopped_within_watchdog() -> None:
    name = _name()
    with Board.open(f"sim://?name={name}", heartbeat=False) as b:
        b.configure(telemetry_hz=500, watchdog_s=0.05)
        b.set_duties([0.5] * 4)
        t_cmd = b.board_time
        s = b.wait(0.2)
        first_stop = next(x for x in s if x.t > t_cmd and x.duty == (0.0,) * 4)
        assert first_stop.t - t_cmd <= 0.05 + 0.002 + 1e-6
        assert any(e[1] == "WATCHDOG" for e in b.stats.events)
        assert registry.get(name).status()["faults"] == ["WATCHDOG"]


def test_disconnect_mid_stream_gives_clear_error_within_a_second() -> None:
    with Board.open("sim://?clock=realtime&disconnect_at=0.4") as b:
        b.configure(telemetry_hz=100)
        b.set_duties([0.2] * 4)
        last_wall = time.monotonic()
        with pytest.raises(BoardError, match="lost the board.*check the cable") as exc:
            for _ in b.samples(5.0):
                last_wall = time.monotonic()
        assert time.monotonic() - last_wall < 1.0
        assert "\n" not in str(exc.value)


def test_pty_server_killed_mid_stream_gives_clear_error(tmp_path) -> None:
    served = spawn_server(tmp_path, "--clock", "realtime")
    try:
        with Board.open(served.path) as b:
            b.configure(telemetry_hz=100)
            b.wait(0.1)
            served.proc.kill()
            served.proc.wait(timeout=5)
            t0 = time.monotonic()
            with pytest.raises(BoardError, match="lost the board"):
                b.wait(5.0)
            assert time.monotonic() - t0 < 1.5
    finally:
        served.stop()


def test_board_reset_mid_stream_is_detected() -> None:
    with Board.open("sim://?reset_at=0.5") as b:
        b.configure(telemetry_hz=100)
        b.set_duties([0.2] * 4)
        old_boot = b.hello.boot_id
        with pytest.raises(BoardError, match="reset") as exc:
            b.wait(2.0)
        assert f"{old_boot:08X}" in str(exc.value)
        assert b.reset_detected
        with pytest.raises(BoardError, match="reset"):
            b.set_duties([0.2] * 4)


def test_board_reset_detected_even_if_its_hello_is_lost() -> None:
    """The reset board's own HELLO never arrives: the stall probe finds the new boot id."""
    name = _name()
    with Board.open(f"sim://?name={name}&reset_at=0.3") as b:
        sim = registry.get(name)
        b.configure(telemetry_hz=100)
        real_boot = sim._boot

        def boot_without_hello() -> None:
            real_boot()
            sim.out.clear()  # HELLO and EVENT lost on the wire
        sim._boot = boot_without_hello
        with pytest.raises(BoardError, match="reset"):
            b.wait(2.0)


def test_version_mismatch_refuses_to_drive_motors() -> None:
    name = _name()
    with pytest.raises(BoardError, match=r"v3.*v2.*motors not driven"):
        Board.open(f"sim://?name={name}&protocol_version=3")
    sim = registry.get(name)
    assert {m[0] for m in sim.received} == {"HELLO_REQ"}

    with Board.open(f"sim://?name={name}&protocol_version=3", strict=False) as b:
        assert not b.version_ok and b.hello.protocol_version == 3
        with pytest.raises(BoardError, match="motors not driven"):
            b.set_duties([0.1] * 4)
    sim = registry.get(name)
    assert "SET_DUTIES" not in {m[0] for m in sim.received}
    assert sim.status()["motors_stopped"]


def test_wrong_baud_rate_handshake_error_names_the_baud_rate() -> None:
    with pytest.raises(BoardError, match=r"baud rate \(board expects 115200, opened at 9600\)"):
        Board.open("sim://", baudrate=9600, timeout=0.5)
    with pytest.raises(BoardError, match="no HELLO"):
        Board.open("sim://?wrong_baud=1", timeout=0.5)


def test_commands_survive_lost_frames_by_retrying() -> None:
    with Board.open("sim://?seed=4&drop=0.03&direction=to_board", timeout=5.0, heartbeat=False) as b:
        for _ in range(10):
            b.ping()
        b.configure(telemetry_hz=100)
        for _ in range(40):
            b.ping()
        assert b.stats.retries > 0


def test_board_with_another_layout_is_recognised_as_another_version(tmp_path) -> None:
    """A v9 firmware whose HELLO is longer than ours: the host still names the version."""
    from omnibench.link.spec import load_protocol

    text = load_protocol().path.read_text()
    text = text.replace("version = 2\n", "version = 9\n", 1).replace(
        '{ name = "capabilities", type = "u8", flags = "capabilities" },',
        '{ name = "capabilities", type = "u8", flags = "capabilities" },\n  { name = "serial", type = "u32" },')
    v9 = tmp_path / "omnibot-board-v9.toml"
    v9.write_text(text)
    with pytest.raises(BoardError, match=r"v9.*this tool speaks v2.*motors not driven"):
        Board.open(f"sim://?protocol={v9}", timeout=1.0)


def _fault_samples(b: Board, seconds: float):
    got = b.wait(seconds)
    return got, [s for s in got if s.faults]


def test_overcurrent_latches_stops_the_motors_and_refuses_duties_until_cleared() -> None:
    """Starting from rest at duty 0.8 draws ~10 A per motor (0.8 * 24 V / 1.84 ohm): above a
    4 A limit the board must latch OVERCURRENT, stop, report it, and refuse duties until
    CLEAR_FAULTS; below the limit nothing trips."""
    name = _name()
    with Board.open(f"sim://?name={name}&overcurrent_limit=4") as b:
        b.configure(telemetry_hz=200)
        b.set_duties([0.1] * 4)  # ~1.3 A at start: under the limit
        _, faulted = _fault_samples(b, 0.3)
        assert not faulted
        b.set_duties([0.8] * 4)
        got, faulted = _fault_samples(b, 0.3)
        assert faulted and b.fault_names(faulted[0].faults) == ["OVERCURRENT"]
        assert all(s.duty == (0.0,) * 4 for s in got if s.t > faulted[0].t)
        assert any(e[1] == "FAULT" for e in b.stats.events)
        with pytest.raises(BoardError, match="OVERCURRENT latched"):
            b.set_duties([0.1] * 4)
        b.clear_faults()
        b.set_duties([0.1] * 4)
        got, faulted = _fault_samples(b, 0.2)
        assert not faulted and got[-1].duty == (pytest.approx(0.1, abs=1e-4),) * 4
        b.stop()


def test_battery_sagging_under_load_latches_undervoltage() -> None:
    """A pack with 0.2 ohm internal resistance sags ~6 V under a 0.8 start (~30 A): below a
    22 V limit the board latches UNDERVOLTAGE; at rest (24 V) it does not."""
    name = _name()
    url = f"sim://?name={name}&undervoltage_limit=22&effects.battery_resistance.R_b=0.2"
    with Board.open(url) as b:
        b.configure(telemetry_hz=200)
        got, faulted = _fault_samples(b, 0.2)
        assert not faulted and min(s.battery_voltage for s in got) > 23.5
        b.set_duties([0.8] * 4)
        got, faulted = _fault_samples(b, 0.3)
        assert faulted and b.fault_names(faulted[0].faults) == ["UNDERVOLTAGE"]
        assert registry.get(name).status()["faults"] == ["UNDERVOLTAGE"]
        b.stop()


def test_scheduled_driver_fault_stops_the_motors_at_its_time() -> None:
    name = _name()
    with Board.open(f"sim://?name={name}&driver_fault_at=0.4") as b:
        b.configure(telemetry_hz=200)
        b.set_duties([0.3] * 4)
        got, faulted = _fault_samples(b, 0.8)
        assert faulted and b.fault_names(faulted[0].faults) == ["DRIVER"]
        assert 0.4 - 1e-9 <= faulted[0].t <= 0.4 + 0.006
        assert all(s.duty == (0.0,) * 4 for s in faulted)
        assert all(not s.faults for s in got if s.t < 0.4 - 1e-9)
