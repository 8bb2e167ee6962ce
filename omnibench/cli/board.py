"""`omnibench board info|monitor`: who is on the port, and its live telemetry."""

from __future__ import annotations

import json
import math
import time

import click

from omnibench.cli.params import FINITE
from omnibench.errors import BoardError, UserError

PORT_HELP = "Serial port or URL: /dev/ttyACM0, sim://?seed=1, socket://host:port, hwgrep://VID:PID."


@click.group(name="board")
def command() -> None:
    """Talk to a motor board: identity, live telemetry."""


@command.command(name="info")
@click.option("--port", required=True, help=PORT_HELP)
@click.option("--timeout", type=FINITE, default=None,
              help="Handshake timeout, s [default: 8, a Mega that resets as the port opens can take 5 s in its "
                   "bootloader].")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def info(port: str, timeout: float | None, as_json: bool) -> None:
    """Handshake with the board and print its identity, protocol and link round trip."""
    from omnibench.link.board import HANDSHAKE_TIMEOUT_S, Board

    if timeout is None:
        timeout = HANDSHAKE_TIMEOUT_S
    if not 0 < timeout <= 60:
        raise UserError(f"--timeout {timeout:g}: give the handshake timeout in s, in (0, 60]")
    with Board.open(port, timeout=timeout, strict=False) as board:
        hello = board.hello
        assert hello is not None
        rtt = [board.ping() for _ in range(5)] if board.version_ok else []
        out = dict(hello.as_dict(), port=port, protocol=board.spec.name,
                   host_protocol_version=board.spec.version, compatible=board.version_ok,
                   ping_ms=round(1e3 * sorted(rtt)[len(rtt) // 2], 3) if rtt else None,
                   faults=_latched_faults(board) if board.version_ok else None)
    if as_json:
        click.echo(json.dumps(out, indent=1))
    else:
        _print_info(out, port)
    if not out["compatible"]:
        raise BoardError(f"board on {port} speaks protocol v{out['protocol_version']}, this tool "
                         f"v{out['host_protocol_version']}: update the firmware or omnibench")


def _latched_faults(board) -> list[str] | None:
    """Names of the faults latched on the board now, read from one telemetry sample (the motors
    stay stopped; nothing is cleared: a run asks the operator before it clears them)."""
    try:
        board.configure(telemetry_hz=min(50, int(board.hello.max_telemetry_rate or 50)))
        try:
            sample = next(iter(board.samples(0.0)), None)
        finally:
            board.configure(telemetry_hz=0)
    except BoardError:  # no telemetry: the identity is still worth printing
        return None
    return board.fault_names(sample.faults) if sample is not None else None


def _print_info(out: dict, port: str) -> None:
    click.echo(f"board {out['board_id']} on {port}: firmware {out['firmware_version']}, "
               f"protocol {out['protocol']} v{out['protocol_version']} "
               f"({'compatible' if out['compatible'] else 'INCOMPATIBLE with this tool, v' + str(out['host_protocol_version'])})")
    click.echo(f"  boot id {out['boot_id']}, encoder {out['counts_per_rev']} counts/rev, "
               f"telemetry up to {out['max_telemetry_rate']} Hz")
    click.echo(f"  capabilities: {', '.join(out['capabilities']) or 'none'}")
    if out["ping_ms"] is not None:
        click.echo(f"  command round trip: {out['ping_ms']:.2f} ms (median of 5)")
    if out["compatible"]:
        faults = out.get("faults")
        click.echo("  faults latched: " + ("unknown (no telemetry sample)" if faults is None else
                                           ", ".join(faults) + " (the next run asks before clearing them)"
                                           if faults else "none"))


@command.command(name="monitor")
@click.option("--port", required=True, help=PORT_HELP)
@click.option("--duration", type=FINITE, default=10.0, show_default=True, help="Board time to watch, s.")
@click.option("--rate", type=int, default=50, show_default=True, help="Telemetry rate, Hz.")
@click.option("--every", type=FINITE, default=0.5, show_default=True, help="Print a line every this many s of board time.")
@click.option("--json", "as_json", is_flag=True, help="One JSON object per printed sample.")
def monitor(port: str, duration: float, rate: int, every: float, as_json: bool) -> None:
    """Show live telemetry (motors stay stopped): encoders, currents, battery, faults."""
    from omnibench.link.board import Board

    if not (0 < duration <= 86400 and 0 < every <= 86400):
        raise UserError(f"--duration and --every must be seconds in (0, 86400], got {duration:g} and {every:g}")
    if not 1 <= rate <= 1000:
        raise UserError(f"--rate {rate}: give the telemetry rate in Hz, in [1, 1000]")
    with Board.open(port) as board:
        board.configure(telemetry_hz=rate)
        next_print = -math.inf
        n = 0
        t_wall = time.monotonic()
        for s in board.samples(duration):
            n += 1
            if s.t < next_print - 1e-9:
                continue
            next_print = s.t + every
            faults = board.fault_names(s.faults)
            if as_json:
                click.echo(json.dumps({"t": s.t, "seq": s.seq, "encoder": s.encoder, "motor_current": s.motor_current,
                                       "battery_voltage": s.battery_voltage, "battery_current": s.battery_current,
                                       "faults": faults, "duty": s.duty}))
            else:
                click.echo(f"t={s.t:9.3f} s  enc {' '.join(f'{c:8d}' for c in s.encoder)}  "
                           f"I {' '.join(f'{i:6.3f}' for i in s.motor_current)} A  "
                           f"{s.battery_voltage:6.2f} V {s.battery_current:6.3f} A  "
                           f"faults {','.join(faults) or '-'}")
        st = board.stats
        if not as_json:
            click.echo(f"{n} samples in {duration:g} s of board time ({time.monotonic() - t_wall:.1f} s wall), "
                       f"{st.lost} lost, {st.crc_errors} CRC errors, {st.framing_errors} framing errors")
