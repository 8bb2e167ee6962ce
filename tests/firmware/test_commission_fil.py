"""`omnibench commission` against the firmware in simavr, wired as the 2019 robot: a build with
a swapped channel, an inverted encoder or swapped chip selects is found, and commission names
the build setting that fixes it."""

from __future__ import annotations

import re

import pytest

from omnibench.bench.commission import commission
from omnibench.bench.wiring import load_wiring
from omnibench.sim.firmware.build import make
from omnibench.sim.firmware.robot import load_robot
from tests.simserver import spawn_server

from .conftest import need

SLOTS = ("FL", "FR", "RL", "RR")
DEFAULT_MAP = {"FL": "128 2 -1", "FR": "128 1 -1", "RL": "129 1 1", "RR": "129 2 1"}


def person(settings: dict[str, str]):
    """A person at the robot: board channel k (the firmware's slot k, MOTOR_<slot>) turns the
    robot's wheel on that driver channel, forward if the build's sign and the wheel's sense agree."""
    robot = load_robot()
    state: dict[str, int] = {}

    def ask(question: str, choices: list[str]) -> str:
        m = re.match(r"Channel (\d) moved", question)
        if m:
            k = int(m.group(1)) - 1
            addr, ch, sign = (int(x) for x in settings.get(f"MOTOR_{SLOTS[k]}", DEFAULT_MAP[SLOTS[k]]).split())
            w = next(i for i, wh in enumerate(robot.wheels) if (wh.driver, wh.channel) == (addr, ch))
            state["dir"] = sign * robot.wheels[w].sense
            return SLOTS[w].lower()
        return "forward" if state["dir"] > 0 else "backward"

    return ask


CASES = [
    ({"MOTOR_FL": "128 1 -1", "MOTOR_FR": "128 2 -1"}, {"motor_channel": (2, 1, 3, 4)},
     "MOTOR_FL must be today's MOTOR_FR"),
    ({"ENCODER_SIGNS": "1 -1 1 1"}, {"encoder_sign": (1, 1, 1, -1)}, "negate entry 4 of ENCODER_SIGNS"),
    # RL's chip (pin 48) counts up, RR's (49) down: read through each other's slot both signs flip
    ({"ENCODER_CS": "46 47 49 48"}, {"encoder_channel": (1, 2, 4, 3), "encoder_sign": (1, 1, -1, -1)},
     "entries 3 of ENCODER_CS and ENCODER_SIGNS must be today's entries 4 (the sign negated)"),
]


@pytest.mark.parametrize("settings, found, fix", CASES, ids=["swapped-channel", "inverted-encoder", "swapped-cs"])
def test_commission_finds_the_miswiring_and_names_the_setting(tmp_path, settings, found, fix) -> None:
    need("avr", "fil")
    make("all", tmp_path, BATTERY_CURRENT="none", **settings)
    make("fil", tmp_path)
    served = spawn_server(tmp_path, "--clock", "fast", "--seed", "8", "--firmware", str(tmp_path / "omnibot.elf"))
    said: list[str] = []
    try:
        commission(served.path, tmp_path / "wiring.toml", ask=person(settings), confirm=lambda q: None,
                   echo=said.append)
    finally:
        served.stop()
    w = load_wiring(tmp_path / "wiring.toml")
    straight = {"motor_channel": (1, 2, 3, 4), "motor_sign": (1, 1, 1, 1), "encoder_channel": (1, 2, 3, 4),
                "encoder_sign": (1, 1, 1, 1)}
    assert all(getattr(w, k) == found.get(k, v) for k, v in straight.items()), w
    hint = [s for s in said if s.startswith("to fix it in the Omnibot firmware")]
    assert len(hint) == 1 and fix in hint[0], said
