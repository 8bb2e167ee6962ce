"""The campaign's analysis stages: the installed `omnibench fit`, `validate-energy` and `diagnose`
commands run in process on the campaign's runs, with their JSON results kept for the report.

This lives with the command line because it runs commands; omnibench.campaign.run receives
`run_analysis` as its `analyse` function and never imports the CLI.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from omnibench.campaign.run import ANALYSIS
from omnibench.cli.progress import TeeStream, working
from omnibench.errors import Terminated, UserError


def _analysis_command(name: str) -> Any | None:
    """The click command for `name` if its module is installed, else None."""
    import importlib
    import importlib.util

    from omnibench.cli import commands

    module = commands()[name][0]
    try:
        if importlib.util.find_spec(module) is None:
            return None
        mod = importlib.import_module(module)
    except ImportError:
        return None
    return mod.commands[name] if hasattr(mod, "commands") else getattr(mod, "command", None)


def _invoke(cmd: Any, name: str, args: list[str], on_line: Callable[[str], None] | None = None,
            live: bool = True) -> tuple[int, str, str]:
    """Run a click command in process; (exit code, stdout, stderr).

    stdout (the stage's JSON) is captured; stderr (its progress lines, its spinner) goes on to the
    terminal as it is written when `live` (a copy is kept for the report), each line to `on_line`."""
    out = io.StringIO()
    err = TeeStream(sys.stderr if live else None, on_line)
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            cmd.main(args=args, prog_name=f"omnibench {name}", standalone_mode=False)
        except SystemExit as exc:
            code = int(exc.code or 0)
        except (KeyboardInterrupt, click.exceptions.Abort) as exc:
            # Ctrl-C (click turns it into Abort): the campaign must stop, not go on to the next stage;
            # SIGTERM (Terminated) keeps its own kind so that it is named as such
            cause = exc if isinstance(exc, KeyboardInterrupt) else exc.__cause__
            raise (Terminated() if isinstance(cause, Terminated) else KeyboardInterrupt()) from exc
        except UserError as exc:
            code = exc.exit_code
            err.write(f"omnibench: error: {exc}\n")
        except Exception as exc:  # noqa: BLE001 - a failing later stage must not lose the campaign
            code = 1
            err.write(f"omnibench: internal error: {type(exc).__name__}: {exc}\n")
    return code, out.getvalue(), err.getvalue()


def _timed_invoke(cmd: Any, name: str, args: list[str], live: bool = True) -> tuple[int, str, str]:
    """_invoke under a spinner with the elapsed time, the stage's latest progress line and an ETA
    (on a terminal; fit and diagnose take minutes)."""
    with working(f"{name} running") as status:
        return _invoke(cmd, name, args, on_line=status.update, live=live)


def _options(cmd: Any) -> set[str]:
    names: set[str] = set()
    for p in getattr(cmd, "params", []):
        names.update(getattr(p, "opts", []))
    return names


def _kept(name: str, earlier: dict[str, Any] | None) -> dict[str, Any] | None:
    """The stage `name` as an interrupted campaign left it, if it finished ("ok") and the files it
    wrote are still there; else None (the stage runs again)."""
    st = (earlier or {}).get(name)
    if not isinstance(st, dict) or st.get("status") != "ok":
        return None
    files = [st.get("model"), ((st.get("result") or {}).get("written") or {}).get("model")]
    if any(isinstance(f, str) and not Path(f).is_file() for f in files):
        return None
    return st


def run_analysis(runs_dir: Path, out: Path, robot_file: Path | None, echo: Callable[[str], None],
                 stages_wanted: tuple[str, ...] = ANALYSIS, *, into: dict[str, Any] | None = None,
                 earlier: dict[str, Any] | None = None,
                 extra: dict[str, tuple[str, ...]] | None = None) -> dict[str, Any]:
    """fit, validate-energy, diagnose on the campaign's runs, each only if installed.

    fit writes OUT/model.toml; validate-energy and diagnose use it (or the robot file when
    the fit did not run). Options are passed only if the installed command declares them.

    into: the dict the stages' results are written to as each one ends (returned too), so a
    caller interrupted by Ctrl-C (KeyboardInterrupt, re-raised) still holds the stages that
    finished; the interrupted one is marked {"status": "interrupted"}.
    earlier: the stages of an interrupted campaign on the same runs: those that finished are
    kept, not run again (`campaign --resume`).
    extra: more options for a stage's command, by stage name (e.g. diagnose's --candidates).

    When diagnose adds an effect, validate-energy runs again on the model it wrote (the
    campaign's answer), recorded as the diagnose stage's "validate_energy".
    """
    from omnibench.cli import verbosity
    from omnibench.model.robot import DEFAULT_ROBOT_FILE

    stages: dict[str, Any] = into if into is not None else {}
    model_file = out / "model.toml"
    model: Path = Path(robot_file) if robot_file else DEFAULT_ROBOT_FILE
    live = verbosity() >= 0
    for name in ANALYSIS:
        if name not in stages_wanted:
            stages[name] = {"status": "skipped", "why": "not asked for (--analysis)"}
            echo(f"== {name}: skipped (not asked for)")
            continue
        kept = _kept(name, earlier)
        if kept is not None:
            stages[name] = kept
            if name == "fit" and kept.get("model"):
                model = Path(kept["model"])
            echo(f"== {name}: kept (finished before the interruption)")
            continue
        try:
            stage = _run_stage(name, runs_dir, out, robot_file, model, echo, live,
                               (extra or {}).get(name, ()))
            if name == "fit" and stage.get("status") == "ok" and model_file.is_file():
                model = model_file
                stage["model"] = str(model_file)
            if name == "diagnose" and "validate-energy" in stages_wanted:
                diagnosed = _diagnosed_model(stage)
                if diagnosed is not None:  # the campaign's answer: its energy error too, beside the declared fit's
                    stage["validate_energy"] = _run_stage("validate-energy", runs_dir, out, robot_file, diagnosed,
                                                          echo, live, (), label="validate-energy (diagnosed model)",
                                                          plots="validate-energy-diagnosed")
        except KeyboardInterrupt:
            stages[name] = {"status": "interrupted", "why": "Ctrl-C"}
            raise
        stages[name] = stage
    return stages


def _diagnosed_model(stage: dict[str, Any]) -> Path | None:
    """The model file diagnose wrote when it added an effect, else None."""
    res = stage.get("result") or {}
    path = (res.get("written") or {}).get("model")
    if stage.get("status") != "ok" or not res.get("selected") or not path or not Path(path).is_file():
        return None
    return Path(path)


def _run_stage(name: str, runs_dir: Path, out: Path, robot_file: Path | None, model: Path,
               echo: Callable[[str], None], live: bool, extra: tuple[str, ...], *, label: str | None = None,
               plots: str | None = None) -> dict[str, Any]:
    """One analysis stage: the installed command run on the campaign's runs; its record."""
    cmd = _analysis_command(name)
    label = label or name
    if cmd is None:
        echo(f"== {label}: skipped (not installed yet)")
        return {"status": "skipped", "why": f"`omnibench {name}` is not installed yet (omnibench.analysis)"}
    opts = _options(cmd)
    args: list[str] = []
    if name == "fit":
        if "--out" in opts:
            args += ["--out", str(out / "model.toml")]
        if "--robot" in opts and robot_file is not None:
            args += ["--robot", str(robot_file)]
    else:
        if "--model" in opts:
            args += ["--model", str(model)]
        if "--out" in opts:  # diagnose writes the extended model (a TOML file)
            args += ["--out", str(out / f"model_{name.replace('-', '_')}.toml")]
    if "--plots" in opts:
        args += ["--plots", str(out / "plots" / (plots or name))]
    if "--json" in opts:
        args += ["--json"]
    args += [*extra, str(runs_dir)]
    command = f"omnibench {name} {' '.join(args)}"
    echo(f"== {label}: {command}")
    code, so, se = _timed_invoke(cmd, name, args, live=live)
    stage: dict[str, Any] = {"status": "ok" if code == 0 else "failed", "exit_code": code, "command": command,
                             "stdout": so[-4000:], "stderr": se[-2000:]}
    if "--json" in args:
        with contextlib.suppress(json.JSONDecodeError):
            stage["result"] = json.loads(so)
    echo(f"   {stage['status']}" + (f": {se.strip().splitlines()[-1]}" if code and se.strip() else ""))
    return stage
