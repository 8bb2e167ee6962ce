"""The rig's drivers behave as Dimension Engineering documents them, and the firmware copes:
the serial timeout is lost in a driver power cycle and comes back within a second; autobauding
drivers take their rate from the first 0xAA (so a 38400 build drives them) and need a new one
after a power cycle."""

from __future__ import annotations

import pytest

from omnibench.sim.firmware.build import make
from omnibench.sim.world import World

from .conftest import need


def rig_for(elf, robot="omnibot-2019"):
    from omnibench.sim.firmware.board import FirmwareBoard

    return FirmwareBoard(World(seed=2), elf, robot)


def test_the_serial_timeout_survives_a_driver_power_cycle(default_build) -> None:
    rig = rig_for(default_build / "omnibot.elf")
    try:
        assert all(d.timeout_s == pytest.approx(0.3) for d in rig.line.drivers.values())
        rig.power_cycle_drivers()
        assert all(d.timeout_s is None for d in rig.line.drivers.values())
        rig.advance_to(rig.clock_us + 1_050_000)  # the firmware resends it every SABERTOOTH_SETUP_MS = 1 s
        assert all(d.timeout_s == pytest.approx(0.3) for d in rig.line.drivers.values())
    finally:
        rig.close()


@pytest.fixture()
def autobaud_robot(tmp_path):
    f = tmp_path / "autobaud.toml"
    f.write_text('extends = "omnibot-2019"\nname = "2019 wiring, autobauding drivers"\n'
                 '[sabertooth]\nmodel = "2x25 v1"\nautobaud = true\n', encoding="utf-8")
    return f


def test_autobauding_drivers_follow_the_first_0xaa_and_need_another_after_a_power_cycle(tmp_path, autobaud_robot) -> None:
    need("avr", "fil")
    make("all", tmp_path, SABERTOOTH_BAUD="38400")
    make("fil", tmp_path)
    rig = rig_for(tmp_path / "omnibot.elf", autobaud_robot)
    try:
        assert rig.chip.s1_baud == pytest.approx(38400, rel=0.01)
        assert rig.line.packets >= 6 and rig.wiring_findings() == []
        rig.power_cycle_drivers()
        assert rig.chip.s1_baud == 0
        rig.advance_to(rig.clock_us + 1_050_000)
        assert rig.chip.s1_baud == pytest.approx(38400, rel=0.01)
        assert all(d.timeout_s == pytest.approx(0.3) for d in rig.line.drivers.values())
    finally:
        rig.close()
    # the same build against stored-rate drivers (the robot as modelled): nothing gets through
    rig = rig_for(tmp_path / "omnibot.elf")
    try:
        assert rig.line.packets == 0 and "SABERTOOTH_BAUD" in " ".join(rig.wiring_findings())
    finally:
        rig.close()
