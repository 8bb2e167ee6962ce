"""The board conformance tests of tests/link, unchanged, against the firmware in simavr.

`omnibench sim serve --firmware` runs the firmware built for the ATmega2560 on a simulated
chip wired as the robot is (omnibench/sim/firmware/robots/omnibot-2019-hall.toml: the 2019
wiring with the Hall current sensors these tests ask for), with the project's plant as its
robot; the tests talk to it through the pty, as to the real board (same Board client, same
serial code path).
"""

from __future__ import annotations

import pytest

from tests.simserver import spawn_server
from tests.link import test_conformance as conformance


@pytest.fixture(scope="module")
def fil_served(fil_elf, tmp_path_factory):
    served = spawn_server(tmp_path_factory.mktemp("fil"), "--seed", "11", "--clock", "fast",
                          "--firmware", str(fil_elf), "--robot", "omnibot-2019-hall")
    yield served
    served.stop()
    assert served.status()["motors_stopped"] is True and served.status()["serving"] is False


@pytest.fixture()
def target(fil_served):
    """The firmware in simavr, served on a pseudo-terminal (fast clock: as fast as the host reads)."""
    return conformance.PtyTarget(fil_served)


class TestFirmwareConformance(conformance.TestBoardConformance):
    """Every test of TestBoardConformance, on the firmware."""


def test_reopening_drops_the_previous_sessions_telemetry(fil_served) -> None:
    conformance.test_reopening_drops_the_previous_sessions_telemetry(fil_served)


WHEELS = ("FL", "FR", "RL", "RR")
JOG = 0.3


def wheel_problems(url: str, status) -> list[str]:
    """Drive each wheel alone at +JOG with the robot upside down; what went wrong, each naming
    the build setting that governs it. `status()` is the rig's status: its `duties` are what
    each wheel's motor gets through the robot's wiring (a person watching the wheels)."""
    from omnibench.link.board import Board

    problems: list[str] = []
    with Board.open(url) as b:
        b.clear_faults()
        b.sim_set_world(mode="upside_down")
        b.configure(telemetry_hz=100)
        for w in range(4):
            u = [0.0] * 4
            u[w] = JOG
            before = b.wait(0.05)[-1]
            b.set_duties(u)
            after = b.wait(0.4)[-1]
            turned = status()["duties"]
            b.stop()
            b.wait(0.6)  # coast to rest
            moving = [k for k in range(4) if abs(turned[k]) > JOG / 2]
            if not moving:
                findings = "; ".join(status()["wiring_findings"]) or "nothing on the wires explains it"
                problems.append(f"duty +{JOG} on {WHEELS[w]}: no wheel turned ({findings})")
                continue
            if moving != [w]:
                got = ", ".join(f"{WHEELS[k]} {'forward' if turned[k] > 0 else 'backward'}" for k in moving)
                problems.append(f"duty +{JOG} on {WHEELS[w]} turned {got}: the firmware drives another driver "
                                f"channel than the robot's {WHEELS[w]} (build setting MOTOR_{WHEELS[w]})")
                continue
            if turned[w] < 0:
                problems.append(f"duty +{JOG} on {WHEELS[w]} turned it backward (the sign in build setting "
                                f"MOTOR_{WHEELS[w]})")
            counted = [after.encoder[k] - before.encoder[k] for k in range(4)]
            k = max(range(4), key=lambda i: abs(counted[i]))
            if abs(counted[k]) < 20:
                problems.append(f"{WHEELS[w]} turned, no counter moved ({counted})")
            elif k != w:
                problems.append(f"{WHEELS[w]} turned and the board counted it as {WHEELS[k]} "
                                f"(build setting ENCODER_CS: {WHEELS[w]}'s chip select)")
            elif counted[k] * (1 if turned[w] > 0 else -1) < 0:
                problems.append(f"{WHEELS[w]} turned forward and the board's count went down "
                                f"(build setting ENCODER_SIGNS)")
        b.sim_set_world(mode="ground")
    return problems


def test_each_wheel_turns_alone_forward_and_counts_up(fil_served) -> None:
    """The firmware drives and reads the robot as it is wired (2019): duty +0.3 on one wheel
    turns that wheel forward and nothing else, and its own counter counts up."""
    assert wheel_problems(fil_served.path, fil_served.status) == []
