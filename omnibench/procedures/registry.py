"""The procedures: one entry each, from which every other list of procedures derives.

An entry names the procedure (as in run.json and procedure files), its command (`omnibench
<command>`) with its line in `omnibench --help` and its help text, the paper section, the label
reports use, the shipped file (procedures/<file>), the module holding its expander (procedure file
-> Plan, imported when first used) and the Observations table its runs feed
(`omnibench.analysis.observations`).

This module imports nothing heavy: `omnibench --help` lists the procedures' commands from it
without loading the model (which the expanders and the plan types need).

Adding a procedure: write its module beside forward_runs.py (an `expand` function), add its
entry below with `register(...)`, ship its TOML file in procedures/ (docs/architecture.md,
"Adding a procedure", lists the files).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from omnibench.resources import data_dir

if TYPE_CHECKING:
    from omnibench.model.robot import Robot
    from omnibench.procedures.plan import Plan, ProcedureFile


@dataclass(frozen=True)
class Procedure:
    """One measurement procedure."""

    name: str  #: run.json `procedure`, the `procedure = ...` key of its file
    command: str  #: `omnibench <command>`
    section: str  #: the paper's section
    label: str  #: how reports and the live view name it
    summary: str  #: its line in `omnibench --help`
    help: str  #: the command's help text
    default_file: str  #: the shipped file under procedures/
    module: str  #: the module whose `expand(procedure_file, robot) -> Plan` expands its files
    observes: str  #: the Observations table its runs feed

    def expand(self, pf: ProcedureFile, robot: Robot) -> Plan:
        """The procedure file `pf` as a Plan for `robot` (the module's `expand`, imported now)."""
        plan: Plan = importlib.import_module(self.module).expand(pf, robot)
        return plan


#: Every procedure, in the order the campaign runs them (filled by `register` below).
REGISTRY: list[Procedure] = []
BY_NAME: dict[str, Procedure] = {}
PROCEDURES: list[str] = []
#: The procedure file a command uses when --procedure is not given.
DEFAULT_FILES: dict[str, str] = {}
LABELS: dict[str, str] = {}
COMMAND_OF: dict[str, str] = {}
#: Runs written by `omnibench import` (logged command traces, no procedure file) -> the table they feed.
IMPORTED_RUNS: dict[str, str] = {
    "step_response": "step_response",
    "random_duty": "step_response",  # a logged command trace replayed whole, like a step response
}
#: run.json `procedure` -> Observations table
RUN_PROCEDURES: dict[str, str] = dict(IMPORTED_RUNS)


def register(p: Procedure) -> None:
    """Add procedure `p` to REGISTRY and to every table derived from it.

    The tables are updated in place, so a module that imported one (`from omnibench.procedures
    import LABELS`) sees the new procedure too."""
    if p.name in BY_NAME or p.command in COMMAND_OF.values():
        raise ValueError(f"procedure {p.name!r} (command {p.command!r}) is already registered")
    REGISTRY.append(p)
    BY_NAME[p.name] = p
    PROCEDURES.append(p.name)
    DEFAULT_FILES[p.name] = p.default_file
    LABELS[p.name] = p.label
    COMMAND_OF[p.name] = p.command
    RUN_PROCEDURES[p.name] = p.observes


register(Procedure(
    "upside_down_sweep", "sweep", "III.i", "III.i upside-down sweep",
    "III.i  upside-down voltage sweep.",
    "III.i  Upside-down voltage sweep: steady wheel speed per duty, direction and wheel set.",
    "upside_down_sweep.toml", "omnibench.procedures.upside_down_sweep", "sweep"))
register(Procedure(
    "forward_runs", "forward", "III.ii", "III.ii forward/backward runs",
    "III.ii forward/backward runs (rolling resistance).",
    "III.ii  Forward/backward runs on the ground; the operator measures the distance (no-slip check).",
    "forward_runs.toml", "omnibench.procedures.forward_runs", "forward"))
register(Procedure(
    "lateral_runs", "lateral", "III.iii", "III.iii lateral runs",
    "III.iii lateral runs with payloads (roller friction).",
    "III.iii  Runs with lateral speed and payloads; the operator measures the displacement.",
    "lateral_runs.toml", "omnibench.procedures.lateral_runs", "lateral"))
register(Procedure(
    "energy_trajectories", "energy", "IV", "IV energy trajectories",
    "IV     energy trajectories with the battery current logged.",
    "IV  Open-loop trajectories (square, circle, figure eight, spin) with the battery current logged.",
    "energy_trajectories.toml", "omnibench.procedures.energy_trajectories", "energy"))


def default_procedure_path(procedure: str) -> Path:
    """The shipped procedure file (procedures/<name>.toml)."""
    return data_dir("procedures") / DEFAULT_FILES[procedure]
