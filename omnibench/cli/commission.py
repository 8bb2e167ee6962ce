"""`omnibench commission`: jog each wheel, ask which turned and which way, write the wiring file."""

from __future__ import annotations

from pathlib import Path

import click


@click.command("commission")
@click.option("--port", metavar="URL", required=True, help="Serial device, or sim://... for the simulated robot.")
@click.option("--robot", "robot_file", type=click.Path(path_type=Path), metavar="FILE",
              help="Robot file (TOML), for the expected battery voltage. Default: the real Omnibot's numbers.")
@click.option("--out", type=click.Path(path_type=Path), default=Path("wiring.toml"), show_default=True,
              help="Wiring file to write; procedures started in this folder read ./wiring.toml.")
def command(port: str, robot_file: Path | None, out: Path) -> None:
    """Check a robot's wiring before the first procedure: each board channel is jogged alone at
    low duty (robot upside down), you say which wheel turned and which way; the encoder signs, the
    battery reading and the current sensors are checked. A map that does not hold together is
    refused (nothing written)."""
    from omnibench.bench.commission import commission

    commission(port, out, robot_file=robot_file, echo=lambda line: click.echo(line, err=True))
