"""The libFuzzer harness of the protocol core (firmware/fuzz/fuzz_core.c): a short run finds
nothing, and a core with a deliberate CRC bug is caught on a crafted frame."""

from __future__ import annotations

import json
import re
import subprocess
import zlib
from pathlib import Path

import pytest

from omnibench.sim.firmware.build import make
from tests.firmware.conftest import need

REPO = Path(__file__).resolve().parents[2]
VECTORS = json.loads((REPO / "tests" / "link" / "vectors.json").read_text())["vectors"]
SEED = b"\x01\x00\x00\x00"  # the harness's generator seed, then the host-link bytes


def _cobs(data: bytes) -> bytes:
    out, block = bytearray(), bytearray()
    for b in data:
        if b == 0:
            out += bytes([len(block) + 1]) + block
            block.clear()
        else:
            block.append(b)
            if len(block) == 254:
                out += b"\xff" + block
                block.clear()
    return bytes(out + bytes([len(block) + 1]) + block)


def _set_duties(crc_xor: int = 0) -> bytes:
    """The SET_DUTIES vector on the wire, its CRC-32 xored with crc_xor."""
    body = bytes.fromhex(next(v for v in VECTORS if v["message"] == "SET_DUTIES")["body_hex"])
    crc = (zlib.crc32(body) ^ crc_xor).to_bytes(4, "little")
    return _cobs(body + crc) + b"\x00"


@pytest.fixture(scope="module")
def fuzzer(tmp_path_factory) -> Path:
    need("fuzz")
    return make("fuzz", tmp_path_factory.mktemp("fw-fuzz")) / "fuzz"


@pytest.fixture(scope="module")
def bugged(tmp_path_factory) -> Path:
    need("fuzz")
    return make("fuzz", tmp_path_factory.mktemp("fw-fuzz-bug"), FUZZ_INJECT_BUG="1") / "fuzz"


def _run(folder: Path, *args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(folder / "fuzz_core"), *map(str, args)], capture_output=True,
                          text=True, cwd=folder, timeout=600)


def test_vector_frame_is_what_the_tests_build() -> None:
    wire = next(v for v in VECTORS if v["message"] == "SET_DUTIES")["wire_hex"]
    assert _set_duties().hex() == wire


def test_short_fuzz_run_finds_nothing(fuzzer: Path, tmp_path: Path) -> None:
    corpus = tmp_path / "corpus"
    corpus.mkdir()
    r = _run(fuzzer, "-runs=30000", "-seed=1", f"-artifact_prefix={tmp_path}/", corpus, fuzzer / "seeds")
    assert r.returncode == 0, r.stderr[-2000:]
    assert re.search(r"Done 30000 runs", r.stderr)
    assert "invariant broken" not in r.stderr and "runtime error" not in r.stderr and "ERROR:" not in r.stderr
    assert not list(tmp_path.glob("crash-*"))
    assert len(list(corpus.iterdir())) > 0


def test_good_core_takes_the_valid_frame_and_refuses_the_wrong_crc(fuzzer: Path, tmp_path: Path) -> None:
    for name, data in (("valid", _set_duties()), ("bad-crc", _set_duties(0xFF000000))):
        (tmp_path / name).write_bytes(SEED + data)
        r = _run(fuzzer, tmp_path / name)
        assert r.returncode == 0, r.stderr[-2000:]


def test_harness_catches_a_duty_moved_by_a_frame_with_a_wrong_crc(bugged: Path, tmp_path: Path) -> None:
    (tmp_path / "bad-crc").write_bytes(SEED + _set_duties(0xFF000000))
    r = _run(bugged, tmp_path / "bad-crc")
    assert r.returncode != 0
    assert "invariant broken: duties 32767 -32767 0 16384 applied without a valid frame" in r.stderr


def test_harness_catches_a_valid_frame_left_unacknowledged(bugged: Path, tmp_path: Path) -> None:
    (tmp_path / "valid").write_bytes(SEED + _set_duties())
    r = _run(bugged, tmp_path / "valid")
    assert r.returncode != 0
    assert "invariant broken: 0 ACKs for a valid frame" in r.stderr
