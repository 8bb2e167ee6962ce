"""The `omnibench` command: a click group whose subcommands live one per module.

Each module in `commands()` defines `command` (a click.Command or Group). Modules are
imported only when their command runs, so `omnibench --help` stays fast.
"""

from __future__ import annotations

import difflib
import importlib
import importlib.util
import os
import sys

import click

from omnibench import __version__
from omnibench.errors import Terminated, UserError
from omnibench.procedures.registry import REGISTRY

#: command name -> (module, one-line help shown in `omnibench --help`); the procedures' commands
#: (sweep, forward, ...) come from omnibench/procedures/registry.py, between these two tables.
_BEFORE: dict[str, tuple[str, str]] = {
    "simulate": ("omnibench.cli.simulate", "Simulate the robot from a command file (no board)."),
    "ports": ("omnibench.cli.ports", "List serial ports."),
    "board": ("omnibench.cli.board", "Talk to a motor board: info, monitor."),
    "sim": ("omnibench.cli.sim", "Run the simulated Omnibot board (pseudo-terminal)."),
    "commission": ("omnibench.cli.commission", "Jog each wheel, check wiring and sensors: write wiring.toml."),
}
_AFTER: dict[str, tuple[str, str]] = {
    "campaign": ("omnibench.cli.campaign", "Run every procedure, fit, validate and diagnose: one report."),
    "import": ("omnibench.cli.importer", "Convert other data (the 2019 TFM logs, your own CSV logs) into runs."),
    "fit": ("omnibench.cli.analysis", "Fit every coefficient with uncertainties."),
    "validate-energy": ("omnibench.cli.analysis", "Predicted vs measured battery energy per run."),
    "predict": ("omnibench.cli.analysis", "Model prediction of a logged run vs measurement."),
    "diagnose": ("omnibench.cli.diagnose", "Find the missing effect, add it, report before/after."),
    "plan": ("omnibench.cli.plan", "Plan the next steps that reach target SEs at least cost."),
}


def commands() -> dict[str, tuple[str, str]]:
    """Every command: name -> (module, its line in `omnibench --help`), in the order of the help.

    The procedures' commands are read from the registry when asked (a procedure registered after
    this module was imported is listed too); the registry imports nothing heavy."""
    procedures = {p.command: ("omnibench.cli.procedures", p.summary) for p in REGISTRY}
    return {**_BEFORE, **procedures, **_AFTER}


def _available() -> list[str]:
    """Commands whose module exists (the rest are still being built)."""
    return [n for n, (mod, _) in commands().items() if importlib.util.find_spec(mod) is not None]


class LazyGroup(click.Group):
    """Resolves subcommands from `commands()` on demand."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return _available()

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        table = commands()
        if name not in table or name not in _available():
            return None
        module = importlib.import_module(table[name][0])
        # A module serving several commands (sweep/forward/...) exposes a `commands` dict.
        return module.commands[name] if hasattr(module, "commands") else module.command

    def resolve_command(self, ctx: click.Context, args: list[str]) -> tuple[str | None, click.Command | None, list[str]]:
        """The command of `args`; a mistyped command name is refused with the closest one."""
        try:
            return super().resolve_command(ctx, args)
        except click.UsageError:
            name = args[0] if args else ""
            close = difflib.get_close_matches(name, self.list_commands(ctx), n=1, cutoff=0.6)
            if close and name.strip():
                ctx.fail(f"No such command '{name}'. Did you mean '{close[0]}'?")
            raise

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        table = commands()
        rows = [(n, table[n][1]) for n in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="omnibench")
@click.option("-v", "--verbose", count=True, help="Say more (every operator action and check, even under the live view).")
@click.option("-q", "--quiet", is_flag=True, help="Say only errors and results (no live view).")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: bool) -> None:
    """omnibench: drive the Omnibot, measure its friction, fit, validate, diagnose.

    Every procedure also runs on the simulated robot: use --port sim://.
    """
    ctx.obj = {"verbosity": -1 if quiet else verbose}


def verbosity() -> int:
    """-1 with -q, 0 by default, 1+ with -v (for the command running now)."""
    ctx = click.get_current_context(silent=True)
    obj = ctx.find_root().obj if ctx is not None else None
    return int((obj or {}).get("verbosity", 0))


def main(argv: list[str] | None = None) -> None:
    """Entry point: user errors become one line on stderr and a non-zero exit."""
    debug = bool(os.environ.get("OMNIBENCH_DEBUG"))
    try:
        cli.main(args=argv, prog_name="omnibench", standalone_mode=False)
    except click.exceptions.Abort as exc:
        if isinstance(exc.__cause__, Terminated):  # click turns KeyboardInterrupt into Abort
            click.echo("omnibench: terminated (SIGTERM)", err=True)
            sys.exit(143)
        # click turns Ctrl-C (KeyboardInterrupt) into Abort; a declined prompt or ended input is Abort too
        interrupted = isinstance(exc.__cause__, KeyboardInterrupt) or isinstance(exc.__context__, KeyboardInterrupt)
        click.echo(f"omnibench: {'interrupted (Ctrl-C)' if interrupted else 'aborted'}", err=True)
        sys.exit(130)
    except click.ClickException as exc:  # usage errors too: one line, not click's three
        where = exc.ctx.command_path if isinstance(exc, click.UsageError) and exc.ctx else ""
        hint = f" (see '{where} --help')" if where else ""
        click.echo(f"omnibench: error: {exc.format_message()}{hint}", err=True)
        sys.exit(exc.exit_code)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except UserError as exc:
        if debug:
            raise
        click.echo(f"omnibench: error: {exc}", err=True)
        sys.exit(exc.exit_code)
    except Terminated:
        click.echo("omnibench: terminated (SIGTERM)", err=True)
        sys.exit(143)
    except KeyboardInterrupt:
        click.echo("omnibench: interrupted", err=True)
        sys.exit(130)
    except Exception as exc:  # last line of defence: one line, not a traceback
        if debug:
            raise
        click.echo(
            f"omnibench: internal error: {type(exc).__name__}: {exc} "
            "(set OMNIBENCH_DEBUG=1 for the traceback)",
            err=True,
        )
        sys.exit(1)
