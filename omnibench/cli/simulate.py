"""`omnibench simulate`: run the model on a duty command file, no board involved."""

from __future__ import annotations

from pathlib import Path

import click

from omnibench.cli.params import FINITE, NonEmptyPath
from omnibench.errors import UserError
from omnibench.runs.store import is_run_dir

OUTPUT_COLUMNS = (
    ["t", "x", "y", "psi", "v1", "v2", "psi_dot"]
    + [f"phi{j}" for j in range(1, 5)]
    + [f"phi_dot{j}" for j in range(1, 5)]
    + [f"i{j}" for j in range(1, 5)]
    + ["V_batt", "I_batt", "E_batt"]
)


@click.command("simulate")
@click.option("--robot", "robot_path", type=NonEmptyPath(dir_okay=False), default=None,
              help="Robot description (TOML). Default: the real Omnibot's numbers.")
@click.option("--commands", "commands_path", required=True, type=NonEmptyPath(dir_okay=False),
              help="CSV with columns t,u1,u2,u3,u4 (s, duty in [-1,1]), held until the next row.")
@click.option("--out", "out_path", required=True, type=NonEmptyPath(dir_okay=False), help="Output CSV.")
@click.option("--upside-down", is_flag=True, help="Robot on blocks, wheels in the air (procedure III.i).")
@click.option("--payload", type=FINITE, default=0.0, show_default=True, help="Mass added on top, kg.")
@click.option("--duration", type=FINITE, default=None,
              help="Simulated time, s. Default: 1 s after the last command.")
@click.option("--rate", type=FINITE, default=100.0, show_default=True, help="Output rows per second, Hz.")
@click.option("--dt", type=FINITE, default=1e-3, show_default=True, help="Physics step, s.")
@click.option("--energy-breakdown", is_flag=True,
              help="Also write where the battery energy went (copper, gear, each friction term, KE).")
def command(robot_path, commands_path, out_path, upside_down, payload, duration, rate, dt,
            energy_breakdown) -> None:
    """Simulate the robot under a duty command file and write its time series."""
    from omnibench.model import Scenario, default_robot, load_robot, simulate
    from omnibench.model.commands import load_commands

    robot = load_robot(robot_path) if robot_path else default_robot()
    cmds = load_commands(commands_path, max_duty=robot.max_duty)
    if not 0 <= payload <= 1000:
        raise UserError(f"--payload must be a mass in [0, 1000] kg, got {payload:g}")
    if duration is not None and not 0 < duration <= 86400:
        raise UserError(f"--duration must be in (0, 86400] s, got {duration:g}")
    out_dir = Path(out_path).resolve().parent
    if is_run_dir(out_dir):
        raise UserError(f"--out {out_path}: is inside the run directory {out_dir}; write elsewhere")
    if not (0 < dt <= 0.01):
        raise UserError(f"--dt must be in (0, 0.01] s, got {dt}")
    if rate <= 0 or rate > 1 / dt:
        raise UserError(f"--rate must be in (0, {1 / dt:g}] Hz for --dt {dt}")
    t_end = duration if duration is not None else cmds.end + 1.0
    if t_end <= 0:
        raise UserError(f"--duration must be positive, got {t_end}")
    every = max(1, int(round(1.0 / (rate * dt))))
    scenario = Scenario(mode="upside_down" if upside_down else "ground", payload=payload)
    df = simulate(robot, scenario, cmds.t, cmds.u, t_end, dt=dt, record_every=every)
    columns = list(OUTPUT_COLUMNS)
    if energy_breakdown:
        columns += [c for c in df.columns if c.startswith("E_") and c != "E_batt" and df[c].abs().max() > 0] + ["KE"]
    out = Path(out_path)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        df[columns].to_csv(out, index=False, float_format="%.9g")
    except OSError as exc:
        raise UserError(f"{out}: cannot write ({exc.strerror})") from None
    last = df.iloc[-1]
    click.echo(
        f"simulated {t_end:g} s {'upside down' if upside_down else 'on the ground'} "
        f"({robot.name}, payload {payload:g} kg): {len(df)} rows -> {out}; "
        f"battery energy {last['E_batt']:.1f} J, final pose x={last['x']:.3f} m y={last['y']:.3f} m "
        f"psi={last['psi']:.3f} rad"
    )
