"""The campaign: every procedure in turn, then fit, validate-energy and diagnose, one report.

The analysis stages belong to omnibench.analysis (written separately). The campaign calls
their commands (`omnibench fit`, `validate-energy`, `diagnose`) only when they are installed,
and says in the report which stages ran, which were skipped and why.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from omnibench import __version__
from omnibench.bench.procedure import PROCEDURES, default_procedure_path
from omnibench.errors import UserError

COMMAND_OF = {
    "upside_down_sweep": "sweep",
    "forward_runs": "forward",
    "lateral_runs": "lateral",
    "energy_trajectories": "energy",
}
ANALYSIS = ("fit", "validate-energy", "diagnose")


def procedure_files(folder: Path | None) -> dict[str, Path]:
    """The four procedure files: <folder>/<procedure>.toml, else the shipped ones."""
    out = {}
    for p in PROCEDURES:
        if folder is not None:
            f = Path(folder) / f"{p}.toml"
            if not f.is_file():
                raise UserError(f"{folder}: no {p}.toml (the campaign needs all four procedure files)")
            out[p] = f
        else:
            out[p] = default_procedure_path(p)
    return out


def _runs_of(runs_dir: Path) -> dict[str, list[tuple[Path, str]]]:
    """Run directories in runs_dir by procedure, oldest first, each with its status."""
    found: dict[str, list[tuple[Path, str]]] = {}
    for run_json in sorted(runs_dir.glob("*/run.json")) if runs_dir.is_dir() else []:
        try:
            meta = json.loads(run_json.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            raise UserError(f"{run_json}: unreadable run.json; move that run out of {runs_dir}") from None
        found.setdefault(str(meta.get("procedure")), []).append((run_json.parent, str(meta.get("status"))))
    return found


def run_campaign(port: str, out: Path, *, robot_file: Path | None = None, procedures_dir: Path | None = None,
                 echo: Callable[[str], None] = print, progress: bool = False,
                 ammeter: str | None = None, stages: tuple[str, ...] = ANALYSIS,
                 resume: bool = False, without_current: bool = False,
                 operator: str = "auto") -> dict[str, Any]:
    """Run the four procedures on `port`, then the analysis `stages`; write out/report.md.

    resume: continue the campaign already in `out`: a procedure whose run is complete is kept,
    an interrupted (or failed) run is resumed, a missing one is run. Without it, `out` must not
    hold runs yet (the analysis reads every run there, so two campaigns must not mix)."""
    from omnibench.bench.procedure import load_plan
    from omnibench.bench.session import completed_run_summary, load_robot_file, run_command

    out = Path(out)
    files = procedure_files(procedures_dir)
    # validate everything before the first motor moves
    robot, _, _ = load_robot_file(robot_file)
    for p, f in files.items():
        load_plan(f, robot, expect=p)
    if not port:
        raise UserError("no --port given (sim:// for the simulated robot)")
    runs_dir = out / "runs"
    earlier = _runs_of(runs_dir)
    if earlier and not resume:
        raise UserError(f"{runs_dir} already holds runs of a campaign: continue it with --resume, "
                        "or give another --out")
    for p in files:
        if len(earlier.get(p, [])) > 1:
            raise UserError(f"{runs_dir} holds {len(earlier[p])} {p} runs; keep one, so the campaign "
                            "knows which to continue")
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    results: dict[str, Any] = {"port": port, "out": str(out), "tool_version": __version__,
                               "robot_file": str(robot_file) if robot_file else "default", "procedures": {},
                               "analysis": {}}
    for p, f in files.items():
        (prior, status), = earlier.get(p, [(None, None)])
        if status == "complete":
            echo(f"== {COMMAND_OF[p]}: kept (complete) {prior}")
            results["procedures"][p] = completed_run_summary(p, prior, echo)
            continue
        echo(f"== {COMMAND_OF[p]}: " + (f"resuming {prior}" if prior else str(f)))
        res = run_command(p, port=port, procedure_file=f, robot_file=robot_file, out=runs_dir, echo=echo,
                          progress=progress, ammeter=ammeter if p == "energy_trajectories" else None,
                          resume=prior, without_current=without_current, operator=operator)
        results["procedures"][p] = res
    results["analysis"] = run_analysis(runs_dir, out, robot_file, echo, stages)
    plots = make_plots(results, out, robot)
    results["plots"] = plots
    results["host_seconds"] = time.monotonic() - t0
    report = write_report(results, out, robot)
    results["report"] = str(report)
    from omnibench.runs.store import json_ready

    (out / "campaign.json").write_text(json.dumps(json_ready(results), indent=2, default=str) + "\n",
                                       encoding="utf-8")
    echo(f"report: {report}")
    return results


# --------------------------------------------------------------------------- analysis stages
def _analysis_command(name: str) -> Any | None:
    """The click command for `name` if its module is installed, else None."""
    import importlib
    import importlib.util

    from omnibench.cli import COMMANDS

    module = COMMANDS[name][0]
    try:
        if importlib.util.find_spec(module) is None:
            return None
        mod = importlib.import_module(module)
    except ImportError:
        return None
    return mod.commands[name] if hasattr(mod, "commands") else getattr(mod, "command", None)


def _invoke(cmd: Any, name: str, args: list[str]) -> tuple[int, str, str]:
    """Run a click command in process; (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            cmd.main(args=args, prog_name=f"omnibench {name}", standalone_mode=False)
        except SystemExit as exc:
            code = int(exc.code or 0)
        except UserError as exc:
            code = exc.exit_code
            err.write(f"omnibench: error: {exc}\n")
        except Exception as exc:  # noqa: BLE001 - a failing later stage must not lose the campaign
            code = 1
            err.write(f"omnibench: internal error: {type(exc).__name__}: {exc}\n")
    return code, out.getvalue(), err.getvalue()


def _options(cmd: Any) -> set[str]:
    names: set[str] = set()
    for p in getattr(cmd, "params", []):
        names.update(getattr(p, "opts", []))
    return names


def parse_stages(text: str) -> tuple[str, ...]:
    """'fit,validate-energy' -> ('fit', 'validate-energy'); 'none' -> (); UserError otherwise."""
    if text.strip().lower() in ("none", ""):
        return ()
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    for n in names:
        if n not in ANALYSIS:
            raise UserError(f"--analysis {text!r}: unknown stage {n!r}; stages are {', '.join(ANALYSIS)} or none")
    return names


def run_analysis(runs_dir: Path, out: Path, robot_file: Path | None, echo: Callable[[str], None],
                 stages_wanted: tuple[str, ...] = ANALYSIS) -> dict[str, Any]:
    """fit, validate-energy, diagnose on the campaign's runs, each only if installed.

    fit writes OUT/model.toml; validate-energy and diagnose use it (or the robot file when
    the fit did not run). Options are passed only if the installed command declares them.
    """
    from omnibench.model.robot import DEFAULT_ROBOT_FILE

    stages: dict[str, Any] = {}
    model_file = out / "model.toml"
    model: Path = Path(robot_file) if robot_file else DEFAULT_ROBOT_FILE
    for name in ANALYSIS:
        if name not in stages_wanted:
            stages[name] = {"status": "skipped", "why": "not asked for (--analysis)"}
            echo(f"== {name}: skipped (not asked for)")
            continue
        cmd = _analysis_command(name)
        if cmd is None:
            stages[name] = {"status": "skipped", "why": f"`omnibench {name}` is not installed yet (omnibench.analysis)"}
            echo(f"== {name}: skipped (not installed yet)")
            continue
        opts = _options(cmd)
        args: list[str] = []
        if name == "fit":
            if "--out" in opts:
                args += ["--out", str(model_file)]
            if "--robot" in opts and robot_file is not None:
                args += ["--robot", str(robot_file)]
        else:
            if "--model" in opts:
                args += ["--model", str(model)]
            if "--out" in opts:  # diagnose writes the extended model (a TOML file)
                args += ["--out", str(out / f"model_{name.replace('-', '_')}.toml")]
        if "--plots" in opts:
            args += ["--plots", str(out / "plots" / name)]
        if "--json" in opts:
            args += ["--json"]
        args.append(str(runs_dir))
        echo(f"== {name}: omnibench {name} {' '.join(args)}")
        code, so, se = _invoke(cmd, name, args)
        stage: dict[str, Any] = {"status": "ok" if code == 0 else "failed", "exit_code": code,
                                 "command": f"omnibench {name} {' '.join(args)}",
                                 "stdout": so[-4000:], "stderr": se[-2000:]}
        if "--json" in args:
            with contextlib.suppress(json.JSONDecodeError):
                stage["result"] = json.loads(so)
        if name == "fit" and code == 0 and model_file.is_file():
            model = model_file
            stage["model"] = str(model_file)
        stages[name] = stage
        echo(f"   {stage['status']}" + (f": {se.strip().splitlines()[-1]}" if code and se.strip() else ""))
    return stages


def _fmt_num(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, (int, float)):
        return f"{v:.4g}"
    return str(v)


def diagnose_lines(res: dict[str, Any]) -> list[str]:
    """Markdown for diagnose's JSON: what was added and why, held-out error before/after,
    what was rejected, what stays ambiguous or unexplained."""
    lines = ["", "| procedure | held-out error before | after |", "|---|---|---|"]
    before, after = res.get("before") or {}, res.get("after") or {}
    for proc in before:
        b, a = (before.get(proc) or {}).get("nrmse"), (after.get(proc) or {}).get("nrmse")
        lines.append(f"| {proc} | {_fmt_num(b)} | {_fmt_num(a)} |")
    lines.append("")
    if res["selected"]:
        lines += ["**Added**", ""]
        for sel in res["selected"]:
            params = ", ".join(f"{k} = {_fmt_num(v.get('value'))} ± {_fmt_num(v.get('se'))} {v.get('unit', '')}".rstrip()
                               for k, v in (sel.get("parameters") or {}).items())
            ev = sel.get("evidence") or {}
            lines.append(f"- `{sel['effect']}` ({sel.get('title', '')}): {params}; likelihood ratio "
                         f"{_fmt_num(ev.get('likelihood_ratio'))} for {ev.get('parameters_added')} parameter(s), "
                         f"p = {_fmt_num(ev.get('p_value'))}, held-out gain {_fmt_num(ev.get('heldout_gain'))}")
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
        lines += ["", "<details><summary>rejected candidates</summary>", ""]
        lines += [f"- `{r.get('effect')}`: {r.get('reason')}" for r in res["rejected"]]
        lines += ["", "</details>"]
    for note in res.get("notes") or []:
        lines.append(f"- note: {note}")
    return lines


def analysis_lines(name: str, st: dict[str, Any], out: Path) -> list[str]:
    """Markdown for one analysis stage's JSON result (tables where the shape is known)."""
    res = st.get("result")
    lines: list[str] = []
    if isinstance(res, dict) and isinstance(res.get("parameters"), dict):
        lines += ["", "| parameter | value | std. error | 95 % interval | unit | verdict |", "|---|---|---|---|---|---|"]
        for k, v in res["parameters"].items():
            if isinstance(v, dict):
                ci = v.get("ci95") or [None, None]
                lines.append(f"| {k} | {_fmt_num(v.get('value'))} | {_fmt_num(v.get('se'))} | "
                             f"[{_fmt_num(ci[0])}, {_fmt_num(ci[1])}] | {v.get('unit', '')} | {v.get('verdict', '')} |")
        lines.append("")
        for key in ("rank", "n_parameters", "condition_number", "confounded", "error_by_procedure"):
            if key in res:
                lines.append(f"- {key.replace('_', ' ')}: {_fmt_num(res[key]) if not isinstance(res[key], (dict, list)) else res[key]}")
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
    elif res is not None:
        text = json.dumps(res, indent=2, default=str).splitlines()
        lines += ["", "```json", *text[:60], *(["..."] if len(text) > 60 else []), "```"]
    else:
        body = (st.get("stdout") or "").strip()
        if body:
            lines += ["", "```", *body.splitlines()[-40:], "```"]
    plots = res.get("plots") if isinstance(res, dict) else None
    for p in plots or []:
        with contextlib.suppress(ValueError):
            lines.append(f"![{name}]({Path(p).resolve().relative_to(out.resolve())})")
    return lines + [""]


# --------------------------------------------------------------------------- plots
def make_plots(results: dict[str, Any], out: Path, robot: Any) -> dict[str, str]:
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
        for k, (ws, grp) in enumerate(st.groupby("wheel_set", sort=False)):
            for j in range(1, 5):
                ax.plot(grp["voltage"], grp[f"w{j}"], "os^v"[j - 1], ms=4, alpha=0.7, color=f"C{k}",
                        label=f"{ws} ({grp['wheel_mass1'].iloc[0]:g} kg)" if j == 1 else None)
        ax.set_xlabel("motor voltage u·V_batt (V)")
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
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


# --------------------------------------------------------------------------- report
def write_report(results: dict[str, Any], out: Path, robot: Any) -> Path:
    """report.md: what was run, what it found, what each analysis stage said."""
    from omnibench.bench.session import LABELS, summary_lines
    from omnibench.runs import read_run

    lines = ["# omnibench campaign report", "",
             f"- port: `{results['port']}`", f"- robot file: {results['robot_file']} ({robot.name})",
             f"- omnibench {results['tool_version']}",
             f"- host time: {results.get('host_seconds', math.nan):.0f} s", ""]
    first = next(iter(results["procedures"].values()), None)
    if first and first.get("run"):
        board = read_run(first["run"]).metadata.get("board") or {}
        if board:
            lines += [f"- board: id {board.get('board_id')}, firmware {board.get('firmware_version')}, "
                      f"protocol {board.get('protocol_version')}, capabilities {', '.join(board.get('capabilities', []))}", ""]
    lines += ["## Procedures", ""]
    for p, res in results["procedures"].items():
        run = read_run(res["run"])
        lines += [f"### {LABELS[p]}", "", f"- run: `{res['run']}` — {run.status}, {len(run.steps)} steps, "
                  f"{len(run.samples)} samples", f"- procedure file: `{run.metadata.get('procedure_file')}`"]
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
        else:
            lines.append(f"- **{name}: {st['status']}** — `{st['command']}`")
            if st["status"] == "failed" and st.get("stderr"):
                lines.append(f"  - error: {st['stderr'].strip().splitlines()[-1]}")
            else:
                lines += analysis_lines(name, st, out)
    lines.append("")
    path = out / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
