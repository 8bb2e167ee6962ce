"""The campaign: every procedure in turn, then fit, validate-energy and diagnose, one report.

The analysis stages are run by the caller's `analyse` function (the command line passes
omnibench.campaign.stages.run_analysis, which calls what `omnibench fit`, `validate-energy` and
`diagnose` do as functions); the report says which stages ran, which were skipped and why.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omnibench import __version__
from omnibench.campaign.answer import Answer, campaign_answer, inadequacy, rounded_like, unit_words, with_se
from omnibench.errors import Terminated, UserError
from omnibench.files import save_figure, write_atomic
from omnibench.locks import holds_out_folder
from omnibench.procedures import COMMAND_OF, LABELS, PROCEDURES, default_procedure_path

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

ANALYSIS = ("fit", "validate-energy", "diagnose")
#: runs the analysis stages: (runs_dir, out, robot_file, echo, stages, *, into=None, earlier=None) -> results by
#: stage name; `into` receives each stage as it ends, `earlier` holds an interrupted campaign's stages to keep
Analyse = Callable[..., dict[str, Any]]


def procedure_files(folder: Path | None) -> dict[str, Path]:
    """Every registered procedure's file, in registry order: <folder>/<procedure>.toml, else the shipped one."""
    out = {}
    for p in PROCEDURES:
        if folder is not None:
            f = Path(folder) / f"{p}.toml"
            if not f.is_file():
                raise UserError(f"{folder}: no {p}.toml (the campaign needs every procedure's file)")
            out[p] = f
        else:
            out[p] = default_procedure_path(p)
    return out


def _runs_of(runs_dir: Path) -> dict[str, list[tuple[Path, str]]]:
    """Run directories in runs_dir by procedure, oldest first, each with its status."""
    from omnibench.runs.check import run_problem
    from omnibench.runs.record import read_info
    from omnibench.runs.store import run_dirs

    found: dict[str, list[tuple[Path, str]]] = {}
    for run_dir in run_dirs(runs_dir):
        try:
            info = read_info(run_dir)
        except UserError as exc:
            raise UserError(f"{exc}; move that run out of {runs_dir}") from None
        why = run_problem(run_dir) if info.complete else None  # kept as is: the analysis must accept it
        if why:
            where = "" if why.startswith(str(run_dir)) else f"{run_dir}: "
            raise UserError(f"{where}{why}; move that run out of {runs_dir}")
        found.setdefault(info.procedure, []).append((run_dir, info.status))
    return found


@holds_out_folder("a campaign")  # two campaigns never write into one --out
def run_campaign(port: str, out: Path, *, robot_file: Path | None = None, procedures_dir: Path | None = None,
                 echo: Callable[[str], None] = print, progress: bool = False,
                 ammeter: str | None = None, stages: tuple[str, ...] = ANALYSIS,
                 resume: bool = False, without_current: bool = False,
                 operator: str = "auto", analyse: Analyse | None = None, plot: bool = False,
                 verbosity: int = 0, stage_options: dict[str, dict[str, Any]] | None = None,
                 allow_other_board: bool = False) -> dict[str, Any]:
    """Run the four procedures on `port`, then the analysis `stages`; write out/report.md.

    resume: continue the campaign already in `out`: a procedure whose run is complete is kept,
    an interrupted (or failed) run is resumed, a missing one is run. Without it, `out` must not
    hold runs yet (the analysis reads every run there, so two campaigns must not mix).

    analyse(runs_dir, out, robot_file, echo, stages) runs the analysis stages and returns their
    results by name (the command line passes omnibench.campaign.stages.run_analysis); None skips them.
    stage_options: more options for a stage, by stage name (e.g. {"diagnose": {"candidates": [...]}}).

    Ctrl-C (KeyboardInterrupt) at any point: the motors are stopped (the procedure's run is marked
    aborted), report.md and campaign.json are written with what finished and where it stopped
    ("status": "interrupted", "stopped_at"), and the KeyboardInterrupt goes on to the caller.
    With `resume`, analysis stages that finished before the interruption are kept when no run
    changed since; every run taken or resumed must be on the board the earlier runs were taken on
    unless `allow_other_board` (then each run records the change)."""
    from omnibench.bench.session import completed_run_summary, load_robot_file, preflight, run_command
    from omnibench.procedures import load_plan

    out = Path(out)
    files = procedure_files(procedures_dir)
    # validate everything before the first motor moves
    robot, _, _ = load_robot_file(robot_file)
    plans = {p: load_plan(f, robot, expect=p) for p, f in files.items()}
    runs_dir = out / "runs"
    earlier = _runs_of(runs_dir)
    if resume and not earlier and not (out / "campaign.json").is_file():
        raise UserError(f"nothing to resume in {out}: it holds no campaign (no runs, no campaign.json); "
                        "check --out, or start the campaign without --resume")
    if not port:
        raise UserError("no --port given (sim:// for the simulated robot)")
    if earlier and not resume:
        raise UserError(f"{runs_dir} already holds runs of a campaign: continue it with --resume, "
                        "or give another --out")
    for p in files:
        if len(earlier.get(p, [])) > 1:
            raise UserError(f"{runs_dir} holds {len(earlier[p])} {p} runs; keep one, so the campaign "
                            "knows which to continue")
    todo = [plans[p] for p in files if not any(st == "complete" for _, st in earlier.get(p, []))]
    preflight(todo, port, ammeter=ammeter, without_current=without_current)  # the board can run them all
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    results: dict[str, Any] = {"port": port, "out": str(out), "tool_version": __version__,
                               "robot_file": str(robot_file) if robot_file else "default", "procedures": {},
                               "analysis": {}, "status": "running"}
    earlier_analysis = _interrupted_analysis(out) if resume else None
    where = ""
    again = f"omnibench campaign --resume --port {port} --out {out}" + (f" --robot {robot_file}" if robot_file else "")
    run_said = False
    try:
        for p, f in files.items():
            (prior, status), = earlier.get(p, [(None, None)])
            if status == "complete":
                echo(f"== {COMMAND_OF[p]}: kept (complete) {prior}")
                results["procedures"][p] = completed_run_summary(p, prior, echo)  # type: ignore[arg-type]
                continue
            earlier_analysis = None  # the runs change: every analysis stage runs again
            where = COMMAND_OF[p]
            echo(f"== {COMMAND_OF[p]}: " + (f"resuming {prior}" if prior else str(f)))
            taken = [d for runs in earlier.values() for d, _ in runs if d != prior]
            taken += [Path(r["run"]) for r in results["procedures"].values() if r.get("run")]
            try:
                res = run_command(p, port=port, procedure_file=f, robot_file=robot_file, out=runs_dir, echo=echo,
                                  progress=progress, ammeter=ammeter if p == "energy_trajectories" else None,
                                  resume=prior, without_current=without_current, operator=operator, plot=plot,
                                  verbosity=verbosity, same_board_as=sorted(set(taken)),
                                  allow_other_board=allow_other_board, resume_command=again)
            except KeyboardInterrupt:
                run_said = True  # the run has printed where its data is and how to continue
                raise
            results["procedures"][p] = res
        where = "analysis"
        if analyse is None:
            results["analysis"] = {n: {"status": "skipped", "why": "no analysis runner given"} for n in ANALYSIS}
        else:
            kwargs: dict[str, Any] = {"into": results["analysis"]}
            if earlier_analysis:
                kwargs["earlier"] = earlier_analysis
            if stage_options:
                kwargs["extra"] = stage_options
            analyse(runs_dir, out, robot_file, echo, stages, **kwargs)
    except KeyboardInterrupt:
        where = next((n for n, st in results["analysis"].items() if st.get("status") == "interrupted"), where)
        results.update(status="interrupted", stopped_at=where)
        how = "terminated (SIGTERM)" if isinstance(sys.exc_info()[1], Terminated) else "interrupted (Ctrl-C)"
        echo(f"campaign {how} in {where}: the motors are stopped, the runs and the finished "
             f"stages are kept in {out}" + ("" if run_said else f"; continue with: {again}"))
        finish_campaign(results, out, robot, t0, echo, summary=False)
        raise
    results["status"] = "complete"
    finish_campaign(results, out, robot, t0, echo, summary=True)
    return results


def _interrupted_analysis(out: Path) -> dict[str, Any] | None:
    """The analysis stages of the interrupted campaign in `out` (its campaign.json), else None."""
    try:
        data = json.loads((out / "campaign.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("status") != "interrupted" or not isinstance(data.get("analysis"), dict):
        return None
    return data["analysis"]


def finish_campaign(results: dict[str, Any], out: Path, robot: Robot, t0: float, echo: Callable[[str], None], *,
            summary: bool) -> None:
    """Plots, report.md, report.html and campaign.json for `results` (complete or interrupted)."""
    from omnibench.campaign.html_report import write_html
    from omnibench.runs.store import json_ready

    try:
        results["plots"] = make_plots(results, out, robot)
    except Exception as exc:  # an interrupted campaign's partial data must not lose the report
        if results.get("status") != "interrupted":
            raise
        results["plots"] = {}
        echo(f"   (plots left out: {type(exc).__name__}: {exc})")
    results["host_seconds"] = time.monotonic() - t0
    report = write_report(results, out, robot)
    results["report"] = str(report)
    results["report_html"] = str(write_html(report))
    write_atomic(out / "campaign.json", json.dumps(json_ready(results), indent=2, default=str) + "\n",
                 "campaign summary")
    if summary:
        from omnibench.campaign.summary import campaign_summary

        for line in campaign_summary(results):
            echo(line)
    else:
        echo(f"report so far: {results['report']} and {results['report_html']}")


# --------------------------------------------------------------------------- analysis stages
def parse_stages(text: str) -> tuple[str, ...]:
    """'fit,validate-energy' -> ('fit', 'validate-energy'); 'none' -> (); UserError otherwise."""
    if text.strip().lower() == "none":
        return ()
    if not text.strip():
        raise UserError("--analysis '': give the stages (fit,validate-energy,diagnose) or none")
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    for n in names:
        if n not in ANALYSIS:
            raise UserError(f"--analysis {text!r}: unknown stage {n!r}; stages are {', '.join(ANALYSIS)} or none")
    return names


def _fmt_num(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, (int, float)):
        return f"{v:.4g}"
    return str(v)


def _pct(v: Any) -> str:
    """A fraction (NRMSE, gain) as a percentage, '–' when missing."""
    if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
        return f"{100 * v:.3g} %"
    return "–"


def _pct3(v: Any) -> str:
    """A value already in percent, to 3 significant digits ('–' when missing)."""
    if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
        return f"{v:.3g} %"
    return "–"


def diagnose_lines(res: dict[str, Any]) -> list[str]:
    """Markdown for diagnose's JSON: what was added and why, held-out error before/after,
    what was rejected, what stays ambiguous or unexplained."""
    lines = ["", "| procedure | held-out error before | after |", "|---|---|---|"]
    before, after = res.get("before") or {}, res.get("after") or {}
    for proc in before:
        b, a = (before.get(proc) or {}).get("nrmse"), (after.get(proc) or {}).get("nrmse")
        lines.append(f"| {proc} | {_pct(b)} | {_pct(a)} |")
    lines.append("")
    if res["selected"]:
        lines += ["**Added**", ""]
        for sel in res["selected"]:
            params = ", ".join(f"{k} = {with_se(v.get('value'), v.get('se'))} {unit_words(v.get('unit'))}".rstrip()
                               for k, v in (sel.get("parameters") or {}).items())
            ev = sel.get("evidence") or {}
            lines.append(f"- `{sel['effect']}` ({sel.get('title', '')}): {params}; likelihood ratio "
                         f"{_fmt_num(ev.get('likelihood_ratio'))} for {ev.get('parameters_added')} parameter(s), "
                         f"p = {_fmt_num(ev.get('p_value'))}, held-out weighted error lower by {_fmt_num(ev.get('heldout_gain'))}")
    else:
        lines.append("**Added**: nothing: no candidate effect earned its parameters on held-out runs.")
    lines.append("")
    for amb in res.get("ambiguous") or []:
        lines.append(f"- ambiguous: `{amb.get('chosen')}` vs `{amb.get('alternative')}` "
                     f"(AIC difference {_fmt_num(amb.get('aic_difference'))}); to separate them: {amb.get('experiment')}")
    for un in res.get("unexplained") or []:
        lines.append(f"- unexplained structure in {un.get('group')} against {un.get('variable')} "
                     f"(p = {_fmt_num(un.get('p'))}): {un.get('where') or un.get('location')}")
    if res.get("rejected"):
        lines += ["", "**Rejected candidates**, by round", ""]
        rounds: dict[Any, list[dict[str, Any]]] = {}
        for r in res["rejected"]:
            rounds.setdefault(r.get("round"), []).append(r)
        for rnd, rs in rounds.items():
            lines.append(f"- round {rnd if rnd is not None else '?'}: "
                         + "; ".join(f"`{r.get('effect')}` ({r.get('reason')})" for r in rs))
    for note in res.get("notes") or []:
        lines.append(f"- note: {note}")
    return lines


def analysis_lines(name: str, st: dict[str, Any], out: Path) -> list[str]:
    """Markdown for one analysis stage's JSON result (tables where the shape is known)."""
    res = st.get("result")
    lines: list[str] = []
    if isinstance(res, dict) and isinstance(res.get("parameters"), dict):
        lines += ["", "| parameter | value ± SE | 95 % interval | unit | verdict |", "|---|---|---|---|---|"]
        for k, v in res["parameters"].items():
            if isinstance(v, dict):
                ci = v.get("ci95") or [None, None]
                se = v.get("se") if v.get("identifiable", True) else None
                lines.append(f"| {k} | {with_se(v.get('value'), se)} | "
                             f"[{rounded_like(ci[0], se)}, {rounded_like(ci[1], se)}] | {unit_words(v.get('unit'))} | "
                             f"{v.get('verdict', '')} |")
        lines.append("")
        for key in ("rank", "n_parameters", "condition_number"):
            if key in res:
                lines.append(f"- {key.replace('_', ' ')}: {_fmt_num(res[key])}")
        for c in res.get("confounded") or []:
            lines.append(f"- confounded: {c.get('combination')} is what the data see ({', '.join(c.get('with') or [])} "
                         f"with {c.get('fixed')} held fixed)")
        errs = res.get("error_by_procedure") or {}
        if errs:
            lines.append("- error by procedure (NRMSE): " + ", ".join(f"{k} {_pct(v)}" for k, v in errs.items()))
        for note in res.get("notes", []) or []:
            lines.append(f"- note: {note}")
    elif isinstance(res, dict) and isinstance(res.get("runs"), list) and name == "validate-energy":
        lines += ["", "| trajectory | measured (J) | predicted (J) | error (%) |", "|---|---|---|---|"]
        for r in res["runs"]:
            lines.append(f"| {r.get('trajectory')} | {_fmt_num(r.get('measured_J'))} | {_fmt_num(r.get('predicted_J'))} | "
                         f"{_fmt_num(r.get('error_pct'))} |")
        lines.append("")
        if "mean_abs_error_pct" in res:
            lines.append(f"- mean |error| {_fmt_num(res['mean_abs_error_pct'])} %, "
                         f"max {_fmt_num(res.get('max_abs_error_pct'))} %")
    elif isinstance(res, dict) and name == "diagnose" and "selected" in res:
        lines += diagnose_lines(res)
    elif isinstance(res, dict):
        lines += [""] + [f"- {k.replace('_', ' ')}: {_fmt_num(v)}" for k, v in res.items()
                         if isinstance(v, (int, float, str, bool)) or v is None]
    else:
        body = (st.get("stdout") or "").strip()
        if body:
            lines += ["", "```", *body.splitlines()[-40:], "```"]
    plots = list(res.get("plots") or []) if isinstance(res, dict) else []
    if isinstance(res, dict):  # diagnose names its plots under "written"
        plots += [p for p in ((res.get("written") or {}).get("plots") or []) if p not in plots]
    if plots:
        lines.append("")  # the figures as their own paragraph, not inside the last list item
    for p in plots:
        with contextlib.suppress(ValueError):
            lines.append(f"![{name}]({Path(p).resolve().relative_to(out.resolve())})")
    return lines + [""]


def answer_lines(ans: Answer, out: Path) -> list[str]:
    """The report's first section: what was identified, how well, what diagnosis added, the
    energy error before/after, and the final model's coefficient table."""
    lines = ["## The answer", ""]
    if not ans.coefficients:
        return lines + ["Nothing was identified: the fit did not run or failed (see Analysis below).", ""]
    wrong = inadequacy(ans)
    if wrong:  # the first thing the report says: these numbers are this model's reading of runs it does not fit
        lines += [f"**{wrong[0]}**", ""] + [f"- {w}" for w in wrong[1:]] + [""]
    n = len(ans.coefficients)
    if ans.model == "diagnosed":
        added = " and ".join(f"`{s.get('effect')}` ({s.get('title', '')})".replace(" ()", "") for s in ans.added)
        lines.append(f"**Identified**: the declared model plus {added}, which diagnosis added: {n} coefficients, "
                     "each with its standard error (SE) and 95 % interval (the fit's own, as in its table; "
                     "value ± 1.96 SE for a refitted coefficient). "
                     "*Before* is the declared model's fit, before diagnosis.")
    else:
        head = "**Fitted** (not identified: the model does not fit these runs, above)" if wrong else "**Identified**"
        lines.append(f"{head}: the declared model, {n} coefficients, each with its standard error (SE), "
                     "95 % interval (the fit's own, as in the fit table) and identifiability verdict."
                     + (" Diagnosis added nothing: no candidate effect earned its parameters on held-out runs."
                        if ans.heldout else ""))
    lines.append("")
    if ans.model == "diagnosed":
        lines += ["| coefficient | value ± SE | 95 % interval | unit | before (declared fit) |", "|---|---|---|---|---|"]
        for c in ans.coefficients:
            cell = c.cells()
            name = f"**{c.name}** (added)" if c.added else c.name
            lines.append(f"| {name} | {cell['value']} | {cell['ci95']} | {cell['unit']} | {cell['before']} |")
    else:
        lines += ["| coefficient | value ± SE | 95 % interval | unit | verdict |", "|---|---|---|---|---|"]
        for c in ans.coefficients:
            cell = c.cells()
            lines.append(f"| {c.name} | {cell['value']} | {cell['ci95']} | {cell['unit']} | {c.verdict} |")
    lines.append("")
    if ans.energy_before is not None:
        if ans.energy_after is not None:
            lines.append(f"- **Energy** (predicted vs measured battery energy, mean |error|): {_pct3(ans.energy_before)} "
                         f"with the declared fit → **{_pct3(ans.energy_after)}** with the diagnosed model")
        else:
            lines.append(f"- **Energy** (predicted vs measured battery energy, mean |error|): {_pct3(ans.energy_before)}")
    if ans.fit_error:
        lines.append("- **How well** the declared fit matches the runs (NRMSE): "
                     + ", ".join(f"{k} {_pct(v)}" for k, v in ans.fit_error.items()))
    if ans.heldout:
        lines.append("- **Held-out error** (runs the fit did not see), declared → "
                     + ("diagnosed" if ans.model == "diagnosed" else "refitted") + ": "
                     + ", ".join(f"{k} {_pct(b)} → {_pct(a)}" for k, (b, a) in ans.heldout.items()))
    for s in ans.added:
        vals = ", ".join(f"{k.split('.')[-1]} = {with_se(v.get('value'), v.get('se'))} {unit_words(v.get('unit'))}".rstrip()
                         for k, v in (s.get("parameters") or {}).items())
        lines.append(f"- **Diagnosis added** `{s.get('effect')}`: {vals}")
    for un in ans.unexplained:
        lines.append(f"- **Left unexplained**: {un.get('group')} against {un.get('variable')}")
    if ans.model_file:
        with contextlib.suppress(ValueError):
            lines.append(f"- model file: `{Path(ans.model_file).resolve().relative_to(out.resolve())}`")
    return lines + [""]


# --------------------------------------------------------------------------- plots
def make_plots(results: dict[str, Any], out: Path, robot: Robot) -> dict[str, str]:
    """PNG plots of each procedure's results (matplotlib, headless)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from omnibench.runs import read_run

    plots: dict[str, str] = {}
    folder = out / "plots"
    folder.mkdir(parents=True, exist_ok=True)
    runs = {p: read_run(r["run"]) for p, r in results["procedures"].items() if r.get("run")}

    if "upside_down_sweep" in runs:
        st = runs["upside_down_sweep"].steps
        fig, ax = plt.subplots(figsize=(7, 4.5))
        sets = list(st.groupby("wheel_set", sort=False))
        span = float(st["voltage"].abs().max() or 1.0)
        for k, (ws, grp) in enumerate(sets):
            for j in range(1, 5):
                # each wheel set and wheel a little apart in voltage, open markers for the later
                # sets: points at the same duty stay visible side by side instead of on top
                dx = span * 0.01 * ((k - (len(sets) - 1) / 2) * 5 + (j - 2.5))
                ax.plot(grp["voltage"] + dx, grp[f"w{j}"], "os^v"[j - 1], ms=5, alpha=0.75, color=f"C{k}",
                        mfc=f"C{k}" if k == 0 else "none", mew=1.2,
                        label=f"{ws} ({grp['wheel_mass1'].iloc[0]:g} kg)" if j == 1 else None)
        ax.set_xlabel("motor voltage u·V_batt (V); wheels FL, FR, RL, RR: ○ □ △ ▽, set apart slightly")
        ax.set_ylabel("steady wheel speed (rad/s)")
        ax.set_title("III.i upside-down sweep: steady speed per wheel")
        ax.axhline(0, color="grey", lw=0.5)
        ax.grid(alpha=0.3)
        ax.legend()
        plots["sweep"] = _save(fig, folder / "sweep_steady_speed.png", plt)

    for p, title in (("forward_runs", "III.ii forward runs: no-slip check"),
                     ("lateral_runs", "III.iii lateral runs: roller slip")):
        if p not in runs:
            continue
        st = runs[p].steps
        fig, ax = plt.subplots(figsize=(6, 4.5))
        if p == "forward_runs":
            ax.plot(st["encoder_distance"].abs(), st["measured_distance"], "o")
            lim = float(max(st["measured_distance"].max(), 0.1)) * 1.05
            ax.plot([0, lim], [0, lim], "k--", lw=0.8, label="no slip")
            ax.set_xlabel("encoder rolling distance r·mean(Δφ) (m)")
            ax.set_ylabel("measured distance (m)")
        else:
            for pay, grp in st.groupby("payload"):
                ax.plot(np.degrees(grp["heading"]) % 360, grp["slip"], "o", label=f"payload {pay:g} kg")
            ax.set_xlabel("heading (deg, 0 = forward, 90 = left)")
            ax.set_ylabel("tape minus rolling distance (m)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend()
        plots[COMMAND_OF[p]] = _save(fig, folder / f"{p}.png", plt)

    if "energy_trajectories" in runs:
        run = runs["energy_trajectories"]
        st = run.steps
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
        labels = [f"{t}#{r}" for t, r in zip(st["trajectory"], st["repetition"])]
        a1.bar(labels, st["energy"].fillna(0.0))
        a1.set_ylabel("battery energy (J)")
        a1.set_title("IV energy per trajectory")
        a1.tick_params(axis="x", rotation=30)
        for _, s in st.iterrows():
            d = run.step_samples(int(s["step"]))
            if d["I_batt"].notna().any():
                a2.plot(d["t"] - d["t"].iloc[0], d["V_batt"] * d["I_batt"], lw=0.8, label=s["trajectory"])
        a2.set_xlabel("time in trajectory (s)")
        a2.set_ylabel("battery power V·I (W)")
        a2.grid(alpha=0.3)
        a2.legend()
        plots["energy"] = _save(fig, folder / "energy.png", plt)
    return plots


def _save(fig: Any, path: Path, plt: Any) -> str:
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return str(path)


# --------------------------------------------------------------------------- report
def write_report(results: dict[str, Any], out: Path, robot: Robot) -> Path:
    """report.md: what was run, what it found, what each analysis stage said."""
    from omnibench.bench.session import summary_lines
    from omnibench.runs import read_run

    ports = sorted({str(read_run(r["run"]).info.port) for r in results["procedures"].values()
                    if r.get("run")}) or [results["port"]]
    lines = ["# omnibench campaign report", ""]
    if results.get("status") == "interrupted":
        lines += [f"**Interrupted (Ctrl-C) in {results.get('stopped_at')}**: this report holds what "
                  "finished before; `omnibench campaign --resume` with the same `--out` continues from there.", ""]
    lines += answer_lines(campaign_answer(results.get("analysis") or {}), out)
    lines += ["## The campaign", "",
              f"- port: {', '.join(f'`{x}`' for x in ports)}", f"- robot file: {results['robot_file']} ({robot.name})",
              f"- omnibench {results['tool_version']}",
              f"- host time: {results.get('host_seconds', math.nan):.0f} s"]
    first = next(iter(results["procedures"].values()), None)
    if first and first.get("run"):
        board = read_run(first["run"]).info.board or {}
        if board:
            lines += [f"- board: id {board.get('board_id')}, firmware {board.get('firmware_version')}, "
                      f"protocol {board.get('protocol_version')}, capabilities {', '.join(board.get('capabilities', []))}"]
    lines.append("")
    lines += ["## Procedures", ""]
    for p, res in results["procedures"].items():
        run = read_run(res["run"])
        lines += [f"### {LABELS[p]}", "", f"- run: `{res['run']}` — {run.status}, {len(run.steps)} steps, "
                  f"{len(run.samples)} samples", f"- port: `{run.info.port}`",
                  f"- procedure file: `{run.info.procedure_file}`"]
        for line in summary_lines(p, {k: v for k, v in res.items()}, len(run.steps)):
            lines.append(f"- {line}")
        plot = results.get("plots", {}).get(COMMAND_OF[p])
        if plot:
            lines += ["", f"![{p}]({Path(plot).relative_to(out)})"]
        lines.append("")
    lines += ["## Analysis", ""]
    for name, st in results["analysis"].items():
        if st["status"] == "skipped":
            lines.append(f"- **{name}: skipped** — {st['why']}")
        elif st["status"] == "interrupted":
            lines.append(f"- **{name}: interrupted** (Ctrl-C) — `{st.get('command', '')}`")
        else:
            lines.append(f"- **{name}: {st['status']}** — `{st['command']}`")
            if st["status"] == "failed" and st.get("stderr"):
                lines.append(f"  - error: {st['stderr'].strip().splitlines()[-1]}")
            else:
                if name == "fit" and (results.get("analysis", {}).get("diagnose") or {}).get("result", {}).get("selected"):
                    lines.append("  - the declared model's fit, **before** diagnosis (the answer above is the diagnosed model)")
                lines += analysis_lines(name, st, out)
                after = st.get("validate_energy")
                if name == "diagnose" and isinstance(after, dict):
                    lines.append(f"- **validate-energy on the diagnosed model: {after['status']}** — `{after.get('command', '')}`")
                    lines += analysis_lines("validate-energy", after, out)
    lines.append("")
    path = out / "report.md"
    return write_atomic(path, "\n".join(lines), "report")
