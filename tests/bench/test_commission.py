"""`omnibench commission` on a mis-wired simulated robot: the map found is the world's wiring,
procedures driven through it behave as on a straight-wired robot, and a wrong map is refused."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from omnibench.bench.commission import commission
from omnibench.bench.wiring import load_wiring
from omnibench.errors import UserError
from omnibench.runs import read_run
from omnibench.sim.world import world_from_url

MISWIRED = "sim://?wiring=2,1,3,-4&encoder_wiring=2,1,3,4&seed=6"
FORWARD = Path(__file__).parent / "person_procedures" / "forward.toml"
WHEELS = ["fl", "fr", "rl", "rr"]


def person_watching(url: str, lie: dict[int, str] | None = None):
    """Answers what a person sees on the robot of `url`: channel k turns wheel |wiring[k]|."""
    wiring = world_from_url(url)[1].wiring
    state: dict[str, int] = {}

    def ask(question: str, choices: list[str]) -> str:
        m = re.match(r"Channel (\d) moved", question)
        if m:
            state["ch"] = int(m.group(1)) - 1
            return (lie or {}).get(state["ch"], WHEELS[abs(wiring[state["ch"]]) - 1])
        return "forward" if wiring[state["ch"]] > 0 else "backward"

    return ask


def test_commission_finds_the_miswiring_and_procedures_use_it(tmp_path) -> None:
    out = tmp_path / "wiring.toml"
    commission(MISWIRED, out, ask=person_watching(MISWIRED), confirm=lambda q: None, echo=lambda s: None)
    w = load_wiring(out)
    assert w.motor_channel == (2, 1, 3, 4) and w.motor_sign == (1, 1, 1, -1)
    assert w.encoder_channel == (2, 1, 3, 4) and w.encoder_sign == (1, 1, 1, 1)
    assert w.motor_current_sensor and w.battery_current_sensor and 20 < w.battery_voltage_V < 30

    from omnibench.cli import main

    for name, extra in (("wired", ["--wiring", str(out)]), ("raw", [])):
        main(["forward", "--port", MISWIRED, "--procedure", str(FORWARD), "--out", str(tmp_path / name), *extra])
    wired = read_run(next((tmp_path / "wired").iterdir()))
    raw = read_run(next((tmp_path / "raw").iterdir()))
    assert wired.steps["no_slip"].all()  # drives straight: encoders agree with the tape
    assert (wired.steps["encoder_distance"] * wired.steps["direction"] > 0.1).all()
    assert wired.metadata["wiring"]["motor_sign"] == [1, 1, 1, -1]
    assert not raw.steps["no_slip"].any()  # the same robot without its map does not


def test_a_wrong_map_is_refused_and_nothing_written(tmp_path) -> None:
    out = tmp_path / "wiring.toml"
    with pytest.raises(UserError, match=r"wrong map.*FL named for channels 2 and 3"):
        commission(MISWIRED, out, ask=person_watching(MISWIRED, lie={2: "fl"}), confirm=lambda q: None,
                   echo=lambda s: None)
    assert not out.exists()


def test_a_wiring_file_of_another_board_is_refused(tmp_path, capsys) -> None:
    from omnibench.cli import main

    f = tmp_path / "wiring.toml"
    f.write_text('board_id = "DEADBEEF"\nmotor_channel = [2, 1, 3, 4]\n', encoding="utf-8")
    with pytest.raises(SystemExit) as exc:
        main(["forward", "--port", MISWIRED, "--procedure", str(FORWARD), "--out", str(tmp_path / "r"),
              "--wiring", str(f)])
    assert exc.value.code == 2
    assert "commissioned on board DEADBEEF" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
