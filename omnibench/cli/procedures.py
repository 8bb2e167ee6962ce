"""`omnibench sweep | forward | lateral | energy`: run one Section III/IV procedure on a board.

Each command validates the robot file, the procedure file, the robot's limits and the answers
file before it opens the port, so bad input never moves a motor. Ctrl-C stops the motors and
marks the run aborted; `--resume RUN_DIR` continues it from its last complete step.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import click

from omnibench.cli.params import FINITE, NonEmptyPath
from omnibench.procedures.registry import REGISTRY, Procedure

#: command -> its procedure, from the procedures' registry
PROCEDURE_OF: dict[str, Procedure] = {p.command: p for p in REGISTRY}


def _make(name: str) -> click.Command:
    entry = PROCEDURE_OF[name]
    procedure = entry.name

    @click.command(name, help=entry.help + f"\n\nDefault procedure file: procedures/{entry.default_file} "
                                           "(copy it and edit). Use --port sim:// for the simulated robot.")
    @click.option("--port", metavar="URL", help="Serial device (/dev/ttyACM0), or sim://... for the simulated robot.")
    @click.option("--procedure", "procedure_file", type=NonEmptyPath(path_type=Path), metavar="FILE",
                  help=f"Procedure file (TOML). Default: the shipped {entry.default_file}.")
    @click.option("--robot", "robot_file", type=NonEmptyPath(path_type=Path), metavar="FILE",
                  help="Robot file (TOML). Default: the real Omnibot's numbers.")
    @click.option("--out", type=NonEmptyPath(path_type=Path), default=Path("runs"), show_default=True,
                  help="Folder that receives the run directory.")
    @click.option("--dry-run", is_flag=True, help="Print the plan, its duration and peak voltage/current; move nothing.")
    @click.option("--resume", type=NonEmptyPath(path_type=Path), metavar="RUN_DIR",
                  help="Continue an interrupted run from its last complete step.")
    @click.option("--allow-other-board", is_flag=True,
                  help="--resume on a board other than the one the run was taken on (recorded as a new segment).")
    @click.option("--answers", type=NonEmptyPath(path_type=Path), metavar="FILE",
                  help="Operator answers (TOML) for unattended runs.")
    @click.option("--measurement-noise", type=FINITE, default=None, metavar="M",
                  help="Simulation only: the simulated operator's tape noise, m (default from the procedure file).")
    @click.option("--operator", "who", type=click.Choice(["auto", "person", "simulated"]), default="auto",
                  show_default=True, help="Who answers the prompts: auto = the simulated operator on a simulator, "
                  "else the person at the keyboard; person = always the keyboard (on a simulator the world follows "
                  "your answers).")
    @click.option("--without-current", is_flag=True, hidden=name != "energy",
                  help="Drive the energy trajectories even with no battery current source (no energy is measured).")
    @click.option("--wiring", type=NonEmptyPath(path_type=Path), metavar="FILE", default=None,
                  help="Wiring file from omnibench commission. Default: ./wiring.toml when it exists.")
    @click.option("--plot", is_flag=True, help="Also a live matplotlib window of the wheel speeds (needs a display).")
    @click.option("--json", "as_json", is_flag=True, help="Print the result as JSON on stdout.")
    @click.option("--ammeter", metavar="URL", default=None, hidden=name != "energy",
                  help="SCPI ammeter on its own serial URL for the battery current (default: the board's sensor).")
    def cmd(port: str | None, procedure_file: Path | None, robot_file: Path | None, out: Path,
            dry_run: bool, resume: Path | None, allow_other_board: bool, answers: Path | None, measurement_noise: float | None,
            who: str, without_current: bool, wiring: Path | None, plot: bool, as_json: bool,
            ammeter: str | None) -> None:
        from omnibench.bench.session import run_command
        from omnibench.cli import verbosity

        level = verbosity()

        def echo(line: str) -> None:
            if level >= 0:
                click.echo(line, err=as_json)

        result: dict[str, Any] = run_command(
            procedure, port=port, procedure_file=procedure_file, robot_file=robot_file, out=out,
            dry_run=dry_run, resume=resume, answers=answers, echo=echo,
            progress=not as_json and sys.stderr.isatty(), measurement_noise=measurement_noise,
            ammeter=ammeter, operator=who, without_current=without_current, wiring=wiring, plot=plot,
            verbosity=level, allow_other_board=allow_other_board,
        )
        if as_json:
            from omnibench.runs.store import json_ready

            click.echo(json.dumps(json_ready(result), indent=2, default=str))
        elif level < 0 and result.get("run"):  # -q: the one line a script needs
            click.echo(str(result["run"]))

    return cmd


commands: dict[str, click.Command] = {name: _make(name) for name in PROCEDURE_OF}
