"""The campaign's analysis stages: the installed `omnibench fit`, `validate-energy` and `diagnose`
commands run in process on the campaign's runs, with their JSON results kept for the report.

This lives with the command line because it runs commands; omnibench.bench.campaign receives
`run_analysis` as its `analyse` function and never imports the CLI.
"""

from __future__ import annotations

import contextlib
import io
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from omnibench.bench.campaign import ANALYSIS
from omnibench.errors import UserError


def _analysis_command(name: str) -> Any | None:
    """The click command for `name` if its module is installed, else None."""
    import importlib
    import importlib.util

    from omnibench.cli import COMMANDS

    module = COMMANDS[name][0]
    try:
        if importlib.util.find_spec(module) is None:
            return None
        mod = importlib.import_module(module)
    except ImportError:
        return None
    return mod.commands[name] if hasattr(mod, "commands") else getattr(mod, "command", None)


def _invoke(cmd: Any, name: str, args: list[str]) -> tuple[int, str, str]:
    """Run a click command in process; (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            cmd.main(args=args, prog_name=f"omnibench {name}", standalone_mode=False)
        except SystemExit as exc:
            code = int(exc.code or 0)
        except UserError as exc:
            code = exc.exit_code
            err.write(f"omnibench: error: {exc}\n")
        except Exception as exc:  # noqa: BLE001 - a failing later stage must not lose the campaign
            code = 1
            err.write(f"omnibench: internal error: {type(exc).__name__}: {exc}\n")
    return code, out.getvalue(), err.getvalue()


def _timed_invoke(cmd: Any, name: str, args: list[str]) -> tuple[int, str, str]:
    """_invoke with a spinner and the elapsed time on a terminal (fit and diagnose take minutes)."""
    import sys
    import time

    if not sys.stderr.isatty():
        return _invoke(cmd, name, args)
    from rich.console import Console

    console = Console(stderr=True)
    t0 = time.monotonic()
    with console.status(f"{name} running (progress below when it reports any)"):
        out = _invoke(cmd, name, args)
    console.print(f"   {name}: {time.monotonic() - t0:.0f} s")
    return out


def _options(cmd: Any) -> set[str]:
    names: set[str] = set()
    for p in getattr(cmd, "params", []):
        names.update(getattr(p, "opts", []))
    return names


def run_analysis(runs_dir: Path, out: Path, robot_file: Path | None, echo: Callable[[str], None],
                 stages_wanted: tuple[str, ...] = ANALYSIS) -> dict[str, Any]:
    """fit, validate-energy, diagnose on the campaign's runs, each only if installed.

    fit writes OUT/model.toml; validate-energy and diagnose use it (or the robot file when
    the fit did not run). Options are passed only if the installed command declares them.
    """
    from omnibench.model.robot import DEFAULT_ROBOT_FILE

    stages: dict[str, Any] = {}
    model_file = out / "model.toml"
    model: Path = Path(robot_file) if robot_file else DEFAULT_ROBOT_FILE
    for name in ANALYSIS:
        if name not in stages_wanted:
            stages[name] = {"status": "skipped", "why": "not asked for (--analysis)"}
            echo(f"== {name}: skipped (not asked for)")
            continue
        cmd = _analysis_command(name)
        if cmd is None:
            stages[name] = {"status": "skipped", "why": f"`omnibench {name}` is not installed yet (omnibench.analysis)"}
            echo(f"== {name}: skipped (not installed yet)")
            continue
        opts = _options(cmd)
        args: list[str] = []
        if name == "fit":
            if "--out" in opts:
                args += ["--out", str(model_file)]
            if "--robot" in opts and robot_file is not None:
                args += ["--robot", str(robot_file)]
        else:
            if "--model" in opts:
                args += ["--model", str(model)]
            if "--out" in opts:  # diagnose writes the extended model (a TOML file)
                args += ["--out", str(out / f"model_{name.replace('-', '_')}.toml")]
        if "--plots" in opts:
            args += ["--plots", str(out / "plots" / name)]
        if "--json" in opts:
            args += ["--json"]
        args.append(str(runs_dir))
        echo(f"== {name}: omnibench {name} {' '.join(args)}")
        code, so, se = _timed_invoke(cmd, name, args)
        stage: dict[str, Any] = {"status": "ok" if code == 0 else "failed", "exit_code": code,
                                 "command": f"omnibench {name} {' '.join(args)}",
                                 "stdout": so[-4000:], "stderr": se[-2000:]}
        if "--json" in args:
            with contextlib.suppress(json.JSONDecodeError):
                stage["result"] = json.loads(so)
        if name == "fit" and code == 0 and model_file.is_file():
            model = model_file
            stage["model"] = str(model_file)
        stages[name] = stage
        echo(f"   {stage['status']}" + (f": {se.strip().splitlines()[-1]}" if code and se.strip() else ""))
    return stages
