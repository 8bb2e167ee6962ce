"""`omnibench campaign`: all four procedures, then fit, validate-energy and diagnose, one report."""

from __future__ import annotations

import functools
import json
import sys
from pathlib import Path
from typing import Any

import click

from omnibench.cli.params import FINITE, NonEmptyPath
from omnibench.cli.plan import design_options
from omnibench.errors import UserError

#: Exit code of a campaign whose runs and report were written but an analysis stage (fit,
#: validate-energy, diagnose) failed: 2 is bad input, 3 a board fault, 130 Ctrl-C.
ANALYSIS_FAILED = 4


@click.command("campaign")
@click.option("--port", metavar="URL", help="Serial device, or sim://... for the simulated robot.")
@click.option("--out", type=NonEmptyPath(path_type=Path), default=Path("campaign"), show_default=True,
              help="Folder for the runs, the analysis outputs, the plots and report.md.")
@click.option("--robot", "robot_file", type=NonEmptyPath(path_type=Path), metavar="FILE",
              help="Robot file (TOML). Default: the real Omnibot's numbers.")
@click.option("--procedures", "procedures_dir", type=NonEmptyPath(path_type=Path, file_okay=False), metavar="DIR",
              help="Folder holding the four procedure files (<procedure>.toml). Default: the shipped ones.")
@click.option("--ammeter", metavar="URL", default=None,
              help="SCPI ammeter on its own serial URL for the energy runs (default: the board's sensor).")
@click.option("--analysis", "analysis", default="fit,validate-energy,diagnose", show_default=True,
              metavar="STAGES", help="Analysis stages to run after the procedures (comma list, or none).")
@click.option("--candidates", default=None, metavar="NAME,...",
              help="diagnose: only these candidate effects (default: the whole library, docs/effects.md).")
@click.option("--resume", is_flag=True,
              help="Continue the campaign in OUT: keep complete runs, resume an interrupted one, run the rest.")
@click.option("--allow-other-board", is_flag=True,
              help="--resume on a board other than the one the earlier runs were taken on (recorded in each run).")
@click.option("--without-current", is_flag=True,
              help="Run the energy trajectories even with no battery current source (no energy is measured).")
@click.option("--operator", "who", type=click.Choice(["auto", "person", "simulated"]), default="auto",
              show_default=True, help="Who answers the prompts (see omnibench sweep --help).")
@click.option("--plot", is_flag=True, help="A live matplotlib window of the wheel speeds (needs a display).")
@click.option("--json", "as_json", is_flag=True, help="Print the campaign summary as JSON on stdout.")
@click.option("--adaptive", is_flag=True,
              help="Plan, run, fit, re-plan until every --target-se is met or the budget is spent (docs/design.md).")
@design_options
@click.option("--budget-minutes", type=FINITE, default=None, help="--adaptive: at most this many minutes of robot time.")
@click.option("--budget-actions", type=int, default=None, help="--adaptive: at most this many operator actions.")
@click.option("--prior-runs", "prior_runs", multiple=True, type=NonEmptyPath(path_type=Path, file_okay=False),
              metavar="RUN", help="--adaptive: a run of the robot's previous campaign (repeat the option): its "
              "fit's values and noise plan the first round; its data are not counted.")
def command(port: str | None, out: Path, robot_file: Path | None, procedures_dir: Path | None,
            ammeter: str | None, analysis: str, candidates: str | None, resume: bool, allow_other_board: bool,
            without_current: bool, who: str,
            plot: bool, as_json: bool, adaptive: bool, target_se: str | None, cost: str | None,
            robot_second: float, floor_length: float, no_current: bool, budget_minutes: float | None,
            budget_actions: int | None, prior_runs: tuple[Path, ...]) -> None:
    """Run the upside-down sweep, forward runs, lateral runs and energy trajectories, then fit,
    validate the energy and diagnose; write OUT/report.md with plots.

    On the simulated robot:  omnibench campaign --port sim:// --out campaign
    """
    from omnibench.campaign.run import parse_stages, run_campaign
    from omnibench.campaign.stages import run_analysis
    from omnibench.cli import verbosity

    level = verbosity()

    def echo(line: str) -> None:
        if level >= 0:
            click.echo(line, err=as_json)

    from omnibench.cli.plan import check_limits, parse_costs
    from omnibench.runs.check import check_out_folder

    check_out_folder(out)
    check_limits(floor_length, budget_minutes, budget_actions)
    costs = parse_costs(cost, robot_second)
    stages = parse_stages(analysis)
    stage_options: dict[str, dict[str, Any]] = {}
    if candidates is not None:
        from omnibench.cli.diagnose import parse_candidates

        stage_options["diagnose"] = {"candidates": parse_candidates(candidates) or []}
    analyse = functools.partial(run_analysis, live=level >= 0)
    if adaptive:
        from omnibench.analysis.design.space import Limits
        from omnibench.campaign.adaptive import run_adaptive_campaign

        if resume:
            raise UserError("--adaptive does not resume a campaign yet: start it in a new --out")
        if stage_options:
            raise UserError("--candidates does not apply to --adaptive yet")
        res = run_adaptive_campaign(port or "", out, target_se or "", robot_file=robot_file,
                                    procedures_dir=procedures_dir, costs=costs,
                                    limits=Limits(floor_length=floor_length), current=not no_current,
                                    budget_minutes=budget_minutes, budget_actions=budget_actions, echo=echo,
                                    stages=stages, analyse=analyse, prior_runs=prior_runs, ammeter=ammeter,
                                    without_current=without_current)
    elif prior_runs:
        raise UserError("--prior-runs needs --adaptive")
    elif target_se:
        raise UserError("--target-se needs --adaptive")
    else:
        res = run_campaign(port or "", out, robot_file=robot_file, procedures_dir=procedures_dir, echo=echo,
                           progress=not as_json and sys.stderr.isatty(), ammeter=ammeter,
                           stages=stages, resume=resume,
                           without_current=without_current, operator=who, analyse=analyse, plot=plot,
                           verbosity=level, stage_options=stage_options, allow_other_board=allow_other_board)
    if as_json:
        from omnibench.runs.store import json_ready

        click.echo(json.dumps(json_ready(res), indent=2, default=str))
    elif level < 0 and res.get("report"):  # -q: the one line a script needs
        click.echo(str(res["report"]))
    failed = [name for name, st in (res.get("analysis") or {}).items()
              if isinstance(st, dict) and st.get("status") == "failed"]
    if failed:  # the runs and the report are written; a script must still see that the answer is missing
        raise UserError(f"analysis stage failed: {', '.join(failed)} (runs and report kept in {out}; the stage's "
                        "own message is in report.md, Analysis)", exit_code=ANALYSIS_FAILED)
