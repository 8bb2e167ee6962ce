"""diagnose on run directories, as a function: what `omnibench diagnose` does (read and check the
runs, fit the declared model, find and add the missing effects, write the extended model and the
figures) and what the campaign's diagnose stage calls (docs/diagnose.md). The shared helpers of the
analysis commands are in `analysis_commands.py`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omnibench.analysis.diagnosis import Diagnosis, diagnose
from omnibench.analysis.diagnosis.loro import HeldOutRuns, heldout_runs, trimmed
from omnibench.analysis.diagnosis.report import write_model as write_diagnosed_model
from omnibench.analysis.diagnosis.report import write_plots as write_diagnosis_plots
from omnibench.analysis.model_file import load_model
from omnibench.analysis.observations import Observations
from omnibench.campaign.analysis_commands import Lines, to_stderr
from omnibench.errors import UserError
from omnibench.model import load_robot
from omnibench.runs.check import check_out_folder, check_output, checked_runs
from omnibench.runs.provenance import model_build


def _diagnosis_number(x: object) -> object:
    """json.dumps `default` of diagnose's JSON: numpy scalars as numbers (non-finite as None),
    anything else as its text."""
    try:
        v = float(x)  # type: ignore[arg-type]  # numpy scalars
    except (TypeError, ValueError):
        return str(x)
    return v if math.isfinite(v) else None


@dataclass
class DiagnosisDone:
    """What `omnibench diagnose` did: the diagnosis, the leave-one-run-out check when asked for,
    the files written ({"model": path, "plots": [paths]})."""

    diagnosis: Diagnosis
    held: HeldOutRuns | None
    written: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {**self.diagnosis.to_json(), "written": self.written,
                "leave_one_run_out": self.held.to_json() if self.held else None}

    def json_text(self) -> str:
        return json.dumps(self.to_json(), indent=2, default=_diagnosis_number)


def diagnose_runs(runs: Sequence[Path], *, model: Path, out: Path | None = None, plots: Path | None = None,
                  candidates: list[str] | None = None, procedures: list[str] | None = None, alpha: float = 1e-3,
                  max_effects: int = 3, seed: int = 0, loro: bool = False, force: bool = False,
                  progress: Lines = to_stderr, allow_mixed: bool = False) -> DiagnosisDone:
    """Fit the declared model `model` to the runs, find residual structure, add the library
    effects that earn their parameters on held-out run steps; write the extended model to `out`
    and the before/after plots to `plots` when given (docs/diagnose.md).

    candidates: only these effects (default: the library); procedures: only these observation
    tables; alpha: family-wise significance level; loro: also leave-one-run-out (an addition that
    costs a run is a trade-off, left out of the written model); force: overwrite `out` even if the
    tool did not write it; allow_mixed: combine runs (and the model) of different robots, boards or
    worlds, with a warning line. progress: lines as it goes."""
    if out is not None:  # the output first: a file the tool did not write is refused before anything is read
        check_output(out, runs, force=force)
    robot = load_robot(model)  # its errors name a robot file: any robot file is a model
    good = tuple(checked_runs(runs, allow_mixed=allow_mixed, model=(f"the model {model}", model_build(robot))))
    if plots is not None:
        check_out_folder(plots, "--plots")
    fit_info = load_model(model)[1]  # [fit]: was this model fitted to these very runs?
    obs = Observations.from_runs(good, robot=robot)
    if not obs.procedures():
        raise UserError("the runs hold no measurements diagnose can use (sweep, forward, lateral, energy, step_response)")

    def say(msg: str) -> None:
        progress(f"diagnose: {msg}")

    diag = diagnose(robot, obs, candidates=candidates, procedures=procedures, alpha=alpha, max_effects=max_effects,
                    seed=seed, progress=say, fit_info=fit_info)
    obs = diag.problem.obs  # runs of unknown mode with the modes the declared fit chose (analysis/modes.py)
    held = None
    if loro:
        if len(obs.run_ids) < 2:
            raise UserError("--loro needs at least two runs (each is predicted from the others)")
        held = heldout_runs(diag, obs, progress=say)
    written: dict[str, Any] = {}
    if out is not None:
        kept = trimmed(diag, held, obs) if held is not None and held.tradeoffs else diag
        written["model"] = str(write_diagnosed_model(kept, out))
    if plots is not None:
        written["plots"] = [str(p) for p in write_diagnosis_plots(diag, plots)]
    return DiagnosisDone(diag, held, written)
