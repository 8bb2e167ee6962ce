"""The firmware's protocol core, compiled for this machine: the frames of tests/link/vectors.json,
the CRC over catalogue parameters, and the behaviour of docs/protocol.md §4 (no hardware)."""

from __future__ import annotations

import json
import random
import subprocess
import tomllib
from pathlib import Path

import pytest

from omnibench.sim.firmware.build import FIRMWARE_DIR
from tests.firmware.corehost import CoreHost

REPO = Path(__file__).resolve().parents[2]
VECTORS = json.loads((REPO / "tests" / "link" / "vectors.json").read_text())


@pytest.fixture()
def core(host_build):
    c = CoreHost(host_build)
    yield c
    c.close()


def _flat(raw: dict) -> list[int]:
    out: list[int] = []
    for v in raw.values():
        out += list(v) if isinstance(v, list) else [v]
    return out


def test_every_vector_packs_frames_and_unpacks(core) -> None:
    assert VECTORS["vectors"]
    for v in VECTORS["vectors"]:
        flat = _flat(v["raw"])
        payload = core.cmd(f"pack {v['id']} " + " ".join(map(str, flat)))[0].split()
        assert (payload[1] if len(payload) > 1 else "") == v["body_hex"][6:], v["message"]
        seq = int.from_bytes(bytes.fromhex(v["body_hex"][2:6]), "little")
        wire = core.cmd(f"frame {v['id']} {seq} {v['body_hex'][6:]}")[0].split()[1]
        assert wire == v["wire_hex"], v["message"]
        values = core.cmd(f"unpack {v['id']} {v['body_hex'][6:]}")[0].split()[1:]
        assert [int(x) for x in values] == flat, v["message"]


def test_crc_check_value_of_the_description(core) -> None:
    desc = tomllib.loads((REPO / "protocols" / f"{VECTORS['protocol']}.toml").read_text())
    got = int(core.cmd("crc " + b"123456789".hex())[0].split()[1], 16)
    assert got == desc["crc"]["check"]


CATALOGUE = {  # name: width, poly, init, refin, refout, xorout, check (reveng catalogue)
    "CRC-32/ISO-HDLC": (32, 0x04C11DB7, 0xFFFFFFFF, 1, 1, 0xFFFFFFFF, 0xCBF43926),
    "CRC-32C": (32, 0x1EDC6F41, 0xFFFFFFFF, 1, 1, 0xFFFFFFFF, 0xE3069283),
    "CRC-32/BZIP2": (32, 0x04C11DB7, 0xFFFFFFFF, 0, 0, 0xFFFFFFFF, 0xFC891918),
    "CRC-16/ARC": (16, 0x8005, 0x0000, 1, 1, 0x0000, 0xBB3D),
    "CRC-16/XMODEM": (16, 0x1021, 0x0000, 0, 0, 0x0000, 0x31C3),
    "CRC-16/IBM-3740": (16, 0x1021, 0xFFFF, 0, 0, 0x0000, 0x29B1),
    "CRC-8/SMBUS": (8, 0x07, 0x00, 0, 0, 0x00, 0xF4),
}


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_crc_is_generic_over_the_catalogue_parameters(host_build, tmp_path, name) -> None:
    """A protocol that changes its frame check (e.g. to a 32-bit CRC) is a regeneration."""
    w, poly, init, refin, refout, xorout, check = CATALOGUE[name]
    main = tmp_path / "m.c"
    main.write_text('#include <stdio.h>\n#include "crc.h"\nint main(void){const unsigned char s[]="123456789";'
                    'crc_init();printf("%lx\\n",(unsigned long)crc_compute(s,9));return 0;}\n')
    exe = tmp_path / "crc"
    defs = [f"-DCRC_WIDTH={w}", f"-DCRC_POLY={poly}UL", f"-DCRC_INIT={init}UL", f"-DCRC_REFIN={refin}",
            f"-DCRC_REFOUT={refout}", f"-DCRC_XOROUT={xorout}UL"]
    subprocess.run(["cc", *defs, f"-I{FIRMWARE_DIR / 'core'}", f"-I{host_build / 'gen'}",
                    str(FIRMWARE_DIR / "core" / "crc.c"), str(main), "-o", str(exe)], check=True)
    assert int(subprocess.run([str(exe)], capture_output=True, text=True).stdout, 16) == check


def _boot(core) -> list:
    return core.frames(core.cmd("boot 3735928559 0"))


def test_boot_sends_hello_then_event_boot_with_seq_from_zero(core) -> None:
    f = _boot(core)
    assert [m.name for m in f] == ["HELLO", "EVENT"] and [m.seq for m in f] == [0, 1]
    assert f[0]["boot_id"] == 0xDEADBEEF and f[0]["protocol_version"] == VECTORS_VERSION()
    assert f[1]["code"] == 1 and f[1]["arg"] == 0xDEADBEEF


def VECTORS_VERSION() -> int:
    return tomllib.loads((REPO / "protocols" / f"{VECTORS['protocol']}.toml").read_text())["protocol"]["version"]


def test_statuses_of_every_kind(core) -> None:
    _boot(core)
    seen = {}
    seen["hello"] = [m.name for m in core.frames(core.send(10, "HELLO_REQ"))]
    assert seen["hello"] == ["HELLO", "ACK"]
    ack = core.frames(core.send(20, "SET_DUTIES", {"duty": [100, 0, 0, 0]}, seq=77))[-1]
    assert (ack["cmd_id"], ack["cmd_seq"], ack["status"], ack["time"]) == (0x10, 77, 0, 20)
    bad = core.codec.encode_raw("SET_DUTIES", 5, {"duty": [0, 0, 0, 0]})[:-2] + (-32768).to_bytes(2, "little", signed=True)
    from omnibench.link.framing import encode_frame
    out = core.cmd(f"rx 30 {encode_frame(bad, core.codec.crc).hex()}")
    assert core.frames(out)[-1]["status"] == 3 and core.duties(out) == []  # BAD_VALUE, nothing changed
    short = core.codec.encode_raw("CONFIGURE", 6, {"watchdog": 500, "telemetry_rate": 0})[:-1]
    assert core.frames(core.cmd(f"rx 40 {encode_frame(short, core.codec.crc).hex()}"))[-1]["status"] == 2
    for name in ("SIM_GET_TRUTH",):
        assert core.frames(core.send(50, name))[-1]["status"] == 1  # real firmware: UNSUPPORTED
    odd = bytes([0x7F, 1, 0])  # unknown id
    assert core.frames(core.cmd(f"rx 60 {encode_frame(odd, core.codec.crc).hex()}"))[-1]["status"] == 1
    tel = bytes([0x82, 1, 0])  # a board -> host id
    assert core.frames(core.cmd(f"rx 70 {encode_frame(tel, core.codec.crc).hex()}"))[-1]["status"] == 1
    for wd, rate in ((19, 0), (10001, 0), (500, 501)):  # the codec refuses these: build them by hand
        body = bytes([0x12, 9, 0]) + wd.to_bytes(2, "little") + rate.to_bytes(2, "little")
        assert core.frames(core.cmd(f"rx 80 {encode_frame(body, core.codec.crc).hex()}"))[-1]["status"] == 3


def test_watchdog_latches_and_refuses_until_cleared(core) -> None:
    _boot(core)
    core.send(0, "CONFIGURE", {"watchdog": 100, "telemetry_rate": 0})
    assert core.duties(core.send(1000, "SET_DUTIES", {"duty": [1000, 2000, 3000, 4000]})) == [(1000, 2000, 3000, 4000)]
    assert core.frames(core.cmd("poll 100999")) == []
    out = core.cmd("poll 101000")
    assert core.duties(out) == [(0, 0, 0, 0)] and "enable 0" in out
    ev = core.frames(out)[0]
    assert ev.name == "EVENT" and ev["code"] == 2 and ev["arg"] == 100
    out = core.send(102000, "SET_DUTIES", {"duty": [1000] * 4})
    assert core.frames(out)[-1]["status"] == 4 and all(d == (0, 0, 0, 0) for d in core.duties(out))
    assert core.frames(core.send(103000, "STOP"))[-1]["status"] == 0  # always accepted
    core.send(104000, "CLEAR_FAULTS")
    assert core.duties(core.send(105000, "SET_DUTIES", {"duty": [5] * 4}))[-1] == (5, 5, 5, 5)


def test_watchdog_after_a_long_idle_without_frames(core) -> None:
    """A board left idle (telemetry off, nothing sent) for more than half the 32-bit µs wrap
    still stamps frames with the time and still stops the wheels when the host goes silent."""
    _boot(core)
    t = 2_200_000_000  # 36.7 min after boot, no frame in between, the loop polling the core
    for when in range(0, t + 1, 100_000_000):
        assert core.frames(core.cmd(f"poll {when}")) == []
    ack = core.frames(core.send(t, "SET_DUTIES", {"duty": [1000] * 4}))[-1]
    assert ack["time"] == t
    out = core.cmd(f"poll {t + 500_000}")
    assert core.duties(out) == [(0, 0, 0, 0)]


def test_telemetry_on_the_configured_schedule_with_applied_duties(core) -> None:
    _boot(core)
    core.cmd("enc 1 -2 3 -4")
    core.send(1000, "CONFIGURE", {"watchdog": 500, "telemetry_rate": 200})
    core.send(2000, "SET_DUTIES", {"duty": [10, -10, 20, -20]})
    times = []
    for t in range(2000, 30000, 700):
        for m in core.frames(core.cmd(f"poll {t}")):
            assert m.name == "TELEMETRY"
            times.append(m["time"])
            assert m["encoder"] == (1, -2, 3, -4) and m["duty"] == (10, -10, 20, -20) and m["battery_voltage"] == 24700
    assert times == list(range(6000, 30000, 5000))


def test_frames_leave_in_board_time_order(core) -> None:
    """A sample latched before a host frame or the watchdog is sent before the ACK or EVENT
    stamped later (the host drops a frame whose time runs backwards); the watchdog stops the
    motors before either is sent."""
    _boot(core)
    core.send(1000, "CONFIGURE", {"watchdog": 100, "telemetry_rate": 200})  # samples at 6000, 11000, ...
    core.send(2000, "SET_DUTIES", {"duty": [10, 10, 10, 10]})
    out = core.frames(core.send(6400, "PING"))  # the 6000 sample latched; the loop saw the PING first
    assert [m.name for m in out] == ["TELEMETRY", "ACK"] and (out[0]["time"], out[1]["time"]) == (6000, 6400)
    for t in range(11000, 102000, 5000):
        core.cmd(f"poll {t}")
    out = core.frames(core.cmd("poll 106400"))  # 100 ms after the PING; the 106000 sample latched
    assert [(m.name, m["time"]) for m in out] == [("TELEMETRY", 106000), ("EVENT", 106400)]
    assert out[0]["duty"] == (0, 0, 0, 0) and out[1]["arg"] == 100  # stopped before anything was sent


def test_garbage_and_bit_flips_never_move_a_motor(core) -> None:
    """Random bytes and 1-3 flipped bits in every kind of host frame (duties zero): no duty ever."""
    _boot(core)
    rng = random.Random(14)
    frames = [core.codec.frame_raw(n, i, r) for i, (n, r) in enumerate([
        ("STOP", {}), ("PING", {}), ("CONFIGURE", {"watchdog": 500, "telemetry_rate": 100}),
        ("SET_DUTIES", {"duty": [0, 0, 0, 0]}), ("CLEAR_FAULTS", {}), ("RESET_ENCODERS", {})])]
    moved = []
    for k in range(3000):
        if k % 3 == 0:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 80)))
        else:
            data = bytearray(rng.choice(frames))
            for _ in range(rng.randint(1, 3)):
                data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
            data = bytes(data)
        moved += [d for d in core.duties(core.cmd(f"rx {k * 100} {data.hex()}")) if any(d)]
    assert moved == []
    # and the link still works afterwards
    assert core.frames(core.send(400000, "PING", seq=9))[-1]["cmd_seq"] == 9


def test_a_protocol_change_is_a_regeneration(tmp_path) -> None:
    """The next version of the description (another 32-bit CRC, an extra TELEMETRY field),
    dropped beside today's: make picks the highest version, and the host codec built from it
    reads the core's frames."""
    import re

    from omnibench.link.codec import Codec
    from omnibench.link.spec import load_protocol
    from omnibench.sim.firmware.build import make
    from tests.firmware.conftest import need

    need("host")
    (current,) = sorted((REPO / "protocols").glob("omnibot-board-v*.toml"))
    text = current.read_text()
    version = int(re.search(r"^version = (\d+)$", text, re.M).group(1))
    nxt = version + 1
    text = text.replace(f"version = {version}\n", f"version = {nxt}\n", 1)
    crc = text[text.index("\n[crc]\n") + 1:text.index("\n[board]\n") + 1]
    text = text.replace(crc, '[crc]\nname = "CRC-32/ISCSI"\nwidth = 32\npoly = 0x1EDC6F41\ninit = 0xFFFFFFFF\n'
                        'refin = true\nrefout = true\nxorout = 0xFFFFFFFF\ncheck = 0xE3069283\n'
                        'covers = "header and payload"\nbyte_order = "little"\n\n')
    field = '  { name = "faults", type = "u8", flags = "faults", doc = "latched fault flags" },\n'
    assert field in text
    text = text.replace(field, field + '  { name = "temperature", type = "i16", scale = 0.01, unit = "K" },\n')
    protos = tmp_path / "protocols"
    protos.mkdir()
    (protos / current.name).write_text(current.read_text())
    (protos / f"omnibot-board-v{nxt}.toml").write_text(text)
    build = make("host", tmp_path / "build", PROTOCOL=str(protos))
    codec = Codec(load_protocol(protos / f"omnibot-board-v{nxt}.toml"))
    c = CoreHost(build)
    c.codec = codec
    try:
        assert int(c.cmd("crc " + b"123456789".hex())[0].split()[1], 16) == 0xE3069283
        hello, event = c.frames(c.cmd("boot 99 0"))
        assert hello["protocol_version"] == nxt and event["arg"] == 99
        c.send(10, "CONFIGURE", {"watchdog": 500, "telemetry_rate": 100})
        tel = c.frames(c.cmd("poll 10010"))[0]  # decoded through the new CRC in CoreHost.frames
        assert tel.name == "TELEMETRY" and tel["temperature"] == 0 and tel["battery_voltage"] == 24700
    finally:
        c.close()


def test_missing_tools_are_named(monkeypatch) -> None:
    """Without the toolchain the firmware tests skip (conftest.need) and the CLI says what to install."""
    import shutil

    from omnibench.errors import UserError
    from omnibench.sim.firmware import build

    monkeypatch.setattr(shutil, "which", lambda name: None)
    assert "avr-gcc" in build.missing_tools("avr")
    with pytest.raises(UserError, match="apt-get install .*simavr"):
        build.require("avr", "fil")


def test_fault_inputs_latch_stop_and_report(core) -> None:
    """An e-stop / undervoltage / overcurrent input latches its bit, stops, drops the enable line."""
    _boot(core)
    core.send(0, "SET_DUTIES", {"duty": [100] * 4})
    core.cmd("fault 16")  # FAULTS_ESTOP
    out = core.cmd("poll 1000")
    ev = core.frames(out)[0]
    assert (ev.name, ev["code"], ev["arg"]) == ("EVENT", 3, 16)
    assert core.duties(out) == [(0, 0, 0, 0)] and "enable 0" in out
    assert core.frames(core.cmd("poll 2000")) == []  # latched once, not re-reported
    core.send(3000, "CLEAR_FAULTS")
    assert core.frames(core.cmd("poll 4000"))[0]["arg"] == 16  # still pressed: latches again
    core.cmd("fault 0")
    core.send(5000, "CLEAR_FAULTS")
    assert core.frames(core.cmd("poll 6000")) == []
    assert core.frames(core.send(7000, "SET_DUTIES", {"duty": [5] * 4}))[-1]["status"] == 0
