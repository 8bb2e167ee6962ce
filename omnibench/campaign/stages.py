"""The campaign's analysis stages: fit, validate-energy and diagnose on the campaign's runs, each
called as a function (omnibench.campaign.analysis_commands and diagnose_command, what the commands of the same names
do), with its record kept for the report: the equivalent command, its exit code, its JSON result
(`result`, and `stdout` as the command prints it) and its progress lines (`stderr`).

omnibench.campaign.run receives `run_analysis` as its `analyse` function (from the command line,
which sets `live`).
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from omnibench.campaign.analysis_commands import fit_runs, validate_runs
from omnibench.campaign.diagnose_command import diagnose_runs
from omnibench.campaign.run import ANALYSIS
from omnibench.errors import UserError
from omnibench.model.robot import DEFAULT_ROBOT_FILE
from omnibench.progress import TeeStream, working


def _call(name: str, work: Callable[[], str], live: bool) -> tuple[int, str, str]:
    """Run one stage under a spinner (on a terminal: the elapsed time, the stage's latest progress
    line and an ETA); (exit code, stdout, stderr).

    stdout (anything printed, then the stage's JSON) is captured; stderr (its progress lines) goes
    on to the terminal as it is written when `live` (a copy is kept for the report). Ctrl-C and
    SIGTERM (KeyboardInterrupt, Terminated) go on to the campaign, which stops; a UserError or any
    other failure of the stage is its exit code and error line, and the campaign goes on."""
    out = io.StringIO()
    with working(f"{name} running") as status:
        err = TeeStream(sys.stderr if live else None, status.update)
        code = 0
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                text = work()
                print(text)
            except UserError as exc:
                code = exc.exit_code
                err.write(f"omnibench: error: {exc}\n")
            except Exception as exc:  # noqa: BLE001 - a failing later stage must not lose the campaign
                code = 1
                err.write(f"omnibench: internal error: {type(exc).__name__}: {exc}\n")
    return code, out.getvalue(), err.getvalue()


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
                 earlier: dict[str, Any] | None = None, extra: dict[str, dict[str, Any]] | None = None,
                 live: bool = True) -> dict[str, Any]:
    """fit, validate-energy, diagnose on the campaign's runs, those in `stages_wanted`.

    fit writes OUT/model.toml; validate-energy and diagnose use it (or the robot file when
    the fit did not run).

    into: the dict the stages' results are written to as each one ends (returned too), so a
    caller interrupted by Ctrl-C (KeyboardInterrupt, re-raised) still holds the stages that
    finished; the interrupted one is marked {"status": "interrupted"}.
    earlier: the stages of an interrupted campaign on the same runs: those that finished are
    kept, not run again (`campaign --resume`).
    extra: more options for a stage, by stage name: keyword arguments of its function (e.g.
    {"diagnose": {"candidates": ["stribeck"]}}, shown in its command as --candidates stribeck).
    live: the stages' progress lines on the terminal as they come (off with -q).

    When diagnose adds an effect, validate-energy runs again on the model it wrote (the
    campaign's answer), recorded as the diagnose stage's "validate_energy".
    """
    stages: dict[str, Any] = into if into is not None else {}
    model_file = out / "model.toml"
    model: Path = Path(robot_file) if robot_file else DEFAULT_ROBOT_FILE
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
                               (extra or {}).get(name, {}))
            if name == "fit" and stage.get("status") == "ok" and model_file.is_file():
                model = model_file
                stage["model"] = str(model_file)
            if name == "diagnose" and "validate-energy" in stages_wanted:
                diagnosed = _diagnosed_model(stage)
                if diagnosed is not None:  # the campaign's answer: its energy error too, beside the declared fit's
                    stage["validate_energy"] = _run_stage("validate-energy", runs_dir, out, robot_file, diagnosed,
                                                          echo, live, {}, label="validate-energy (diagnosed model)",
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


#: a stage's options as in its command line (how its record names them)
_OPTION = {"candidates": "--candidates"}


def _stage_work(name: str, runs_dir: Path, out: Path, robot_file: Path | None, model: Path, plots: Path,
                extra: dict[str, Any]) -> Callable[[], str]:
    """The stage's function call, with the files the campaign gives it (its JSON text when called)."""
    if name == "fit":
        return lambda: fit_runs([runs_dir], out=out / "model.toml", robot_file=robot_file, plots=plots,
                                **extra).json_text()
    if name == "validate-energy":
        return lambda: validate_runs([runs_dir], model=model, plots=plots, **extra).json_text()
    if name == "diagnose":
        return lambda: diagnose_runs([runs_dir], model=model, out=out / "model_diagnose.toml", plots=plots,
                                     **extra).json_text()
    raise ValueError(f"unknown analysis stage {name!r}")


def _command(name: str, runs_dir: Path, out: Path, robot_file: Path | None, model: Path, plots: Path,
             extra: dict[str, Any]) -> str:
    """The `omnibench` command line that does what the stage does (for the report)."""
    args: list[str] = []
    if name == "fit":
        args += ["--out", str(out / "model.toml")]
        if robot_file is not None:
            args += ["--robot", str(robot_file)]
    else:
        args += ["--model", str(model)]
        if name == "diagnose":  # diagnose writes the extended model (a TOML file)
            args += ["--out", str(out / "model_diagnose.toml")]
    args += ["--plots", str(plots), "--json"]
    for key, value in extra.items():
        args += [_OPTION[key], ",".join(value) if isinstance(value, (list, tuple)) else str(value)]
    return f"omnibench {name} {' '.join([*args, str(runs_dir)])}"


def _run_stage(name: str, runs_dir: Path, out: Path, robot_file: Path | None, model: Path,
               echo: Callable[[str], None], live: bool, extra: dict[str, Any], *, label: str | None = None,
               plots: str | None = None) -> dict[str, Any]:
    """One analysis stage on the campaign's runs; its record."""
    folder = out / "plots" / (plots or name)
    command = _command(name, runs_dir, out, robot_file, model, folder, extra)
    echo(f"== {label or name}: {command}")
    code, so, se = _call(name, _stage_work(name, runs_dir, out, robot_file, model, folder, extra), live)
    stage: dict[str, Any] = {"status": "ok" if code == 0 else "failed", "exit_code": code, "command": command,
                             "stdout": so[-4000:], "stderr": se[-2000:]}
    with contextlib.suppress(json.JSONDecodeError):
        stage["result"] = json.loads(so)
    echo(f"   {stage['status']}" + (f": {se.strip().splitlines()[-1]}" if code and se.strip() else ""))
    return stage
