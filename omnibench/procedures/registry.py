"""The procedures: one entry each, from which every other list of procedures derives.

An entry names the procedure (as in run.json and procedure files), its command (`omnibench
<command>`), the paper section, the label reports use, the shipped file (procedures/<file>),
the expander (procedure file -> Plan) and the Observations table its runs feed
(`omnibench.analysis.observations`). Adding a procedure: write its module here (an `expand`
function, as forward_runs.py), add its entry to REGISTRY, ship its TOML file in procedures/ and
teach the analysis the table it observes (docs/architecture.md lists the files).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omnibench.procedures import energy_trajectories, forward_runs, lateral_runs, upside_down_sweep
from omnibench.procedures.plan import Plan, ProcedureFile, check_limits, read_procedure_file, space_limit

if TYPE_CHECKING:
    from omnibench.model.robot import Robot


@dataclass(frozen=True)
class Procedure:
    """One measurement procedure of the paper."""

    name: str  #: run.json `procedure`, the `procedure = ...` key of its file
    command: str  #: `omnibench <command>`
    section: str  #: the paper's section
    label: str  #: how reports and the live view name it
    help: str  #: the command's help text
    default_file: str  #: the shipped file under procedures/
    expand: Callable[[ProcedureFile, Any], Plan]  #: procedure file, robot -> Plan
    observes: str  #: the Observations table its runs feed


REGISTRY: tuple[Procedure, ...] = (
    Procedure("upside_down_sweep", "sweep", "III.i", "III.i upside-down sweep",
              "III.i  Upside-down voltage sweep: steady wheel speed per duty, direction and wheel set.",
              "upside_down_sweep.toml", upside_down_sweep.expand, "sweep"),
    Procedure("forward_runs", "forward", "III.ii", "III.ii forward/backward runs",
              "III.ii  Forward/backward runs on the ground; the operator measures the distance (no-slip check).",
              "forward_runs.toml", forward_runs.expand, "forward"),
    Procedure("lateral_runs", "lateral", "III.iii", "III.iii lateral runs",
              "III.iii  Runs with lateral speed and payloads; the operator measures the displacement.",
              "lateral_runs.toml", lateral_runs.expand, "lateral"),
    Procedure("energy_trajectories", "energy", "IV", "IV energy trajectories",
              "IV  Open-loop trajectories (square, circle, figure eight, spin) with the battery current logged.",
              "energy_trajectories.toml", energy_trajectories.expand, "energy"),
)

#: Runs written by `omnibench import` (logged command traces, no procedure file) -> the table they feed.
IMPORTED_RUNS: dict[str, str] = {
    "step_response": "step_response",
    "random_duty": "step_response",  # a logged command trace replayed whole, like a step response
}

BY_NAME: dict[str, Procedure] = {p.name: p for p in REGISTRY}
PROCEDURES: tuple[str, ...] = tuple(BY_NAME)
#: The procedure file a command uses when --procedure is not given.
DEFAULT_FILES: dict[str, str] = {p.name: p.default_file for p in REGISTRY}
EXPANDERS: dict[str, Callable[[ProcedureFile, Any], Plan]] = {p.name: p.expand for p in REGISTRY}
LABELS: dict[str, str] = {p.name: p.label for p in REGISTRY}
COMMAND_OF: dict[str, str] = {p.name: p.command for p in REGISTRY}
#: run.json `procedure` -> Observations table
RUN_PROCEDURES: dict[str, str] = {**{p.name: p.observes for p in REGISTRY}, **IMPORTED_RUNS}


def default_procedure_path(procedure: str) -> Path:
    """The shipped procedure file (procedures/<name>.toml)."""
    from omnibench.resources import data_dir

    return data_dir("procedures") / DEFAULT_FILES[procedure]


def load_plan(path: str | Path, robot: Robot, expect: str | None = None) -> Plan:
    """Read, validate and expand a procedure file for `robot`; checks the robot's limits.

    `expect`: the procedure the command runs (a sweep file given to `omnibench forward` is an
    error naming the file).
    """
    pf = read_procedure_file(path)
    name = pf.data.get("procedure")
    if name not in PROCEDURES:
        pf.fail(None, "procedure", f"expected one of {', '.join(PROCEDURES)}, got {name!r}")
    if expect is not None and name != expect:
        pf.fail(None, "procedure", f"this file describes {name}, but the command runs {expect}")
    plan = EXPANDERS[name](pf, robot)
    plan.settings["max_distance_m"] = space_limit(pf)
    check_limits(plan, robot, pf)
    return plan
