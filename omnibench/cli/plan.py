"""`omnibench plan`: the next steps that shrink the target parameters' SE most per unit of cost,
written as procedure files the runner executes unchanged (docs/design.md)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import click

from omnibench.cli.params import FINITE, NonEmptyPath
from omnibench.errors import UserError


def parse_costs(text: str | None, robot_second: float) -> Any:
    """'flip=60,wheels=180' -> Costs with those action costs (s) over the defaults."""
    from omnibench.analysis.design.space import DEFAULT_ACTION_COSTS, Costs

    acts = dict(DEFAULT_ACTION_COSTS)
    for item in [t.strip() for t in (text or "").split(",") if t.strip()]:
        key, _, val = item.partition("=")
        key = key.strip()
        if key not in acts:
            raise UserError(f"--cost {item!r}: unknown action {key!r}; actions are {', '.join(acts)}")
        try:
            v = float(val.strip().removesuffix("s").strip())
        except ValueError:
            raise UserError(f"--cost {item!r}: expected ACTION=SECONDS, e.g. wheels=120") from None
        if not 0 <= v <= 86_400:
            raise UserError(f"--cost {item!r}: a cost is a number of seconds in [0, 86400]")
        acts[key] = v
    if not 0 < robot_second <= 86_400:  # free robot time would make every step free: nothing to rank
        raise UserError(f"--robot-second {robot_second:g}: give the cost of a robot second in s, in (0, 86400]")
    return Costs(actions=acts, robot_second=robot_second)


def check_limits(floor_length: float, budget_minutes: float | None, budget_actions: int | None) -> None:
    """Refuse a floor (m) or budget (minutes, actions) no lab has, before any work starts."""
    if not 0 < floor_length <= 100:
        raise UserError(f"--floor-length {floor_length:g}: give the metres of floor, in (0, 100]")
    if budget_minutes is not None and not 0 < budget_minutes <= 10_000:
        raise UserError(f"--budget-minutes {budget_minutes:g}: give minutes of robot time, in (0, 10000]")
    if budget_actions is not None and not 0 < budget_actions <= 10_000:
        raise UserError(f"--budget-actions {budget_actions}: give a number of operator actions, in [1, 10000]")


def design_options(f: Any) -> Any:
    """Options shared by `plan` and `campaign --adaptive`."""
    for opt in reversed([
        click.option("--target-se", "target_se", metavar="P=SE,...",
                     help="Target standard errors: a=2% (relative to the value) or a=0.0005 (SI)."),
        click.option("--cost", "cost", default=None, metavar="ACTION=S,...",
                     help="Operator action costs in seconds (flip=60, wheels=180, payload=20, measure=30 "
                          "by default; measure = start mark and tape)."),
        click.option("--robot-second", type=FINITE, default=3.0, show_default=True,
                     help="Cost of one second of robot time, in seconds (battery, wear, the operator waiting)."),
        click.option("--floor-length", type=FINITE, default=2.5, show_default=True,
                     help="Metres of straight floor a run may use from its start mark."),
        click.option("--no-current", is_flag=True, help="The board logs no motor current (plan without it)."),
    ]):
        f = opt(f)
    return f


@click.command("plan")
@click.argument("runs", nargs=-1, type=NonEmptyPath(path_type=Path))
@click.option("--model", "model_file", type=NonEmptyPath(path_type=Path), default=None,
              help="Model or robot file (default: the shipped Omnibot); its values are the starting point.")
@design_options
@click.option("--procedures", "procedures_dir", type=NonEmptyPath(path_type=Path, file_okay=False), metavar="DIR",
              default=None, help="The lab's procedure files (wheel sets, payloads, settings). Default: the shipped ones.")
@click.option("--out", type=NonEmptyPath(path_type=Path), default=Path("plan"), show_default=True,
              help="Folder for the planned procedure files and plan.json.")
@click.option("--budget-minutes", type=FINITE, default=None, help="At most this many minutes of robot time.")
@click.option("--budget-actions", type=int, default=None, help="At most this many operator actions.")
@click.option("--json", "as_json", is_flag=True, help="Print the plan as JSON.")
def command(runs: tuple[Path, ...], model_file: Path | None, target_se: str | None, cost: str | None,
            robot_second: float, floor_length: float, no_current: bool, procedures_dir: Path | None, out: Path,
            budget_minutes: float | None, budget_actions: int | None, as_json: bool) -> None:
    """Plan the next steps from the RUNS so far (none: from the model file alone) that bring the
    target parameters to their SE at the least cost; write them as procedure files in OUT.

    omnibench plan runs/ --target-se a=2%,b=1%,c=5%,C_r=5%
    """
    from omnibench.analysis.design.files import diagnostic_floor, space_from_files, write_procedures
    from omnibench.analysis.design.planner import describe_actions, parse_targets, plan
    from omnibench.analysis.design.space import Limits
    from omnibench.analysis.fitting import fit
    from omnibench.analysis.model_file import load_model
    from omnibench.analysis.observations import Observations
    from omnibench.campaign.run import procedure_files
    from omnibench.model import default_robot
    from omnibench.procedures import COMMAND_OF
    from omnibench.runs.check import check_out_folder, checked_runs

    check_out_folder(out)
    runs = tuple(checked_runs(runs)) if runs else ()
    check_limits(floor_length, budget_minutes, budget_actions)
    robot = load_model(model_file)[0] if model_file else default_robot()
    targets = parse_targets(target_se or "", robot)
    costs = parse_costs(cost, robot_second)
    files = procedure_files(procedures_dir)
    space = space_from_files(robot, files, Limits(floor_length=floor_length))
    res = obs = None
    have: set[str] = set()
    if runs:
        obs = Observations.from_runs(runs, robot)
        res = fit(robot, obs)
        have = set(obs.procedures())
    floor = [c for c in diagnostic_floor(robot, files, space) if c.procedure not in have]
    design = plan(robot, res, targets, space, costs, current=not no_current, required=floor, obs=obs,
                  budget_seconds=60 * budget_minutes if budget_minutes else math.inf,
                  budget_actions=budget_actions if budget_actions is not None else math.inf)
    written = write_procedures(design.units, files, out, robot) if design.units else []
    doc = {**design.to_json(), "files": [str(p) for _, p in written],
           "from": "fit of " + ", ".join(map(str, runs)) if runs else "the model file alone (prior)"}
    out.mkdir(parents=True, exist_ok=True)
    (out / "plan.json").write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    if as_json:
        click.echo(json.dumps(doc, indent=2))
        return
    click.echo(f"plan from {doc['from']}: expected standard errors after it")
    click.echo(design.table(robot))
    click.echo(f"operator actions: {describe_actions(design.actions)}")
    for note in design.notes:
        click.echo(f"note: {note}")
    if written:
        click.echo("run in this order:")
        for proc, path in written:
            click.echo(f"  omnibench {COMMAND_OF[proc]} --port PORT --procedure {path}")
    else:
        click.echo("nothing to run: " + ("every target is met already" if all(design.met.values())
                                          else "no candidate step helps (see the refused targets)"))
