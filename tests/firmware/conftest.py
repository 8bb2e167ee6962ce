"""Firmware tests: build what they need once per session; skip with one line if a tool is missing."""

from __future__ import annotations

import pytest

from omnibench.sim.firmware.build import make, missing_tools


def need(*purposes: str) -> None:
    """Skip the test (one line naming the tools) unless every tool of `purposes` is present."""
    miss = missing_tools(*purposes)
    if miss:
        pytest.skip(f"firmware tools missing: {', '.join(miss)}")


@pytest.fixture(scope="session")
def host_build(tmp_path_factory):
    """The protocol core built for this machine (build/host/core_host)."""
    need("host")
    return make("host", tmp_path_factory.mktemp("fw-host"))


@pytest.fixture(scope="session")
def fil_elf(tmp_path_factory):
    """The firmware for the robot with Hall current sensors (the conformance tests ask for
    BATTERY_CURRENT), and the simavr harness."""
    need("avr", "fil")
    build = make("all", tmp_path_factory.mktemp("fw-fil"), BATTERY_CURRENT="hall", MOTOR_CURRENT="hall")
    make("fil", build)
    return build / "omnibot.elf"


@pytest.fixture(scope="session")
def default_build(tmp_path_factory):
    """The firmware with every build setting at its default (the robot as wired in 2019), and
    pinrec, the bare-chip pin recorder (firmware/sim/pinrec.c)."""
    need("avr", "fil")
    build = make("all", tmp_path_factory.mktemp("fw-default"))
    make("pinrec", build)
    make("fil", build)
    return build
