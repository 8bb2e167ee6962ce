"""Firmware built for another wiring fails against the robot as it is wired, naming the mismatch.

Each build below differs from the 2019 robot in one setting; the rig is the robot
(omnibench/sim/firmware/robots/omnibot-2019.toml) whatever the build says. The conformance
check of each wheel (test_fil_conformance.wheel_problems) must fail and name the setting.
"""

from __future__ import annotations

import pytest

from omnibench.sim.firmware.build import make
from tests.simserver import spawn_server

from .conftest import need
from .test_fil_conformance import wheel_problems

MISWIRED = [
    ({"SABERTOOTH_S1_PIN": "18"}, ["SABERTOOTH_S1_PIN=6"]),      # packets on TX1, S1 is on pin 6
    ({"SABERTOOTH_BAUD": "38400"}, ["SABERTOOTH_BAUD"]),         # the drivers store 9600
    ({"MOTOR_FL": "128 1 -1", "MOTOR_FR": "128 2 -1"}, ["MOTOR_FL", "MOTOR_FR"]),  # FL, FR channels swapped
    ({"MOTOR_RL": "129 1 -1"}, ["MOTOR_RL"]),                    # RL's sign
    ({"ENCODER_SIGNS": "1 1 1 -1"}, ["ENCODER_SIGNS"]),          # FR's counter sign
    ({"ENCODER_CS": "47 46 48 49"}, ["ENCODER_CS"]),             # FL and FR chip selects swapped
]


@pytest.mark.parametrize("settings, named", MISWIRED, ids=[n[0] for _, n in MISWIRED])
def test_a_miswired_build_fails_naming_the_setting(tmp_path, settings, named) -> None:
    need("avr", "fil")
    make("all", tmp_path, **settings)
    make("fil", tmp_path)
    served = spawn_server(tmp_path, "--clock", "fast", "--seed", "5", "--firmware", str(tmp_path / "omnibot.elf"))
    try:
        problems = wheel_problems(served.path, served.status)
    finally:
        served.stop()
    assert problems, f"a build with {settings} passed against the 2019 robot"
    assert all(any(n in p for n in named) for p in problems), problems  # each problem names one
    assert all(any(n in p for p in problems) for n in named), problems  # and each setting is named
    print("\n".join(problems))
