"""fit and validate-energy on run directories, as functions: what `omnibench fit` and
`omnibench validate-energy` do (read and check the runs, fit or validate, write the model file and
the figures), and what the campaign's analysis stages call; diagnose is its own module
(`diagnose_command.py`: `omnibench fit` does not import the diagnosis, ~1 s of CPU).

In the campaign layer because they orchestrate the analysis (the fit, the diagnosis in its own
package, the model file, the plots) from above. Each returns what it did, with `to_json()` (the
command's `--json` result) and `json_text()` (that result as the command prints it, also kept by
the campaign). The commands only parse their options, call these and print; progress lines go to
the `progress` function given (the commands and the campaign write them on stderr).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from omnibench.analysis.fitting import DEFAULT_PROCEDURES, FitResult, fit, fit_per_wheel
from omnibench.analysis.model_file import load_model, write_model
from omnibench.analysis.modes import ModeProfile, profile_deviance, profile_modes
from omnibench.analysis.observations import PROCEDURES, Observations
from omnibench.analysis.validate import EnergyValidation, validate_energy
from omnibench.errors import UserError
from omnibench.model import default_robot
from omnibench.model.robot import Robot
from omnibench.progress import working
from omnibench.runs.check import check_out_folder, check_output, checked_runs
from omnibench.runs.provenance import model_build
from omnibench.runs.store import json_ready

Lines = Callable[[str], None]


def to_stderr(line: str) -> None:
    """A progress line on stderr (where the commands and the campaign's stages put them)."""
    print(line, file=sys.stderr, flush=True)


def _silent(line: str) -> None:
    """Drops the line (the `--json` output has no prose)."""


def _json_text(data: Any) -> str:
    return json.dumps(json_ready(data), indent=2, allow_nan=False)


def model_robot(path: Path | None) -> tuple[Robot, dict[str, Any]]:
    """The robot of a model file (or plain robot file) and its [fit] table; the shipped Omnibot
    and {} for None."""
    if path is None:
        return default_robot(), {}
    return load_model(path)


# --------------------------------------------------------------------------- fit
@dataclass
class FitDone:
    """What `omnibench fit` did: the fit, the per-wheel sweep fits, the files written."""

    result: FitResult
    wheels: dict[int, FitResult]  #: wheel (1-4) -> its own upside-down sweep fit (a, b, c)
    model_path: Path  #: the model file written
    figures: list[str]  #: the figures written
    #: runs of unknown mode: the assignments of modes fitted and the one kept (None: no such run)
    modes: ModeProfile | None = None

    def to_json(self) -> dict[str, Any]:
        data = self.result.to_json()
        data["per_wheel"] = {str(j): r.to_json()["parameters"] for j, r in self.wheels.items()}
        data["model_file"] = str(self.model_path)
        data["plots"] = self.figures
        data["mode_profile"] = self.modes.to_json() if self.modes is not None else None
        return data

    def json_text(self) -> str:
        return _json_text(self.to_json())


def fit_runs(runs: Sequence[Path], *, out: Path, robot_file: Path | None = None, free: list[str] | None = None,
             procedures: list[str] | None = None, per_wheel: bool = True, plots: Path | None = None,
             skip_bad: bool = False, force: bool = False, progress: Lines = to_stderr,
             say: Lines = _silent, allow_mixed: bool = False) -> FitDone:
    """Fit every coefficient the runs measure (weighted least squares through the simulator),
    write the model file `out` and, with `plots`, the figures there.

    free: the parameters to fit (default: what the runs measure); procedures: the observation
    tables that enter the fit (default: sweep, forward, lateral); per_wheel: also fit the
    upside-down sweep of each wheel on its own; force: overwrite `out` even if the tool did not
    write it. progress: skipped runs and the like; say: what the
    text output tells before the fit (nothing in JSON)."""
    robot, _ = model_robot(robot_file)
    good = checked_runs(runs, skip_bad=skip_bad, echo=progress, allow_mixed=allow_mixed)
    check_output(out, good, force=force)
    if plots is not None:
        check_out_folder(plots, "--plots")
    obs = Observations.from_runs(good, robot)
    if procedures is not None:
        bad = [p for p in procedures if p not in PROCEDURES]
        if bad or not procedures:
            raise UserError(f"--procedures: {', '.join(bad) or 'empty'}; choose from {', '.join(PROCEDURES)}")
        if not any(len(obs.table(p)) for p in procedures):
            raise UserError(f"none of the runs holds {', '.join(procedures)} observations ({obs.summary()})")
    elif not any(len(obs.table(p)) for p in ("sweep", "forward", "lateral")):
        raise UserError("none of the runs is a sweep, forward or lateral run: nothing to fit "
                        f"({obs.summary()})")
    say(f"Read {len(obs.run_ids)} run(s): {obs.summary()}")
    say("Fitting through the simulator (weighted least squares)...")

    def fit_one(o: Observations) -> tuple[FitResult, float, dict[str, float]]:
        r = fit(robot, o, free, procedures=procedures)
        res = r.residuals[r.residuals["used"]]
        group = (res["procedure"].astype(str) + "/" + res["signal"].astype(str)).to_numpy()
        cost = profile_deviance(res["residual"].to_numpy(float), res["sigma"].to_numpy(float), group)
        return r, cost, {"residual_rms": float(np.sqrt(np.mean(res["residual"].to_numpy(float) ** 2)))}

    with working("fitting"):
        # runs of unknown mode: every assignment fitted, the lowest profile deviance kept (analysis/modes.py)
        obs, result, modes = profile_modes(obs, procedures if procedures is not None else DEFAULT_PROCEDURES,
                                           fit_one, say=progress)
    if modes is not None:
        result.notes.append(modes.text())
    wheels = {}
    if per_wheel and "sweep" in result.procedures and obs.sweep["wheel"].nunique() > 1:
        wheels = fit_per_wheel(result.robot, obs, ["a", "b", "c"])
    paths = [obs.runs[r]["path"] or r for r in result.runs_used]
    model_path = write_model(out, result, [str(p) for p in paths], per_wheel=wheels or None)
    figures = []
    if plots is not None:
        from omnibench.analysis import plots as pl

        if "sweep" in result.procedures:
            figures.append(str(pl.plot_sweep_fit(result.robot, obs, result.residuals, plots)))
        figures.append(str(pl.plot_residuals(result.residuals, plots)))
    return FitDone(result, wheels, model_path, figures, modes)


# --------------------------------------------------------------------------- validate-energy
@dataclass
class ValidationDone:
    """What `omnibench validate-energy` did: predicted vs measured battery energy per run."""

    validation: EnergyValidation
    model: Path  #: the model file validated
    figure: Path | None  #: the current-trace figure, when asked for

    def to_json(self) -> dict[str, Any]:
        data = self.validation.to_json()
        data["model"] = str(self.model)
        data["plots"] = [str(self.figure)] if self.figure else []
        return data

    def json_text(self) -> str:
        return _json_text(self.to_json())


def validate_runs(runs: Sequence[Path], *, model: Path, plots: Path | None = None, skip_bad: bool = False,
                  progress: Lines = to_stderr, allow_mixed: bool = False) -> ValidationDone:
    """Replay each energy run's duties through the model file `model` and compare predicted with
    measured battery energy (paper IV); with `plots`, the current-trace figure there."""
    if plots is not None:
        check_out_folder(plots, "--plots")
    robot, _ = model_robot(model)
    obs = Observations.from_runs(checked_runs(runs, skip_bad=skip_bad, echo=progress, allow_mixed=allow_mixed,
                                              model=(f"the model {model}", model_build(robot))), robot)
    val = validate_energy(robot, obs)
    fig = None
    if plots is not None:
        from omnibench.analysis.plots import plot_energy

        fig = plot_energy(val, plots)
    return ValidationDone(val, model, fig)
