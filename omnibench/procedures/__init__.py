"""The measurement procedures (paper sections III.i, III.ii, III.iii, IV) as data: pure, no board.

- `registry`: one entry per procedure (name, command, section, label, default file, expander,
  the table it observes); every other list of procedures derives from it.
- `plan`: the plan types (World, Step, Plan), the procedure file reader with units and line
  numbers, the sections every procedure shares, the robot's limits, and `load_plan`.
- one module per procedure (`upside_down_sweep`, `forward_runs`, `lateral_runs`,
  `energy_trajectories`): its `expand(procedure_file, robot) -> Plan`.

Below the bench (which runs plans on a board) and the analysis (which designs plans and reads
their runs); it knows only the model's units and geometry.

The names below are imported from their module when first used (PEP 562 `__getattr__`): the
command line reads `registry` for `omnibench --help` without loading `plan`, which loads the
model (numba).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from omnibench.procedures.plan import (
        MAX_COUNT,
        MAX_LENGTH_M,
        MAX_MASS_KG,
        MAX_STEP_S,
        Plan,
        ProcedureFile,
        Step,
        World,
        body_velocity_duties,
        check_limits,
        duty_limit,
        format_masses,
        load_plan,
        read_procedure_file,
        stall_current,
        step_distance_bound,
    )
    from omnibench.procedures.registry import (
        COMMAND_OF,
        DEFAULT_FILES,
        IMPORTED_RUNS,
        LABELS,
        PROCEDURES,
        REGISTRY,
        RUN_PROCEDURES,
        Procedure,
        default_procedure_path,
        register,
    )

_PLAN = ("MAX_COUNT", "MAX_LENGTH_M", "MAX_MASS_KG", "MAX_STEP_S", "Plan", "ProcedureFile", "Step", "World",
         "body_velocity_duties", "check_limits", "duty_limit", "format_masses", "load_plan", "read_procedure_file",
         "stall_current", "step_distance_bound")
_REGISTRY = ("COMMAND_OF", "DEFAULT_FILES", "IMPORTED_RUNS", "LABELS", "PROCEDURES", "REGISTRY", "RUN_PROCEDURES",
             "Procedure", "default_procedure_path", "register")
#: public name -> the module that defines it
_HOME = {**dict.fromkeys(_PLAN, "omnibench.procedures.plan"),
         **dict.fromkeys(_REGISTRY, "omnibench.procedures.registry")}

__all__ = [
    "COMMAND_OF", "DEFAULT_FILES", "IMPORTED_RUNS", "LABELS", "MAX_COUNT", "MAX_LENGTH_M", "MAX_MASS_KG",
    "MAX_STEP_S", "PROCEDURES", "REGISTRY", "RUN_PROCEDURES", "Plan", "Procedure", "ProcedureFile", "Step",
    "World", "body_velocity_duties", "check_limits", "default_procedure_path", "duty_limit", "format_masses",
    "load_plan", "read_procedure_file", "register", "stall_current", "step_distance_bound",
]


def __getattr__(name: str) -> object:
    """`omnibench.procedures.<name>`: the name from its module, imported now."""
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(home), name)
