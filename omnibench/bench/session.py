"""One procedure run from the command line's point of view: validate everything, open the
board, create (or resume) the run directory, run, and leave the motors stopped and the run
marked on every exit path.

Order matters: the robot file, the procedure file, the limits and the answers file are all
checked before the port is opened, so a bad input never moves a motor.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omnibench.errors import UserError
from omnibench.procedures import (
    LABELS,
    Plan,
    default_procedure_path,
    duty_limit,
    load_plan,
    stall_current,
    step_distance_bound,
)
from omnibench.runs.store import is_run_dir

if TYPE_CHECKING:
    from omnibench.model.robot import Robot


def load_robot_file(robot_file: str | Path | None) -> tuple[Any, str, str]:
    """(Robot, its TOML text as run, its path or 'default')."""
    from omnibench.model.robot import DEFAULT_ROBOT_FILE, load_robot

    path = Path(robot_file) if robot_file else DEFAULT_ROBOT_FILE
    robot = load_robot(path)
    return robot, path.read_text(encoding="utf-8"), str(path) if robot_file else f"default ({path.name})"


def plan_summary(plan: Plan, robot: Robot) -> dict[str, Any]:
    """What a dry run prints: steps, driving time bound, peak voltage and current, actions."""
    from omnibench.bench.operator import actions_for

    world = None
    n_actions = 0
    for s in plan.steps:
        n_actions += len(actions_for(world, s.world)) + (1 if s.kind in ("timed", "trajectory") else 0)
        world = s.world
    peak_u = plan.peak_duty
    peak_batt = 0.0
    for s in plan.steps:
        for _, u in s.schedule:
            # every motor stalled at once: I_batt = sum(u_i * i_i) + I_0 with i_i = u_i V / R_a
            peak_batt = max(peak_batt, sum(abs(x) * stall_current(robot, x) for x in u) + robot.I_0)
    return {
        "procedure": plan.procedure,
        "procedure_file": plan.path,
        "steps": len(plan.steps),
        "max_driving_time_s": plan.max_duration,
        "operator_actions": n_actions,
        "measurements": sum(1 for s in plan.steps if s.measure),
        "peak_duty": peak_u,
        "peak_voltage_V": peak_u * robot.V_batt,
        "peak_motor_current_A": stall_current(robot, peak_u),
        "peak_battery_current_A": peak_batt,
        "limits": {"max_duty": robot.max_duty, "max_current_A": robot.max_current,
                   "duty_limit": duty_limit(robot), "max_distance_m": plan.settings.get("max_distance_m")},
        "max_step_distance_m": max((step_distance_bound(s, robot) for s in plan.steps
                                    if s.world.mode == "ground" and s.schedule), default=0.0),
    }


def format_plan(plan: Plan, robot: Robot) -> list[str]:
    s = plan_summary(plan, robot)
    lines = [f"{LABELS[plan.procedure]} from {plan.path}: {s['steps']} steps"]
    world = None
    for st in plan.steps:
        if st.world != world:
            lines.append(f"  -- {st.world.describe()}")
            world = st.world
        bound = "at most " if st.kind == "hold" else ""
        extra = f", then {st.measure} measured" if st.measure else ""
        lines.append(f"  {st.index:3d}  {st.label}: {bound}{st.max_time:.1f} s{extra}")
    lines.append(f"driving time: at most {s['max_driving_time_s']:.0f} s of board time "
                 f"(plus {s['operator_actions']} operator actions)")
    if s["max_step_distance_m"] > 0:
        lines.append(f"ground steps take the robot at most {s['max_step_distance_m']:.2f} m from their start (no-load speeds; "
                     f"[space] max_distance {s['limits']['max_distance_m']:g} m, enforced from the encoders)")
    lines.append(f"peak voltage {s['peak_voltage_V']:.1f} V (duty {s['peak_duty']:.2f}, limit "
                 f"{s['limits']['duty_limit']:.3g}); peak motor current {s['peak_motor_current_A']:.1f} A at stall "
                 f"(limit {robot.max_current:g} A); battery at most {s['peak_battery_current_A']:.1f} A")
    return lines


def _num(v: Any) -> Any:
    """None for missing values (pandas gives NaN for a column a row lacks)."""
    if isinstance(v, float) and math.isnan(v):
        return None
    return v


def summarise(procedure: str, records: list[dict[str, Any]]) -> dict[str, Any]:
    """Lab-level results of a run's completed steps (used for the report and --json)."""
    records = [{k: _num(v) for k, v in r.items()} for r in records]
    out: dict[str, Any] = {}
    if procedure == "upside_down_sweep":
        out["steady_steps"] = sum(1 for r in records if r.get("steady"))
        out["not_steady_steps"] = [r["step"] for r in records if not r.get("steady")]
    elif procedure in ("forward_runs", "lateral_runs"):
        slips = [abs(r["slip"]) for r in records if r.get("slip") is not None]
        out["no_slip_passed"] = sum(1 for r in records if r.get("no_slip"))
        out["no_slip_failed"] = [r["step"] for r in records if r.get("no_slip") is False]
        out["max_abs_slip_m"] = max(slips) if slips else None
    elif procedure == "energy_trajectories":
        out["energy_J"] = {f"{r['trajectory']}#{r['repetition']}": r.get("energy") for r in records}
    return out


def applied_duties(samples: Any, firmware_timing: Any) -> dict[str, Any] | None:
    """How the drivers applied the run's duties, when its firmware timing names their
    resolution: {"steps": per direction, "changed": [[commanded, applied], ...] for each distinct
    commanded duty the drivers cannot represent}; None for a run without one."""
    driver = firmware_timing.get("driver") if isinstance(firmware_timing, dict) else None
    if not isinstance(driver, dict) or not driver.get("steps"):
        return None
    import numpy as np

    from omnibench.model.actuation import applied_duty

    cols = [c for c in ("u1", "u2", "u3", "u4") if c in getattr(samples, "columns", ())]
    u = np.unique(np.round(samples[cols].to_numpy(dtype=float), 5)) if cols and len(samples) else np.zeros(0)
    u = u[np.isfinite(u) & (u != 0)]
    a = applied_duty(u, steps=int(driver["steps"]), wire_scale=int(driver.get("wire_scale", 32767)))
    changed = [[float(x), round(float(y), 6)] for x, y in zip(u, a) if abs(x - y) > 1e-5]
    return {"steps": int(driver["steps"]), "changed": changed}


def summary_lines(procedure: str, summary: dict[str, Any], n: int) -> list[str]:
    out = _procedure_lines(procedure, summary, n)
    applied = summary.get("applied_duties")
    if isinstance(applied, dict) and applied.get("changed"):
        pairs = applied["changed"]
        shown = ", ".join(f"{c:g} as {a:.4g}" for c, a in pairs[:6]) + (f" and {len(pairs) - 6} more" if len(pairs) > 6 else "")
        out.append(f"duties as the drivers apply them (nearest of {applied['steps']} steps per direction): {shown} "
                   "(recorded as commanded; the analysis uses the applied duties)")
    return out


def _procedure_lines(procedure: str, summary: dict[str, Any], n: int) -> list[str]:
    if procedure == "upside_down_sweep":
        bad = summary["not_steady_steps"]
        return [f"steady state reached in {summary['steady_steps']}/{n} steps"
                + (f" (not steady: steps {bad})" if bad else "")]
    if procedure == "forward_runs":
        return [f"no-slip check: {summary['no_slip_passed']}/{n} runs passed"
                + (f", largest |encoder - tape| {summary['max_abs_slip_m'] * 1000:.1f} mm"
                   if summary["max_abs_slip_m"] is not None else "")]
    if procedure == "lateral_runs":
        slipped = len(summary["no_slip_failed"])
        return [f"roller slip reported on {slipped}/{n} runs"
                + (f" (largest {summary['max_abs_slip_m']:.3f} m between rolling distance and tape)"
                   if summary["max_abs_slip_m"] is not None else "")]
    if procedure == "energy_trajectories":
        return [f"{k}: " + (f"{v:.1f} J" if v is not None else "no battery current logged")
                for k, v in summary["energy_J"].items()]
    return []


#: errors of the output file system: reported in one line naming the file, run left resumable
DISK_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EDQUOT, errno.EFBIG, errno.EIO}
#: bytes claimed (run.json.reserve) before the robot moves, so a full disk can still mark run.json
RESERVE_BYTES = 256 * 1024


@contextlib.contextmanager
def run_lock(run_dir: Path) -> Iterator[None]:
    """Hold an exclusive lock on the run directory (nothing is written): a second process
    writing the same run (two `--resume` at once) is refused, naming the first."""
    from omnibench import locks

    try:
        fd = locks.lock_directory(run_dir)
    except locks.Locked as exc:
        raise UserError(f"{run_dir}: this run is being written by {exc.holder}; wait for it to end "
                        "(one process per run)") from None
    try:
        yield
    finally:
        os.close(fd)


def disk_error_line(exc: OSError, run_dir: Path) -> str:
    """'cannot write FILE: No space left on device' (the file named)."""
    name = exc.filename or (run_dir / "samples.csv")
    return f"cannot write {name}: {exc.strerror or exc}"


def run_command(
    procedure: str,
    *,
    port: str | None,
    procedure_file: str | Path | None,
    robot_file: str | Path | None,
    out: str | Path,
    dry_run: bool = False,
    resume: str | Path | None = None,
    answers: str | Path | None = None,
    echo: Callable[[str], None] = print,
    progress: bool = True,
    measurement_noise: float | None = None,
    timeout: float | None = None,
    ammeter: str | None = None,
    operator: str = "auto",
    without_current: bool = False,
    wiring: str | Path | None = None,
    plot: bool = False,
    verbosity: int = 0,
    same_board_as: Sequence[Path] = (),
    allow_other_board: bool = False,
    resume_command: str | None = None,
) -> dict[str, Any]:
    """Validate, then run (or resume, or dry-run) one procedure. Returns a JSON-able summary.

    Raises UserError for bad input before any motor moves; KeyboardInterrupt propagates after
    the motors are stopped and the run is marked aborted.

    operator: "auto" (the simulated operator on a simulator, the answers file, else the person at
    the keyboard), "person" (always the keyboard; on a simulator the world follows the answers)
    or "simulated". without_current: let `energy` drive without any battery current source.
    same_board_as: runs the new one must share a board with (a campaign's earlier runs; a resumed
    run is always checked); allow_other_board: go on on another board, recorded in the run.
    resume_command: the command a user types to continue (a campaign gives its own).
    """
    from omnibench.bench.operator import AnswersOperator

    # 1. everything from files, before any port is touched
    if resume is not None:
        run_dir = Path(resume)
        from omnibench.runs.record import check_resumable

        info, _ = check_resumable(run_dir, procedure)  # every file checked; nothing written yet
        robot, robot_text, robot_name = load_robot_file(run_dir / "robot.toml")
        robot_name = info.robot_file or robot_name
        plan = load_plan(run_dir / "procedure.toml", robot, expect=procedure)
        if info.steps_planned not in (None, len(plan.steps)):
            raise UserError(f"{run_dir}: procedure.toml expands to {len(plan.steps)} steps, "
                            f"run.json planned {info.steps_planned}")
    else:
        robot, robot_text, robot_name = load_robot_file(robot_file)
        pfile = Path(procedure_file) if procedure_file else default_procedure_path(procedure)
        plan = load_plan(pfile, robot, expect=procedure)
        out_path = Path(out)
        if out_path.exists() and not out_path.is_dir():
            raise UserError(f"--out {out_path}: exists and is not a directory (runs are written into a directory)")
        if is_run_dir(out_path):
            raise UserError(f"--out {out_path}: is a run directory; give the folder that should hold the new run, "
                            "or --resume it")
    if measurement_noise is not None and not 0 <= measurement_noise <= 1:
        raise UserError(f"--measurement-noise {measurement_noise:g}: give the tape's noise in metres, in [0, 1]")
    if operator not in OPERATORS:
        raise UserError(f"--operator {operator!r}: choose {', '.join(OPERATORS)}")
    from omnibench.bench.wiring import wiring_for

    wired, wiring_file = wiring_for(wiring)
    answer_op = AnswersOperator(answers) if answers else None
    if answer_op is not None:
        answer_op.check(plan.steps)
    summary = plan_summary(plan, robot)
    if dry_run:
        for line in format_plan(plan, robot):
            echo(line)
        return {"dry_run": True, **summary}
    if not port:
        raise UserError("no --port given (a serial device such as /dev/ttyACM0, or sim:// for the simulated robot)")

    # 2. the board (a resumed run is locked first: a second --resume is refused before any port)
    from omnibench.bench.link_adapter import open_bench_board

    if port.startswith("sim:"):
        _prepare_kernel(echo if progress and verbosity >= 0 else None)

    with (run_lock(Path(resume)) if resume is not None else contextlib.nullcontext()), \
            open_bench_board(port, timeout=timeout, ammeter=ammeter) as board:
        if wired is not None:
            from omnibench.bench.wiring import WiredBoard

            board = WiredBoard(board, wired)
            echo(f"wiring from {wiring_file}: {wired.describe()}")
        return _run_on_board(procedure, plan, robot, robot_text, robot_name, board, port=port, out=out,
                             resume=resume, answer_op=answer_op, echo=echo, progress=progress,
                             measurement_noise=measurement_noise, who=operator,
                             without_current=without_current, plot=plot, verbosity=verbosity,
                             wiring_file=str(wiring_file) if wired is not None and wiring_file else None,
                             same_board_as=same_board_as, allow_other_board=allow_other_board,
                             resume_command=resume_command)


OPERATORS = ("auto", "person", "simulated")


def _prepare_kernel(echo: Callable[[str], None] | None) -> None:
    """Load the simulator's physics kernel now, with a spinner: the first time on a machine (or
    after a code change) it compiles for about 35 s of CPU, which used to look like a hang."""
    import time

    from omnibench.model.kernel import load_kernel

    if echo is None:
        load_kernel()
        return
    from rich.console import Console

    t0 = time.monotonic()
    with Console(stderr=True).status("preparing the simulated robot's physics kernel "
                                     "(compiled once per machine and code version: about 35 s the first time)"):
        load_kernel()
    if time.monotonic() - t0 > 2.0:
        echo(f"physics kernel ready ({time.monotonic() - t0:.0f} s)")


def _wiring_record(board: Any) -> dict[str, Any] | None:
    """The wiring the run used (None: straight, no wiring file)."""
    from dataclasses import asdict

    w = getattr(board, "wiring", None)
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(w).items()} if w is not None else None


def firmware_timing_record(board: Any) -> dict[str, Any] | None:
    """The run's `firmware_timing`: how the board's firmware rounds and times the duties, when
    its HELLO says the duties go to the packet-serial drivers (omnibench/model/actuation.py);
    None when the board does not say (the analysis then applies no firmware timing)."""
    if not getattr(board, "packet_serial_drivers", False):
        return None
    from omnibench.model.actuation import firmware_timing

    return firmware_timing()


def _choose_operator(board: Any, plan: Plan, robot: Robot, answer_op: Any, measurement_noise: float | None,
                     who: str = "auto") -> Any:
    from omnibench.bench.operator import ConsoleOperator, SimulatedOperator

    sim = getattr(board, "is_simulator", False)
    if who == "person":
        return ConsoleOperator(robot, mirror=board if sim else None)
    if who == "simulated" and not sim:
        raise UserError("--operator simulated needs a simulated board (sim:// or omnibench sim serve)")
    if sim:
        op = plan.settings.get("operator", {})
        noise = op.get("measurement_noise", 0.002) if measurement_noise is None else measurement_noise
        return SimulatedOperator(board, noise=noise, seed=op.get("seed", 1), measurer=answer_op)
    if answer_op is not None:
        return answer_op
    return ConsoleOperator(robot)


def missing_current(plan: Plan, board: Any, port: str, without_current: bool) -> str | None:
    """Why `plan` cannot run on `board` for want of a battery current (energy needs it: the
    board's sensor or an ammeter attached), or None."""
    if plan.procedure != "energy_trajectories" or getattr(board, "has_battery_current", False):
        return None
    if plan.settings.get("ammeter_required"):
        return (f"{plan.path}: [ammeter] required = true, but the board on {port} reports no "
                "battery current sensor and no --ammeter was given")
    if not without_current:
        return (f"energy needs the battery current, but the board on {port} reports no battery "
                "current sensor and no --ammeter was given: give --ammeter URL, or --without-current "
                "to drive the trajectories anyway (no energy is measured)")
    return None


def preflight(plans: Sequence[Plan], port: str, *, ammeter: str | None = None, without_current: bool = False,
              timeout: float | None = None) -> None:
    """Open the board once and check that it can run every plan (a campaign's procedures)
    before the first one moves a motor: UserError naming the first that cannot."""
    from omnibench.bench.link_adapter import open_bench_board

    needs_board = [p for p in plans if p.procedure == "energy_trajectories"]
    if not needs_board:
        return
    with open_bench_board(port, timeout=timeout, ammeter=ammeter) as board:
        for plan in needs_board:
            problem = missing_current(plan, board, port, without_current)
            if problem:
                raise UserError(f"{problem} (checked before the campaign's first procedure)")


def _check_same_board(now: dict[str, Any], hello: dict[str, Any], port: str, runs: Sequence[Path],
                      allow_other_board: bool, echo: Callable[[str], None]) -> dict[str, Any]:
    """Refuse to go on with `runs` (the run resumed, a campaign's earlier runs) on a board that is
    not the one they were taken on, before anything is written; with `allow_other_board`, say so
    and return what changed, for the new segment. A new boot id alone is recorded, not refused."""
    from omnibench.runs.provenance import board_changes, latest_provenance
    from omnibench.runs.record import read_info

    changes: list[str] = []
    rebooted = False
    for run in runs:
        try:
            before = latest_provenance(read_info(run).raw)
        except (OSError, ValueError, UserError):
            continue  # a run that cannot be read is refused by the resume itself, naming the file
        found = board_changes(before, now)
        if found and not allow_other_board:
            raise UserError(f"{port} is not the board {run} was taken on ({'; '.join(found)}): connect that board, "
                            "or give --allow-other-board to go on here (recorded as a new segment on this board)")
        if found:
            echo(f"warning: {run} goes on on another board ({'; '.join(found)}); --allow-other-board: "
                 "recorded in the run")
        changes += [c for c in found if c not in changes]
        was, boot = before.get("boot_id"), hello.get("boot_id")
        rebooted = rebooted or (was is not None and boot is not None and was != boot)
    return {"changes": changes, "rebooted": rebooted}


def _run_on_board(procedure: str, plan: Plan, robot: Robot, robot_text: str, robot_name: str, board: Any, *,
                  port: str, out: str | Path, resume: str | Path | None, answer_op: Any,
                  echo: Callable[[str], None], progress: bool,
                  measurement_noise: float | None, who: str = "auto",
                  without_current: bool = False, plot: bool = False, verbosity: int = 0,
                  wiring_file: str | None = None, same_board_as: Sequence[Path] = (),
                  allow_other_board: bool = False, resume_command: str | None = None) -> dict[str, Any]:
    import click

    from omnibench.bench.runner import Runner, Terminated, safe_stop, sigterm_as_interrupt
    from omnibench.runs import RunWriter
    from omnibench.runs.provenance import run_provenance
    from omnibench.runs.record import read_info, read_steps
    from omnibench.runs.store import RunLog

    def steps_done(path: Path) -> list[int]:
        return [int(r["step"]) for r in read_steps(path, read_info(path))]

    hello = dict(getattr(board, "hello", {}) or {})
    cpr = hello.get("counts_per_rev") or robot.counts_per_rev
    problem = missing_current(plan, board, port, without_current)
    if problem:
        raise UserError(problem)
    operator = _choose_operator(board, plan, robot, answer_op, measurement_noise, who)
    provenance = run_provenance(
        robot=robot.to_toml_dict(), robot_file=robot_name, robot_text=robot_text, hello=hello,
        port=port, simulated=bool(getattr(board, "is_simulator", port.startswith("sim:"))),
        wiring_file=wiring_file)
    changes = _check_same_board(provenance, hello, port, ([Path(resume)] if resume is not None else [])
                                + list(same_board_as), allow_other_board, echo)
    if resume is not None:
        try:
            writer = RunWriter.resume(Path(resume), board=hello, segment_info={
                "port": port, "provenance": provenance, "board_changes": changes["changes"],
                "rebooted": changes["rebooted"]})  # validates every file first
        except OSError as exc:
            raise UserError(f"cannot resume {resume}: {disk_error_line(exc, Path(resume))}") from None
        done = set(steps_done(writer.path))
        todo = [s for s in plan.steps if s.index not in done]
        announce = f"resuming {writer.path}: {len(done)} of {len(plan.steps)} steps already complete"
    else:
        try:
            writer = RunWriter.create(
                Path(out), procedure, procedure_text=plan.text, procedure_file=str(plan.path),
                robot=robot.to_toml_dict(), robot_text=robot_text, robot_file=robot_name, board=hello,
                port=port, counts_per_rev=cpr,
                extra={"steps_planned": len(plan.steps), "plan": plan_summary(plan, robot),
                       "settings": plan.settings, "wiring": _wiring_record(board),
                       "provenance": provenance, "firmware_timing": firmware_timing_record(board),
                       **({"board_changes": changes["changes"]} if changes["changes"] else {})},
                reserve=RESERVE_BYTES,  # room to mark the run on a full disk, claimed before the robot moves
            )
        except OSError as exc:
            need = (f" (a run claims {RESERVE_BYTES // 1024} KiB before the robot moves, to mark run.json on a "
                    "full disk)") if str(exc.filename or "").endswith(".reserve") else ""
            raise UserError(f"cannot create a run under {out}: {disk_error_line(exc, Path(out))}{need}") from None
        todo = list(plan.steps)
        announce = f"{LABELS[procedure]}: run {writer.path}"
    status: str = "failed"
    reason: str | None = "unknown"
    disk_full = False
    lock = run_lock(writer.path) if resume is None else contextlib.nullcontext()
    locked = False
    log: Callable[[str], None] = lambda line: None  # noqa: E731 - until log.txt is open
    restore: Callable[[], Any] = lambda: None  # noqa: E731 - until SIGTERM is caught, nothing to restore
    try:
        # from here on a Ctrl-C marks the run aborted (a Ctrl-C right after the run folder was
        # made, as the operator read its path, left run.json saying "running")
        echo(announce)
        lock.__enter__()
        locked = True
        log = RunLog(writer.path)  # log.txt: what the terminal said
        log(f"{LABELS[procedure]} on {port}, operator {operator.source}")
        restore = sigterm_as_interrupt()
        if resume is not None:  # a new run claimed its reserve as it was created
            writer.reserve(max(RESERVE_BYTES, 8 * len(json.dumps(writer.metadata, default=str))))
        writer.update(operator=operator.source)
        total = sum(s.max_time for s in todo)
        view = None
        if progress and todo and verbosity >= 0:
            from omnibench.bench.live import LiveView, display_available

            if plot and not display_available():
                echo("--plot: no display here (DISPLAY/WAYLAND_DISPLAY unset): terminal view only")
            view = LiveView(LABELS[procedure], total, len(plan.steps), cpr, plot=plot and display_available())
        elif plot:
            echo("--plot needs the live view (a terminal, without -q/--json)")

        def runner_echo(line: str) -> None:
            log(line)
            if view is None or verbosity > 0:
                echo(line)

        runner = Runner(plan, robot, board, writer, operator,
                        progress=view.advance if view is not None else None, echo=runner_echo, view=view)
        try:
            runner.run(todo)
        finally:
            if view is not None:
                view.close()
        status, reason = "complete", None
    except Terminated:
        status, reason = "aborted", "terminated (SIGTERM)"
        raise
    except KeyboardInterrupt:
        status, reason = "aborted", "interrupted by the operator (Ctrl-C)"
        raise
    except click.exceptions.Abort:
        status, reason = "aborted", "the operator declined an action (or the input ended)"
        raise
    except UserError as exc:
        status, reason = "failed", str(exc)
        raise
    except OSError as exc:
        if exc.errno not in DISK_ERRNOS:
            status, reason = "failed", f"{type(exc).__name__}: {exc}".splitlines()[0]
            raise
        status, reason, disk_full = "failed", disk_error_line(exc, writer.path), True
        raise UserError(reason) from None
    except Exception as exc:
        status, reason = "failed", f"{type(exc).__name__}: {exc}".splitlines()[0]
        raise
    finally:
        stopped = safe_stop(board)
        writer.release_reserve()  # frees the space run.json needs, even on a full disk
        try:
            writer.event("motors_stopped", confirmed=stopped)
            if getattr(board, "link_stats", None) is not None:
                writer.update(link=board.link_stats)  # retries, lost frames, CRC and time faults
        except Exception:  # noqa: BLE001
            pass
        try:
            writer.finish(status, reason)
        except OSError as exc:  # never hide the first error; say what could not be marked
            click.echo(f"omnibench: also {disk_error_line(exc, writer.path)} (run.json may still say running)",
                       err=True)
        log(f"run {status}" + (f": {reason}" if reason else "") + f"; motors {'stopped' if stopped else 'NOT confirmed stopped'}")
        restore()
        if locked:
            lock.__exit__(None, None, None)
        if status != "complete":
            resumable = status == "aborted" or disk_full
            from omnibench.procedures import COMMAND_OF

            again = resume_command or f"omnibench {COMMAND_OF[procedure]} --resume {writer.path} --port {port}"
            click.echo(f"run {status}: {reason}; motors {'stopped' if stopped else 'NOT confirmed stopped'}; "
                       f"data kept in {writer.path}"
                       + (f"; continue{' once there is space' if disk_full else ''} with: {again}" if resumable else ""),
                       err=True)
    return completed_run_summary(procedure, writer.path, echo)


def completed_run_summary(procedure: str, path: str | Path, echo: Callable[[str], None] = print) -> dict[str, Any]:
    """The JSON-able summary of a complete run of `procedure`, read back from its files."""
    from omnibench.runs import read_run

    run = read_run(path)
    recs = run.steps.to_dict("records")
    res = summarise(procedure, recs)
    applied = applied_duties(run.samples, run.info.firmware_timing)
    if applied is not None:
        res["applied_duties"] = applied
    for line in summary_lines(procedure, res, len(recs)):
        echo(line)
    echo(f"run complete: {path} ({len(run.steps)} steps, {len(run.samples)} samples)")
    return {"run": str(path), "status": "complete", "procedure": procedure,
            "steps": int(len(run.steps)), "samples": int(len(run.samples)), **res}
