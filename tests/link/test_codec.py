"""Protocol description, CRC, framing and codec: committed vectors and property tests."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from omnibench.errors import UserError
from omnibench.link.codec import Codec, CodecError
from omnibench.link.framing import Crc, decode_chunk
from omnibench.link.spec import load_protocol
from omnibench.sim.board import SimBoard

VECTORS = json.loads(Path(__file__).with_name("vectors.json").read_text())["vectors"]
SPEC = load_protocol("omnibot-board-v2")
CODEC = Codec(SPEC)


def crc32_iso_hdlc_bitwise(data: bytes) -> int:
    """Reference CRC-32/ISO-HDLC written from its definition (poly 0x04C11DB7 reflected =
    0xEDB88320, init and final XOR 0xFFFFFFFF)."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xEDB88320 if crc & 1 else crc >> 1
    return crc ^ 0xFFFFFFFF


def cobs_decode_reference(enc: bytes) -> bytes:
    """Reference COBS decoder written from the algorithm's definition."""
    out, i = bytearray(), 0
    while i < len(enc):
        code = enc[i]
        assert code != 0
        out += enc[i + 1 : i + code]
        i += code
        if code != 0xFF and i < len(enc):
            out.append(0)
    return bytes(out)


def test_crc_variant_and_check_value() -> None:
    assert SPEC.crc.name == "CRC-32/ISO-HDLC" and SPEC.version == 2
    assert SPEC.crc.check == 0xCBF43926
    assert Crc(SPEC.crc).checksum(b"123456789") == 0xCBF43926
    assert crc32_iso_hdlc_bitwise(b"123456789") == 0xCBF43926


def test_vectors_cover_every_message() -> None:
    assert {v["message"] for v in VECTORS} == {m.name for m in SPEC.messages}


@pytest.mark.parametrize("v", VECTORS, ids=lambda v: v["message"])
def test_vector_is_independently_valid(v: dict) -> None:
    wire = bytes.fromhex(v["wire_hex"])
    assert wire[-1] == 0 and 0 not in wire[:-1]
    data = cobs_decode_reference(wire[:-1])
    body, crc = data[:-4], int.from_bytes(data[-4:], "little")
    assert body.hex() == v["body_hex"]
    assert crc == crc32_iso_hdlc_bitwise(body)
    assert body[0] == v["id"] and int.from_bytes(body[1:3], "little") == v["seq"]


@pytest.mark.parametrize("v", VECTORS, ids=lambda v: v["message"])
def test_host_codec_matches_vector(v: dict) -> None:
    assert CODEC.frame_raw(v["message"], v["seq"], v["raw"]).hex() == v["wire_hex"]
    bodies = CODEC.deframer().feed(bytes.fromhex(v["wire_hex"]))
    assert len(bodies) == 1
    msg = CODEC.decode_raw(bodies[0])
    assert msg.name == v["message"] and msg.seq == v["seq"]
    for k, val in v["raw"].items():
        assert msg.fields[k] == (tuple(val) if isinstance(val, list) else val)


@pytest.fixture(scope="module")
def sim_board() -> SimBoard:
    return SimBoard()


@pytest.mark.parametrize("v", [v for v in VECTORS if v["direction"] == "board_to_host"], ids=lambda v: v["message"])
def test_sim_board_encodes_vector(sim_board: SimBoard, v: dict) -> None:
    sim_board.tx_seq = v["seq"]
    assert sim_board.encode_tx(v["message"], v["raw"]).hex() == v["wire_hex"]


@pytest.mark.parametrize("v", [v for v in VECTORS if v["direction"] == "host_to_board"], ids=lambda v: v["message"])
def test_sim_board_decodes_vector(v: dict) -> None:
    board = SimBoard()
    board.take_output()
    board.feed(bytes.fromhex(v["wire_hex"]))
    name, seq, raw = board.received[-1]
    assert (name, seq) == (v["message"], v["seq"])
    for k, val in v["raw"].items():
        assert raw[k] == (tuple(val) if isinstance(val, list) else val)
    acks = [CODEC.decode(b) for b in CODEC.deframer().feed(board.take_output())]
    ack = [m for m in acks if m.name == "ACK"]
    assert len(ack) == 1 and ack[0]["cmd_seq"] == v["seq"] and ack[0]["cmd_id"] == v["id"]
    assert ack[0]["status"] == SPEC.enums["status"]["OK"]


def test_telemetry_fits_48_wire_bytes() -> None:
    assert CODEC.wire_size("TELEMETRY") <= 48
    tel = next(v for v in VECTORS if v["message"] == "TELEMETRY")
    assert len(bytes.fromhex(tel["wire_hex"])) <= 48


# ----------------------------------------------------------------------------- properties
def _raw_strategy(name: str):
    m = SPEC.message(name)
    parts = {}
    for f in m.fields:
        lo, hi = f.raw_range
        one = st.integers(lo, hi)
        parts[f.name] = st.lists(one, min_size=f.count, max_size=f.count) if f.count > 1 else one
    return st.fixed_dictionaries(parts)


MESSAGES = [m.name for m in SPEC.messages]


@settings(max_examples=300, deadline=None)
@given(data=st.data(), name=st.sampled_from(MESSAGES), seq=st.integers(0, 0xFFFF))
def test_raw_round_trip(data, name: str, seq: int) -> None:
    raw = data.draw(_raw_strategy(name))
    wire = CODEC.frame_raw(name, seq, raw)
    assert 0 not in wire[:-1]
    msg = CODEC.decode_raw(decode_chunk(wire[:-1], CODEC.crc))
    assert (msg.name, msg.seq) == (name, seq)
    for k, val in raw.items():
        assert msg.fields[k] == (tuple(val) if isinstance(val, list) else val)


@settings(max_examples=200, deadline=None)
@given(duty=st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4),
       current=st.lists(st.floats(-32.0, 32.0), min_size=4, max_size=4),
       volts=st.floats(0.0, 65.0), t=st.floats(0.0, 4294.0))
def test_physical_round_trip_within_resolution(duty, current, volts, t) -> None:
    values = {"time": t, "encoder": [1, 2, 3, 4], "motor_current": current, "battery_voltage": volts,
              "battery_current": current[0], "faults": 0, "duty": duty}
    msg = CODEC.decode(CODEC.encode("TELEMETRY", 7, values))
    assert all(abs(a - b) <= 0.5 / 32767 + 1e-12 for a, b in zip(msg["duty"], duty))
    assert all(abs(a - b) <= 0.0005 + 1e-9 for a, b in zip(msg["motor_current"], current))
    assert abs(msg["battery_voltage"] - volts) <= 0.0005 + 1e-9
    assert abs(msg["time"] - t) <= 0.5e-6 + 1e-9


@settings(max_examples=200, deadline=None)
@given(garbage=st.binary(max_size=40), seq=st.integers(0, 0xFFFF), with_delimiter=st.booleans())
def test_frame_after_garbage_is_recovered(garbage: bytes, seq: int, with_delimiter: bool) -> None:
    """Line noise before a frame costs at most the noise: the frame itself is accepted."""
    if not with_delimiter:
        garbage = garbage.replace(b"\x00", b"\x01")
    wire = CODEC.frame_raw("ACK", seq, {"cmd_id": 2, "cmd_seq": seq, "status": 0, "time": 99})
    d = CODEC.deframer()
    bodies = d.feed(garbage + (b"\x00" if with_delimiter else b"") + wire)
    assert [CODEC.decode_raw(b).seq for b in bodies][-1:] == [seq]


@given(cut=st.integers(1, 40))
def test_a_reader_that_starts_mid_frame_counts_no_link_error(cut: int) -> None:
    """Opening a port (or flushing its input) while the board sends telemetry starts the stream
    inside a frame: after `resync` that tail is dropped without a CRC or framing error, a whole
    frame at the cut is delivered, and the errors of the stream after it still count."""
    frames = [CODEC.frame_raw("ACK", seq, {"cmd_id": 2, "cmd_seq": seq, "status": 0, "time": 99}) for seq in range(3)]
    stream = b"".join(frames)
    cut = min(cut, len(frames[0]) - 2)  # at least one byte of the first frame is left
    d = CODEC.deframer()
    d.resync()
    bodies = d.feed(stream[cut:])
    assert [CODEC.decode_raw(b).seq for b in bodies] == [1, 2]
    assert d.stats.crc_errors == 0 and d.stats.framing_errors == 0
    # the same bytes read without resync: the tail is an error (what a clean link used to report)
    plain = CODEC.deframer()
    assert [CODEC.decode_raw(b).seq for b in plain.feed(stream[cut:])] == [1, 2]
    assert plain.stats.crc_errors + plain.stats.framing_errors == 1
    # a cut exactly at a frame boundary loses nothing
    d.resync()
    assert [CODEC.decode_raw(b).seq for b in d.feed(stream)] == [0, 1, 2]
    # after the first chunk, a corrupted frame counts again
    bad = bytearray(frames[1])
    bad[2] ^= 0x5A
    d.feed(bytes(bad))
    assert d.stats.crc_errors + d.stats.framing_errors == 1


@settings(max_examples=200, deadline=None)
@given(pos=st.integers(0, 40), flip=st.integers(1, 255))
def test_any_single_corrupted_byte_is_rejected(pos: int, flip: int) -> None:
    wire = bytearray(CODEC.frame_raw("TELEMETRY", 3, next(v for v in VECTORS if v["message"] == "TELEMETRY")["raw"]))
    wire[pos] ^= flip
    d = CODEC.deframer()
    bodies = d.feed(bytes(wire) + b"\x00")
    original = CODEC.encode_raw("TELEMETRY", 3, next(v for v in VECTORS if v["message"] == "TELEMETRY")["raw"])
    assert original not in bodies
    assert bodies == []


def test_out_of_range_value_is_refused() -> None:
    with pytest.raises(CodecError):
        CODEC.encode("SET_DUTIES", 1, {"duty": [1.5, 0, 0, 0]})
    with pytest.raises(CodecError):
        CODEC.encode("CONFIGURE", 1, {"watchdog": 0.001, "telemetry_rate": 100})


def test_malformed_description_gives_one_line_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[protocol]\nname = 'x'\n")
    with pytest.raises(UserError, match="lacks"):
        load_protocol(bad)
    bad.write_text("not toml [")
    with pytest.raises(UserError, match="not valid TOML"):
        load_protocol(bad)


def test_a_different_firmware_is_described_not_coded(tmp_path: Path) -> None:
    """A firmware with a wider TELEMETRY (extra temperature field) needs only a new file."""
    text = SPEC.path.read_text().replace(
        '{ name = "faults", type = "u8", flags = "faults", doc = "latched fault flags" },',
        '{ name = "faults", type = "u8", flags = "faults", doc = "latched fault flags" },\n'
        '  { name = "temperature", type = "i16", scale = 0.01, unit = "degC" },')
    other = tmp_path / "other-fw.toml"
    other.write_text(text.replace("version = 2\n", "version = 7\n", 1))
    spec = load_protocol(other)
    assert spec.version == 7 and spec.message("TELEMETRY").payload_size == 35
    codec = Codec(spec)
    raw = dict(next(v for v in VECTORS if v["message"] == "TELEMETRY")["raw"], temperature=-1234)
    msg = codec.decode(decode_chunk(codec.frame_raw("TELEMETRY", 1, raw)[:-1], codec.crc))
    assert msg["temperature"] == pytest.approx(-12.34)
