"""The operator: whoever flips the robot, swaps wheels, places weights and reads the tape.

Three kinds, one interface:

- `ConsoleOperator`: a person at the keyboard (click prompts).
- `AnswersOperator`: answers from a file, for unattended runs (checked before any motor moves).
- `SimulatedOperator`: in simulation, performs the actions through the simulated board's
  sim-only world messages and measures the true pose with configurable Gaussian noise.

Measurements are returned in SI: a distance in m (tape measure, unsigned), or a displacement
(forward m, left m) in the robot frame at the start mark.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from omnibench.errors import UserError
from omnibench.files import read_toml
from omnibench.model.units import to_si
from omnibench.procedures import Step, World

if TYPE_CHECKING:
    from omnibench.model.robot import Robot


@dataclass(frozen=True)
class Action:
    """A physical action asked of the operator. `key` is stable (flip, wheels, payload, place)."""

    key: str
    prompt: str
    world: World | None = None


def actions_for(current: World | None, target: World) -> list[Action]:
    """The actions that turn `current` (None: unknown, e.g. after a resume) into `target`."""
    acts: list[Action] = []
    if current is None or current.mode != target.mode:
        if target.mode == "upside_down":
            acts.append(Action("flip", "Turn the robot upside down on its stand, wheels free in the air", target))
        else:
            acts.append(Action("flip", "Put the robot on the ground, wheels down", target))
    if current is None or current.wheel_set != target.wheel_set or current.wheel_mass != target.wheel_mass:
        if target.wheel_mass is not None:
            from omnibench.procedures import format_masses

            what = f"wheel set {target.wheel_set!r} ({format_masses(target.wheel_mass)})"
        else:
            what = f"wheel set {target.wheel_set!r}"
        acts.append(Action("wheels", f"Mount {what} on all four axles", target))
    if (current is None and (target.payload > 0 or target.mode == "ground")) or (
            current is not None and current.payload != target.payload):
        if target.payload > 0:
            acts.append(Action("payload", f"Place {target.payload:g} kg on top of the robot "
                                          "(total payload, centred)", target))
        else:
            acts.append(Action("payload", "Remove any payload from the top of the robot", target))
    return acts


class Operator(Protocol):
    source: str

    def perform(self, action: Action, step: Step | None) -> str:
        """Do `action`; returns the answer to record (e.g. "done")."""
        ...

    def start_mark(self, step: Step) -> str:
        """Put the robot at the start mark (before a timed run); returns the answer."""
        ...

    def measure(self, step: Step) -> Any:
        """After a run: a distance (m) or a displacement (forward m, left m)."""
        ...

    def remeasure(self, step: Step, question: str) -> Any | None:
        """The reading disagrees with the encoders (`question` says how): a new reading, or None
        to keep the first."""
        ...


MAX_LENGTH_M = 100.0  #: longest tape reading taken as a measurement (m)


def parse_length(text: str, where: str) -> float:
    """'1.23', '1.23 m', '123 cm' -> metres; UserError naming `where` otherwise."""
    try:
        v = to_si(text.strip() if isinstance(text, str) else text, "m")
    except ValueError as exc:
        raise UserError(f"{where}: {exc}") from None
    if abs(v) > MAX_LENGTH_M:
        raise UserError(f"{where}: {text!r} is longer than any lab floor ({MAX_LENGTH_M:g} m)")
    return v


def parse_distance(text: str, where: str) -> float:
    """A tape distance (unsigned, m): as parse_length, and refused when negative."""
    v = parse_length(text, where)
    if v < 0:
        raise UserError(f"{where}: {text!r} is negative; a distance is the tape's reading (>= 0, e.g. '0.62 m')")
    return v


def parse_displacement(value: Any, where: str) -> tuple[float, float]:
    """'0.5, 0.2' / ['0.5 m', '20 cm'] -> (forward m, left m)."""
    if isinstance(value, str):
        parts = [p for p in re.split(r"[,;]", value) if p.strip()]
    elif isinstance(value, (list, tuple)):
        parts = list(value)
    else:
        parts = []
    if len(parts) != 2:
        raise UserError(f"{where}: expected two lengths 'forward, left', got {value!r}")
    return parse_length(parts[0], where), parse_length(parts[1], where)


class ConsoleOperator:
    """A person at the keyboard.

    Every prompt that leads to motion says what moves next (`describe_motion`, needs `robot`)
    and needs an explicit yes; type-ahead is dropped. On a simulated board (`mirror`), what the
    person confirms is also done to the simulated world, so its physics follows the prompts
    (how a person tries the procedures against `omnibench sim serve`).
    """

    source = "console"

    def __init__(self, robot: Robot | None = None, mirror: Any = None) -> None:
        self.robot, self.mirror = robot, mirror
        self._sim = SimulatedOperator(mirror, noise=0.0) if mirror is not None else None

    def _next(self, step: Step | None) -> str:
        from omnibench.bench.prompts import describe_motion

        return describe_motion(step, self.robot) + "\n" if step is not None and self.robot is not None else ""

    def perform(self, action: Action, step: Step | None) -> str:
        import click

        from omnibench.bench.prompts import ask_yes

        click.echo("", err=True)  # off the progress bar's line
        ask_yes(f"{self._next(step)}{action.prompt}.")
        if self._sim is not None:
            self._sim.perform(action, step)
        return "done"

    def start_mark(self, step: Step) -> str:
        import click

        from omnibench.bench.prompts import ask_yes

        click.echo("", err=True)
        ask_yes(f"{self._next(step)}Put the robot at the start mark, facing along the marked axis.")
        if self._sim is not None:
            self._sim.start_mark(step)
        return "done"

    def measure(self, step: Step) -> Any:
        from omnibench.bench.prompts import read_answer

        while True:
            if step.measure == "distance":
                text = read_answer("Distance travelled, start mark to robot (e.g. 1.23 m)")
            else:
                text = read_answer("Displacement in the robot's start frame: forward, left (e.g. 0.52 m, 0.30 m)")
            try:
                return self._parse(step, text)
            except UserError as exc:
                import click

                click.echo(f"  {exc}; try again", err=True)

    @staticmethod
    def _parse(step: Step, text: str) -> Any:
        if step.measure == "distance":
            return parse_distance(text, "answer")
        return parse_displacement(text, "answer")

    def remeasure(self, step: Step, question: str) -> Any | None:
        """`question` (the tape disagrees with the encoders): a new reading, or None to keep."""
        import click

        from omnibench.bench.prompts import read_answer

        while True:
            text = read_answer(f"{question}: re-measure? Type the new reading, or keep")
            if text.lower() == "keep":
                return None
            try:
                return self._parse(step, text)
            except UserError as exc:
                click.echo(f"  {exc}; type a length, or keep", err=True)


class AnswersOperator:
    """Answers from a TOML file, for unattended runs::

        actions = "done"          # answer to every physical action (set up beforehand)
        [distance]                # step index = distance travelled (forward_runs)
        0 = "1.02 m"
        [displacement]            # step index = [forward, left] (lateral_runs)
        0 = ["0.40 m", "0.23 m"]
    """

    source = "answers-file"

    def __init__(self, path: str | Path) -> None:
        self.path = str(path)
        self.data, _ = read_toml(path, "answers file")
        if self.data.get("actions", "done") != "done":
            raise UserError(f"{path}: actions = {self.data['actions']!r}; an answers file can only say \"done\"")
        unknown = set(self.data) - {"actions", "distance", "displacement"}
        if unknown:
            raise UserError(f"{path}: unknown key {sorted(unknown)[0]!r}; use actions, [distance], [displacement]")

    def check(self, steps: list[Step]) -> None:
        """Every step that needs a measurement has one (before any motor moves)."""
        for table in ("distance", "displacement"):
            known = {str(s.index) for s in steps if s.measure == table}
            extra = sorted(set(self.data.get(table, {})) - known)
            if extra:
                raise UserError(f"{self.path}: [{table}] answers step {extra[0]}, which this procedure does not "
                                f"measure (steps measured: {', '.join(sorted(known, key=int)) or 'none'})")
        for s in steps:
            if s.measure is not None:
                table = self.data.get(s.measure, {})
                if str(s.index) not in table:
                    raise UserError(f"{self.path}: [{s.measure}] has no answer for step {s.index} ({s.label})")
                self._value(s)

    def _value(self, step: Step) -> Any:
        raw = self.data[step.measure][str(step.index)]  # type: ignore[index]
        where = f"{self.path}: [{step.measure}] {step.index}"
        if step.measure == "distance":
            return parse_distance(raw, where)
        return parse_displacement(raw, where)

    def perform(self, action: Action, step: Step | None) -> str:
        return str(self.data.get("actions", "done"))

    def start_mark(self, step: Step) -> str:
        return str(self.data.get("actions", "done"))

    def measure(self, step: Step) -> Any:
        return self._value(step)

    def remeasure(self, step: Step, question: str) -> Any | None:
        """A file cannot measure again: the reading is kept (and the question recorded)."""
        return None


class SimulatedOperator:
    """Acts through the simulated board's world messages and measures the true pose + noise.

    `noise`: standard deviation (m) of each tape reading; `measurer` optionally replaces the
    tape (answers from a file).
    """

    source = "simulated-operator"

    def __init__(self, board: Any, noise: float = 0.002, seed: int = 1, measurer: Any = None) -> None:
        self.board, self.noise = board, float(noise)
        self.rng = np.random.default_rng(seed)
        self.measurer = measurer
        self._start: tuple[float, float, float] | None = None

    def perform(self, action: Action, step: Step | None) -> str:
        w = action.world
        if action.key == "clear_faults":
            return "done"  # the simulated operator agrees (the answer is logged with its source)
        assert w is not None
        if action.key == "flip":
            self.board.sim_set_world(mode=w.mode)
        elif action.key == "wheels":
            if w.wheel_mass is not None:
                self.board.sim_set_world(wheel_mass=w.wheel_mass)
        elif action.key == "payload":
            self.board.sim_set_world(payload=w.payload)
        return "done"

    def start_mark(self, step: Step) -> str:
        self._start = self.board.sim_truth()
        return "done"

    def remeasure(self, step: Step, question: str) -> Any | None:
        """Measure again (a fresh tape reading); answers from a file are kept."""
        if self.measurer is not None:
            return self.measurer.remeasure(step, question)
        return self.measure(step)

    def measure(self, step: Step) -> Any:
        if self.measurer is not None:
            return self.measurer.measure(step)
        if self._start is None:
            raise RuntimeError("measure() before start_mark()")
        x0, y0, psi0 = self._start
        x1, y1, _ = self.board.sim_truth()
        dx, dy = x1 - x0, y1 - y0
        fwd = math.cos(psi0) * dx + math.sin(psi0) * dy
        left = -math.sin(psi0) * dx + math.cos(psi0) * dy
        if step.measure == "distance":
            return float(math.hypot(fwd, left) + self.rng.normal(0.0, self.noise))
        return (float(fwd + self.rng.normal(0.0, self.noise)), float(left + self.rng.normal(0.0, self.noise)))
