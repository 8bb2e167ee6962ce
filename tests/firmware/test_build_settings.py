"""Build settings are tracked: `make VAR=value` rebuilds what depends on it, `make` prints the
settings in force, a bad value is one line; the board then reports what it was built with."""

from __future__ import annotations

import subprocess

import pytest

from omnibench.link.codec import Codec
from omnibench.link.framing import Deframer
from omnibench.link.spec import load_protocol
from omnibench.sim.firmware.build import FIRMWARE_DIR, make

from .conftest import need


def hello_of(elf) -> dict:
    """The HELLO the firmware sends by itself after boot, read off its UART0 in simavr."""
    from omnibench.sim.firmware.fil import Harness

    chip = Harness(elf)
    try:
        chip.run_until(16_000_000 // 20)  # 50 ms
        data, _ = chip.host_read()
    finally:
        chip.close()
    codec = Codec(load_protocol())
    for body in Deframer(codec.crc, codec.spec.max_frame_bytes).feed(data):
        msg = codec.decode(body)
        if msg.name == "HELLO":
            return dict(msg.fields)
    raise AssertionError(f"no HELLO in {data.hex()}")


def run_make(build, *settings: str) -> subprocess.CompletedProcess:
    """make -C firmware BUILD=build ARGS (targets and VAR=value)."""
    return subprocess.run(["make", "-C", str(FIRMWARE_DIR), f"BUILD={build}", *settings],
                          capture_output=True, text=True)


def test_changing_a_setting_rebuilds_and_the_board_reports_it(tmp_path) -> None:
    need("avr", "fil")
    make("all", tmp_path, BOARD_ID="4242")
    make("fil", tmp_path)
    elf = tmp_path / "omnibot.elf"
    assert hello_of(elf)["board_id"] == 4242
    before = elf.stat().st_mtime_ns
    again = run_make(tmp_path, "BOARD_ID=4242")  # same settings: nothing to rebuild
    assert again.returncode == 0 and "avr-gcc" not in again.stdout and elf.stat().st_mtime_ns == before
    assert "BOARD_ID=4242" in again.stdout and "SABERTOOTH_S1_PIN=6" in again.stdout  # settings in force
    changed = run_make(tmp_path, "BOARD_ID=777")
    assert changed.returncode == 0 and "avr-gcc" in changed.stdout
    assert hello_of(elf)["board_id"] == 777


@pytest.mark.parametrize("setting, words", [
    ("MOTOR_FL=128 3 -1", "MOTOR_FL"), ("SABERTOOTH_S1_PIN=5", "SABERTOOTH_S1_PIN"),
    ("ENCODER_CS=46 46 48 49", "ENCODER_CS"), ("BOARD_ID=twelve", "BOARD_ID"),
])
def test_a_bad_setting_is_one_line_naming_it(tmp_path, setting, words) -> None:
    need("avr")
    r = run_make(tmp_path, setting)
    assert r.returncode != 0
    lines = [x for x in r.stderr.splitlines() if x.startswith("bad build setting")]
    assert len(lines) == 1 and words in lines[0] and "Traceback" not in r.stderr


def test_serve_without_the_harness_library_says_run_make_fil(tmp_path, monkeypatch, capsys) -> None:
    """`sim serve --firmware` with no libomnibot_fil.so anywhere: one line, not an OSError."""
    need("avr", "fil")
    import omnibench.sim.firmware.fil as fil
    from tests.bench.test_end_to_end import omnibench

    make("all", tmp_path)
    monkeypatch.setattr(fil, "FIRMWARE_DIR", tmp_path / "nowhere")
    code, _, err = omnibench(capsys, "sim", "serve", "--firmware", str(tmp_path / "omnibot.elf"))
    assert code != 0 and "run make -C firmware fil" in err and "Traceback" not in err and "OSError" not in err
    assert len(err.strip().splitlines()) == 1, err


def test_make_fil_without_the_simavr_headers_names_the_packages(tmp_path) -> None:
    r = run_make(tmp_path, "fil", "SIMAVR_INC=/nonexistent")
    assert r.returncode != 0
    assert "apt-get install libsimavr-dev libelf-dev pkg-config" in r.stderr
