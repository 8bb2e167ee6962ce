"""The board conformance tests of tests/link, unchanged, against the firmware in simavr.

`omnibench sim serve --firmware` runs the firmware built for the ATmega2560 on a simulated
chip wired as the robot is (omnibench/sim/firmware/robots/omnibot-2019-hall.toml: the 2019
wiring with the Hall current sensors these tests ask for), with the project's plant as its
robot; the tests talk to it through the pty, as to the real board (same Board client, same
serial code path).
"""

from __future__ import annotations

import pytest

from omnibench.sim.testing import spawn_server
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
