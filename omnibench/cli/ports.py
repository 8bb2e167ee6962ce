"""`omnibench ports`: list the serial ports this machine has."""

from __future__ import annotations

import json

import click


@click.command(name="ports")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list.")
def command(as_json: bool) -> None:
    """List serial ports (USB boards show their VID:PID and serial number).

    The simulated board needs no port: use --port sim:// with any command.
    """
    from serial.tools import list_ports

    ports = sorted(list_ports.comports(), key=lambda p: p.device)
    rows = [{"device": p.device, "description": p.description, "hwid": p.hwid,
             "serial_number": p.serial_number, "manufacturer": p.manufacturer} for p in ports]
    if as_json:
        click.echo(json.dumps(rows, indent=1))
        return
    if not rows:
        click.echo("no serial ports found (plug the board in, or use --port sim:// for the simulated robot)")
        return
    for r in rows:
        click.echo(f"{r['device']:<20} {r['description']}  [{r['hwid']}]")
