"""`omnibench sim serve`: the simulated Omnibot on a pseudo-terminal for other processes."""

from __future__ import annotations

import sys
from urllib.parse import urlencode

import click

from omnibench.cli.params import FINITE, NonEmptyPath
from omnibench.errors import UserError


@click.group(name="sim")
def command() -> None:
    """Run the simulated Omnibot board (see docs/simulator.md)."""


@command.command(name="serve")
@click.option("--world", "world_file", type=NonEmptyPath(dir_okay=False), help="World file (TOML): mode, masses, payload, sensors, hidden effects, faults.")
@click.option("--seed", type=int, default=None, help="Seed for sensor noise, faults and boot ids.")
@click.option("--clock", type=click.Choice(["realtime", "fast"]), default="realtime", show_default=True,
              help="realtime: board time follows the wall clock (x --speed); fast: as fast as the host reads.")
@click.option("--speed", type=FINITE, default=None, help="Simulated seconds per wall second: always on the realtime clock, while telemetry is "
              "off on the fast clock (a person at a prompt).")
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE",
              help="Any sim:// URL parameter, e.g. --set mode=upside_down --set drop=0.01 (repeatable).")
@click.option("--status-file", type=NonEmptyPath(dir_okay=False), help="Keep the board's duties/faults/state in this JSON file.")
@click.option("--ammeter", is_flag=True, help="Also serve a SCPI ammeter on a second pseudo-terminal (its path is line 2).")
@click.option("--firmware", type=NonEmptyPath(dir_okay=False), default=None,
              help="Run this board firmware (.elf, make -C firmware) in simavr instead of the simulated board.")
@click.option("--robot", default=None, metavar="NAME|FILE.toml",
              help="With --firmware: the robot wiring the chip is connected to (omnibench/sim/firmware/robots/; "
                   "default omnibot-2019, the robot as wired).")
def serve(world_file: str | None, seed: int | None, clock: str, speed: float | None, settings: tuple[str, ...],
          status_file: str | None, ammeter: bool, firmware: str | None, robot: str | None) -> None:
    """Serve the simulated board on a pseudo-terminal until interrupted.

    Prints the device path on the first line of stdout (the ammeter's on the second with
    --ammeter), notes on stderr. On Ctrl-C or SIGTERM the motors are stopped and the
    status file says so.
    """
    from omnibench.sim.world import world_from_url

    params: dict[str, str] = {"clock": clock}
    if world_file:
        params["world"] = world_file
    if seed is not None:
        params["seed"] = str(seed)
    if speed is not None:
        params["speed"] = str(speed)
    for item in settings:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UserError(f"--set needs KEY=VALUE, got {item!r}")
        params[key.strip()] = value.strip()
    _, world, _ = world_from_url("sim://omnibot?" + urlencode(params))
    board = None
    if robot is not None and firmware is None:
        raise UserError("--robot describes the wiring around a firmware: give --firmware too")
    if firmware is not None:
        from omnibench.sim.firmware.build import require

        require("fil")
        from omnibench.sim.firmware.board import FirmwareBoard

        board = FirmwareBoard(world, firmware, robot)
        board.max_wall_s = 0.02  # stay responsive when the machine is slower than real time
    from omnibench.sim.pty_server import run_server  # imports the physics: after checking input

    sys.exit(run_server(world, status_file=status_file, ammeter=ammeter, out=sys.stdout, log=sys.stderr, board=board))
