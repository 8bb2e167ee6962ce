"""The runner: executes a plan's steps on a board, records everything, stops the motors on
every exit path.

Timing follows the board's clock (telemetry time stamps), so a simulated board may run faster
than real time; the host's clock only bounds every phase (HOST_SLACK_S beyond its planned
board time), so no frame with a wrong time can hold a duty longer than planned.

A step's results come only from samples taken under its own command: the board time in each
command's acknowledgement says when the board applied it, and a sample is used only if it is
later than that and reports the duties commanded then (telemetry that queued up on the port
while the host was busy is written to samples.csv but never counted for the step). The
board's watchdog is fed from the runner's loop (`keepalive` every eighth of the watchdog of board or
host time), never by a thread, so a hung runner lets the board stop the motors. Between steps the runner asks the operator for
the physical actions the next step's world needs (flip, swap wheels, place a weight) and, for
timed runs, for the start mark and the measurement after the run.

Results each step adds to its record (units SI):

- ``hold`` (upside-down sweep): ``steady`` (bool), ``hold_time`` s, ``average`` s, ``w1..w4`` steady
  wheel speeds rad/s (slope of a straight-line fit of the wheel angle over the last `average` s),
  ``w_std1..4`` rad/s (std of the two-reading speeds in that window), ``i1..i4`` mean motor
  currents A, ``V_batt``, ``I_batt`` means, ``t_hold`` board time the duty was applied.
- ``timed`` (forward/lateral): ``dphi1..4`` rad (encoder angle change over the run),
  ``encoder_distance`` m = r * mean(dphi) (the rolling distance), ``kin_forward``/``kin_left``
  m (displacement from pinv(R) dphi), ``measured_distance`` or ``measured_forward``/``measured_left``
  m (the operator's tape), ``slip`` m (measured minus rolling), ``no_slip`` (bool).
- ``trajectory`` (energy): ``energy`` J (trapezoid of V_batt*I_batt over the step), ``charge`` C,
  ``I_batt_mean``, ``I_batt_peak`` A, ``has_current`` (bool).
"""

from __future__ import annotations

import functools
import math
import signal
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from omnibench.bench.operator import Action, actions_for
from omnibench.errors import BoardError, Terminated, UserError
from omnibench.procedures import Plan, Step, World

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

#: A tape reading this many no-slip tolerances away from the encoders is questioned at once.
QUESTION_FACTOR = 3.0

FAULT_NAMES = ("WATCHDOG", "OVERCURRENT", "UNDERVOLTAGE", "DRIVER", "ESTOP")
DUTY_LSB = 1.0 / 32767      #: duty resolution on the wire: a reported duty within one LSB is the commanded one
HOST_SLACK_S = 3.0          #: a phase ends when its board time is done, or this long (host clock) after


def fault_names(flags: int) -> str:
    return "+".join(n for b, n in enumerate(FAULT_NAMES) if flags & (1 << b)) or f"0x{flags:02x}"


# --------------------------------------------------------------------------- steady state
@dataclass
class SteadyVerdict:
    steady: bool
    slope: np.ndarray  # rad/s^2 per wheel
    t_stat: np.ndarray
    std: np.ndarray  # rad/s
    floor: np.ndarray  # rad/s
    n: int


def steady_state(t: np.ndarray, phi: np.ndarray, *, window: float, confidence: float,
                 noise_factor: float, relative_tolerance: float, counts_per_rev: float) -> SteadyVerdict:
    """Are the wheel speeds steady over the last `window` seconds of (t s, phi (n,4) rad)?

    Speeds come from successive readings, w_k = dphi/dt. Per wheel, steady when
      (a) the slope of a straight-line fit of w against t is not significantly different from
          zero (two-sided t-test at `confidence`), or the speed change it implies over the
          window is below half the noise floor (a drift too small to matter), and
      (b) std(w) <= noise_factor * floor, where floor = max(quantisation noise of a
          two-reading speed, 2 pi / counts_per_rev / (median dt * sqrt 6),
          relative_tolerance * |mean w|).
    """
    sel = t >= t[-1] - window
    tt, pp = t[sel], phi[sel]
    n = len(tt) - 1
    if n < 6:
        z = np.zeros(phi.shape[1])
        return SteadyVerdict(False, z, z, z, z, n)
    dt = np.diff(tt)
    w = np.diff(pp, axis=0) / dt[:, None]
    tm = 0.5 * (tt[1:] + tt[:-1])
    x = tm - tm.mean()
    sxx = float((x**2).sum())
    slope = (x[:, None] * (w - w.mean(axis=0))).sum(axis=0) / sxx
    resid = w - w.mean(axis=0) - np.outer(x, slope)
    s2 = (resid**2).sum(axis=0) / max(n - 2, 1)
    se = np.sqrt(s2 / sxx)
    t_stat = np.where(se > 0, np.abs(slope) / np.where(se > 0, se, 1.0), np.where(slope == 0, 0.0, np.inf))
    t_crit = _t_crit(confidence, max(n - 2, 1))
    q = 2.0 * math.pi / float(counts_per_rev)
    quant = q / (float(np.median(dt)) * math.sqrt(6.0))
    floor = np.maximum(quant, relative_tolerance * np.abs(w.mean(axis=0)))
    std = w.std(axis=0, ddof=1)
    slope_ok = (t_stat < t_crit) | (np.abs(slope) * window <= 0.5 * floor)
    std_ok = std <= noise_factor * floor
    return SteadyVerdict(bool(np.all(slope_ok & std_ok)), slope, t_stat, std, floor, n)


@functools.lru_cache(maxsize=256)
def _t_crit(confidence: float, dof: int) -> float:
    """Two-sided Student-t critical value (cached: evaluated many times per step). scipy.special's
    stdtrit is what scipy.stats.t.ppf evaluates, bit for bit, without importing scipy.stats."""
    from scipy import special

    return float(special.stdtrit(dof, 0.5 + confidence / 2.0))


def angle_slope(t: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Least-squares slope of each wheel angle against time (rad/s), (n,4) -> (4,)."""
    x = t - t.mean()
    return (x[:, None] * (phi - phi.mean(axis=0))).sum(axis=0) / float((x**2).sum())


# --------------------------------------------------------------------------- runner
@dataclass
class StepData:
    """Samples of the current step, kept in memory for the step's results."""

    t: list[float] = field(default_factory=list)
    enc: list[tuple[int, ...]] = field(default_factory=list)
    cur: list[tuple[float, ...] | None] = field(default_factory=list)
    V: list[float | None] = field(default_factory=list)
    I: list[float | None] = field(default_factory=list)
    rejected: int = 0  #: samples read during the step but not taken under its command
    #: dead reckoning from the encoders (x m, y m, psi rad in the start frame), samples used, farthest m
    pose: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    pose_n: int = 0
    farthest: float = 0.0

    def arrays(self, counts_per_rev: float) -> tuple[np.ndarray, np.ndarray]:
        t = np.asarray(self.t, dtype=float)
        phi = np.asarray(self.enc, dtype=float).reshape(-1, 4) * (2 * math.pi / counts_per_rev)
        return t, phi


class Runner:
    """Runs the steps of `plan` on `board`, writing to `writer`, asking `operator`.

    `progress(board_seconds_done, label)` is called as board time advances.
    `echo(line)` prints one line for the engineer.
    """

    def __init__(self, plan: Plan, robot: Robot, board: Any, writer: Any, operator: Any, *,
                 progress: Callable[[float, str], None] | None = None,
                 echo: Callable[[str], None] | None = None, read_timeout: float = 2.0,
                 view: Any = None) -> None:
        self.plan, self.robot, self.board, self.writer, self.operator = plan, robot, board, writer, operator
        self._progress = progress or (lambda done, label: None)
        self._step_progress = 0.0
        self.echo = echo or (lambda line: None)
        self.read_timeout = read_timeout
        #: the live view (omnibench.bench.live.LiveView): every sample, and a pause before prompts
        self.view = view
        self.world: World | None = None
        self.cpr = float(getattr(board, "hello", {}).get("counts_per_rev") or robot.counts_per_rev)
        self.watchdog_s = float(plan.settings.get("watchdog_s", 0.5))
        self.telemetry_hz = float(plan.settings.get("telemetry_hz", 100.0))
        self._paused = False  # telemetry off while a person works (see _quiet)
        #: the lab's space for one ground step, m ([space] max_distance), enforced from the encoders
        self.max_distance = plan.settings.get("max_distance_m")
        from omnibench.model.geometry import inverse_kinematics

        self._pinv_R = np.linalg.pinv(inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha))
        #: keepalive period: 8 PINGs per watchdog timeout, so that on a cable losing 20 % of
        #: the host's frames the watchdog still fires only when the runner stops (0.2^8 ~ 3e-6)
        self.keep_every = self.watchdog_s / 8.0
        self._fed_board = -math.inf   # board time of the last frame sent (command or keepalive)
        self._fed_host = -math.inf    # host clock of the same
        #: (board time applied, duties) of the commands in force, oldest first (None: no ack time)
        self._applied: list[tuple[float | None, tuple[float, ...]]] = []
        self._duties = (0.0, 0.0, 0.0, 0.0)
        self.done_time = 0.0
        self.records: list[dict[str, Any]] = []

    def progress(self, dt: float, label: str) -> None:
        """Report `dt` board seconds of progress, capped at the step's planned maximum."""
        self._step_progress += dt
        self._progress(dt, label)

    # -- board helpers ----------------------------------------------------------------------
    def _applied_at(self, t: float | None, duties: tuple[float, ...]) -> None:
        self._applied.append((t, duties))
        del self._applied[:-8]  # older commands cannot matter for samples still to come
        self._fed_host = time.monotonic()
        if t is not None:
            self._fed_board = t

    def _command(self, duties: Sequence[float]) -> None:
        self._duties = tuple(float(u) for u in duties)  # type: ignore[assignment]
        self._applied_at(self.board.set_duties(self._duties), self._duties)

    def _stop(self) -> None:
        self._duties = (0.0, 0.0, 0.0, 0.0)
        self._applied_at(self.board.stop(), self._duties)

    def _feed_watchdog(self, t_board: float) -> None:
        """Keepalive when an eighth of the watchdog timeout of board or host time passed since
        the last frame sent: called only from the runner's loop, so the board stops the motors if it hangs."""
        now = time.monotonic()
        if t_board - self._fed_board >= self.keep_every or now - self._fed_host >= self.keep_every:
            self.board.keepalive()
            self._fed_board, self._fed_host = t_board, now

    def _under_command(self, s: Any, t_from: float | None) -> bool:
        """Was sample `s` taken under the runner's current commands? It must be later than
        `t_from` (the phase's first command) and report the duties of the command in force
        at its time (the latest one applied before it)."""
        if t_from is not None and not s.t > t_from:
            return False
        in_force = None
        for t_ack, duties in self._applied:
            if t_ack is None or t_ack < s.t:
                in_force = duties
        if in_force is None:
            return False
        return all(abs(float(a) - b) <= 1.01 * DUTY_LSB for a, b in zip(s.duty, in_force))

    def _read(self, step: Step, data: StepData, t_from: float | None = None) -> Any:
        """Read and record the next sample; returns it if it was taken under the current
        command (after `t_from`, with the commanded duties), else None. Samples not taken
        under the step's command are written to samples.csv with no step."""
        s = self.board.read(self.read_timeout)
        ok = self._under_command(s, t_from)
        mc = s.motor_current if getattr(self.board, "has_motor_current", True) else None
        ib = s.battery_current if getattr(self.board, "has_battery_current", True) else None
        row = {"step": step.index if ok else None, "t": s.t, "seq": s.seq, "faults": s.faults,
               **{f"u{j + 1}": s.duty[j] for j in range(4)},
               **{f"enc{j + 1}": s.encoder[j] for j in range(4)},
               "V_batt": s.battery_voltage, "I_batt": ib}
        if mc is not None:
            row.update({f"i{j + 1}": mc[j] for j in range(4)})
        self.writer.sample(row)
        if self.view is not None:
            self.view.sample(step, s)
        if s.faults:
            self.writer.event("fault", t=s.t, step=step.index, flags=int(s.faults), names=fault_names(int(s.faults)))
            self._stop()
            raise BoardError(f"board reported fault {fault_names(int(s.faults))} during step {step.index} "
                             f"({step.label})")  # the session then confirms the motors stopped
        self._feed_watchdog(s.t)
        if not ok:
            data.rejected += 1
            return None
        data.t.append(s.t)
        data.enc.append(tuple(s.encoder))
        data.cur.append(tuple(mc) if mc is not None else None)
        data.V.append(s.battery_voltage)
        data.I.append(ib)
        return s

    def _next(self, step: Step, data: StepData, t_from: float | None, host_end: float) -> Any:
        """The next sample under the current command (None once `host_end` has passed)."""
        while time.monotonic() <= host_end:
            s = self._read(step, data, t_from)
            if s is not None:
                return s
        return None

    def _run_for(self, step: Step, data: StepData, duration: float,
                 schedule: list[tuple[float, tuple[float, ...]]] | None,
                 until: Callable[[float], bool] | None = None,
                 accept_from: float | None = None) -> tuple[float, float]:
        """Apply `schedule` (None: motors off, as the caller left them) for `duration` board
        seconds; returns (t0, t_end): board time the phase's command was applied, last sample.

        Only samples taken under the step's commands (after `accept_from`, default: this
        phase's command) are added to `data` and count time. The phase also ends
        `HOST_SLACK_S` after its duration on the host's clock. After an operator pause the
        link is re-synchronised first."""
        self._resync()
        if schedule:
            self._command(schedule[0][1])
        t_cmd = self._applied[-1][0] if self._applied else None
        t_from = t_cmd if accept_from is None else accept_from
        host_end = time.monotonic() + duration + HOST_SLACK_S
        k = 0
        s = self._next(step, data, t_from, host_end)
        if s is None:
            return self._host_limit(step, t_cmd, t_cmd)
        t0 = t_cmd if t_cmd is not None else s.t
        last_progress = t0
        while True:
            rel = s.t - t0
            if rel >= duration or (until is not None and until(rel)):
                break
            if schedule:
                while k + 1 < len(schedule) and rel >= schedule[k + 1][0]:
                    k += 1
                    self._command(schedule[k][1])
            if s.t - last_progress >= 0.2:
                self.progress(s.t - last_progress, step.label)
                last_progress = s.t
            nxt = self._next(step, data, t_from, host_end)
            if nxt is None:
                self._host_limit(step, t0, s.t)
                break
            s = nxt
            self._check_space(step, data)
        self.progress(s.t - last_progress, step.label)
        return t0, s.t

    def distance_from_start(self, data: StepData) -> float:
        """How far the robot is from where the step started, m: its pose dead-reckoned from the
        encoders (each sample's delta phi -> body motion pinv(R) . delta phi, turned into the
        start frame). Also updates `data.farthest`."""
        k = 2 * math.pi / self.cpr
        x, y, psi = data.pose
        for i in range(max(1, data.pose_n), len(data.enc)):
            dphi = (np.asarray(data.enc[i], dtype=float) - np.asarray(data.enc[i - 1], dtype=float)) * k
            dx, dy, dpsi = self._pinv_R @ dphi
            mid = psi + 0.5 * dpsi
            x += math.cos(mid) * dx - math.sin(mid) * dy
            y += math.sin(mid) * dx + math.cos(mid) * dy
            psi += dpsi
        data.pose, data.pose_n = [x, y, psi], len(data.enc)
        d = math.hypot(x, y)
        data.farthest = max(data.farthest, d)
        return d

    def _check_space(self, step: Step, data: StepData) -> None:
        """A ground step that takes the robot past `[space] max_distance` stops the motors and
        ends the run (UserError): the dry run's bound assumed a sane board; the encoders tell."""
        if self.max_distance is None or step.world.mode != "ground":
            return
        d = self.distance_from_start(data)
        if d > self.max_distance:
            self._stop()
            self.writer.event("distance_limit", step=step.index, t=data.t[-1] if data.t else None,
                              distance=d, limit=self.max_distance)
            raise UserError(f"step {step.index} ({step.label}): the encoders say the robot is {d:.2f} m from "
                            f"where the step started, past the lab's space ([space] max_distance "
                            f"{self.max_distance:g} m); motors stopped")

    def _host_limit(self, step: Step, t0: float | None, t_end: float | None) -> tuple[float, float]:
        """The phase overran its time on the host's clock: stop the motors, say so."""
        self._stop()
        self.writer.event("host_time_limit", step=step.index, t=t_end,
                          why=f"phase not done after its duration + {HOST_SLACK_S:g} s of host time")
        if t0 is None or t_end is None:
            raise BoardError(f"no telemetry under step {step.index}'s command ({step.label}) within its time "
                             "limit on the host clock")
        return t0, t_end

    # -- the operator -------------------------------------------------------------------------
    def _quiet(self, why: str) -> None:
        """Before a person works: motors stopped and telemetry off, so the board sends nothing
        and its watchdog (armed only while a duty is non-zero) has nothing to guard, however
        long the pause. Idempotent: consecutive prompts share one quiet period."""
        self._stop()
        if self.view is not None:
            self.view.pause()
        if self._paused:
            return
        self.board.configure(telemetry_hz=0, watchdog_s=self.watchdog_s)
        self._paused = True
        self.writer.event("pause", why=why)

    def _resync(self) -> None:
        """After a pause: telemetry back on, anything left on the line dropped, and a first
        fresh sample read so the board clock (which ran on during the pause) is current."""
        if not self._paused:
            return
        self.board.configure(telemetry_hz=self.telemetry_hz, watchdog_s=self.watchdog_s)
        n = self.board.discard_pending()
        self._paused = False
        self.writer.event("resync", discarded=int(n))

    def _ask(self, action: Action, step: Step) -> None:
        self._quiet(f"operator: {action.key}")
        self.echo(f"operator: {action.prompt}")
        answer = self.operator.perform(action, step)
        self.writer.operator_answer(step.index, action.key, action.prompt, answer, self.operator.source)

    def _clear_faults_with_consent(self) -> None:
        """A fault latched before the run (e.g. the watchdog of an interrupted run) is shown
        to the operator and cleared only if they agree; both are logged. Declining aborts."""
        if not hasattr(self.board, "latched_faults"):
            return
        flags = int(self.board.latched_faults())
        if not flags:
            return
        names = fault_names(flags)
        self.writer.event("faults_latched", flags=flags, names=names)
        action = Action("clear_faults", f"The board has fault {names} latched (motors stopped). Find and fix "
                        "its cause, then clear it")
        self._quiet("operator: clear_faults")
        self.echo(f"operator: {action.prompt}")
        answer = self.operator.perform(action, None)
        self.writer.operator_answer(None, action.key, action.prompt, answer, self.operator.source)
        self.board.clear_faults()
        self.writer.event("faults_cleared", flags=flags, names=names, by=self.operator.source)

    def _setup_world(self, step: Step) -> None:
        for action in actions_for(self.world, step.world):
            self._ask(action, step)
        if self.world != step.world:
            self.writer.event("world", step=step.index, **{
                "mode": step.world.mode, "wheel_set": step.world.wheel_set,
                "wheel_mass": list(step.world.wheel_mass) if step.world.wheel_mass else None,
                "payload": step.world.payload})
        self.world = step.world

    # -- steps ---------------------------------------------------------------------------------
    def run(self, steps: Sequence[Step]) -> list[dict[str, Any]]:
        """Run `steps` in order; each completed step is written at once (resume-safe)."""
        _t_crit(0.95, 10)  # import scipy.special now: importing it mid-step stalls the loop
        self.board.configure(telemetry_hz=self.telemetry_hz, watchdog_s=self.watchdog_s)
        self._stop()
        self._clear_faults_with_consent()
        self.board.reset_encoders()
        self.writer.event("encoders_reset")
        for step in steps:
            self._setup_world(step)
            self.writer.event("step_start", step=step.index, label=step.label, step_kind=step.kind)
            if step.kind == "hold":
                rec = self._hold(step)
            elif step.kind == "timed":
                rec = self._timed(step)
            elif step.kind == "trajectory":
                rec = self._trajectory(step)
            else:  # pragma: no cover - plans only make the kinds above
                raise ValueError(step.kind)
            record = {"step": step.index, "kind": step.kind, "label": step.label,
                      "mode": step.world.mode, "wheel_set": step.world.wheel_set,
                      "payload": step.world.payload, **step.params, **rec}
            self.writer.event("step_end", t=rec.get("t_end"), step=step.index)
            left = step.max_time - self._step_progress  # a sweep step usually ends early
            if left > 0:
                self._progress(left, step.label)
            self._step_progress = 0.0
            self.writer.step_complete(record)
            self.records.append(record)
        self._stop()
        return self.records

    def _hold(self, step: Step) -> dict[str, Any]:
        ss = self.plan.settings["steady_state"]
        data = StepData()
        t_rest = None
        if step.settle > 0:
            self._stop()
            t_rest, _ = self._run_for(step, data, step.settle, None)
        hold = StepData()
        verdict: list[SteadyVerdict | None] = [None]
        counter = [0]

        # the speed is the slope over the last `average` s: the level is held at least that long past min_hold
        earliest = ss["min_hold"] + max(ss["window"], ss["average"])

        def until(rel: float) -> bool:
            if rel < earliest:
                return False
            counter[0] += 1
            if counter[0] % 3:
                return False
            t, phi = hold.arrays(self.cpr)
            v = steady_state(t, phi, window=ss["window"], confidence=ss["confidence"],
                             noise_factor=ss["noise_factor"], relative_tolerance=ss["relative_tolerance"],
                             counts_per_rev=self.cpr)
            verdict[0] = v
            return v.steady

        t0, t_end = self._run_for(step, hold, step.duration, [(0.0, step.schedule[0][1])], until)
        t, phi = hold.arrays(self.cpr)
        sel = t >= t[-1] - ss["average"]
        w = angle_slope(t[sel], phi[sel]) if sel.sum() >= 3 else np.full(4, np.nan)
        dts = np.diff(t[sel])
        later = dts > 0  # two samples with one board time (a repeated frame) give no speed
        wk = np.diff(phi[sel], axis=0)[later] / dts[later, None] if later.any() else np.full((1, 4), np.nan)
        v = verdict[0]
        rec: dict[str, Any] = {
            "steady": bool(v.steady) if v is not None else False,
            "hold_time": t_end - t0, "average": float(ss["average"]), "t_rest": t_rest, "t_hold": t0, "t_start": t_rest if t_rest is not None else t0,
            "t_end": t_end, "samples_used": len(hold.t), "samples_rejected": data.rejected + hold.rejected,
            **{f"w{j + 1}": float(w[j]) for j in range(4)},
            **{f"w_std{j + 1}": float(np.std(wk[:, j], ddof=1)) if len(wk) > 1 else None for j in range(4)},
        }
        rec.update(self._electrical(hold, sel))
        if not rec["steady"]:
            self.writer.event("not_steady", step=step.index, t=t_end,
                              why=f"wheel speeds not steady after max_hold {ss['max_hold']:g} s")
        return rec

    def _electrical(self, d: StepData, sel: np.ndarray | None = None) -> dict[str, Any]:
        out: dict[str, Any] = {}
        idx = np.flatnonzero(sel) if sel is not None else np.arange(len(d.t))
        cur = [d.cur[k] for k in idx if d.cur[k] is not None]
        for j in range(4):
            out[f"i{j + 1}"] = float(np.mean([c[j] for c in cur])) if cur else None  # type: ignore[index]
        V = [d.V[k] for k in idx if d.V[k] is not None]
        I = [d.I[k] for k in idx if d.I[k] is not None]
        out["V_batt"] = float(np.mean(V)) if V else None  # type: ignore[arg-type]
        out["I_batt"] = float(np.mean(I)) if I else None  # type: ignore[arg-type]
        return out

    def _drive_from_start_mark(self, step: Step) -> tuple["StepData", float, float, float]:
        """Operator puts the robot at the start mark; drive the step's schedule, stop, let it
        settle. Returns the samples and board times (start, end of drive, end of settle), s."""
        self._quiet("operator: start mark")
        answer = self.operator.start_mark(step)
        self.writer.operator_answer(step.index, "place", "Put the robot at the start mark", answer,
                                    self.operator.source)
        data = StepData()
        t0, t_drive_end = self._run_for(step, data, step.duration, step.schedule)
        self._stop()
        _, t_end = self._run_for(step, data, step.settle, None, accept_from=t0)
        return data, t0, t_drive_end, t_end

    def _timed(self, step: Step) -> dict[str, Any]:
        data, t0, t_drive_end, t_end = self._drive_from_start_mark(step)
        t, phi = data.arrays(self.cpr)
        dphi = phi[-1] - phi[0]
        self._quiet("operator: measure")
        measured, questioned = self._measure(step, dphi)
        return {"t_start": t0, "t_drive_end": t_drive_end, "t_end": t_end, "samples_rejected": data.rejected,
                **self.slip_check(dphi, measured, step), "tape_questioned": questioned,
                **self._electrical(data)}

    def _measure(self, step: Step, dphi: np.ndarray) -> tuple[Any, bool]:
        """The operator's reading, questioned at once while it is far from what the encoders
        measured (see `tape_question`); returns (reading, whether it was questioned and kept)."""
        prompt = ("distance travelled (m)" if step.measure == "distance"
                  else "displacement forward, left (m)")
        measured = self.operator.measure(step)
        for _ in range(5):
            self.writer.operator_answer(step.index, step.measure or "measure", prompt,
                                        list(measured) if isinstance(measured, tuple) else measured,
                                        self.operator.source)
            question = self.tape_question(dphi, measured, step)
            if question is None:
                return measured, False
            self.writer.event("tape_questioned", step=step.index, question=question)
            self.echo(question)
            again = self.operator.remeasure(step, question)
            if again is None:
                self.writer.event("tape_kept", step=step.index, question=question)
                return measured, True
            measured = again
        return measured, True

    def tape_question(self, dphi: np.ndarray, measured: Any, step: Step) -> str | None:
        """A question for the operator when the tape reading is beyond QUESTION_FACTOR times the
        no-slip tolerance from the encoders' no-slip displacement (a misread tape, a wrong run),
        else None. Smaller differences are slip, reported by the no-slip check."""
        chk = self.slip_check(dphi, measured, step)
        tol = self.plan.settings["no_slip"]
        if step.measure == "distance":
            enc, m = abs(chk["encoder_distance"]), float(measured)
            gap, size = abs(m - enc), max(abs(m), enc)
            said = f"encoders say {enc:.2f} m, you typed {m:.2f} m"
        else:
            ef, el = chk["kin_forward"], chk["kin_left"]
            mf, ml = (float(v) for v in measured)
            gap, size = math.hypot(mf - ef, ml - el), max(math.hypot(mf, ml), math.hypot(ef, el))
            said = (f"encoders say {ef:.2f} m forward, {el:.2f} m left; you typed {mf:.2f} m forward, "
                    f"{ml:.2f} m left")
        allowed = QUESTION_FACTOR * (tol["tolerance"] + tol["relative_tolerance"] * size)
        return said if gap > allowed else None

    def slip_check(self, dphi: np.ndarray, measured: Any, step: Step) -> dict[str, Any]:
        """Compare the encoders' rolling distance with the operator's measurement."""
        from omnibench.model.geometry import inverse_kinematics

        r = self.robot.r
        R = inverse_kinematics(self.robot.L, self.robot.l, r, self.robot.alpha)
        kin = np.linalg.pinv(R) @ dphi  # body displacement if the wheels do not slip
        rolling = float(r * np.mean(dphi))
        tol = self.plan.settings["no_slip"]
        out: dict[str, Any] = {**{f"dphi{j + 1}": float(dphi[j]) for j in range(4)},
                               "encoder_distance": rolling, "kin_forward": float(kin[0]),
                               "kin_left": float(kin[1]), "kin_yaw": float(kin[2])}
        if step.measure == "distance":
            m = float(measured)
            slip = m - abs(rolling)
            size = abs(m)
            out.update(measured_distance=m)
        else:
            fwd, left = (float(v) for v in measured)
            slip = math.hypot(fwd - rolling, left)
            size = math.hypot(fwd, left)
            out.update(measured_forward=fwd, measured_left=left,
                       kin_residual=math.hypot(fwd - kin[0], left - kin[1]))
        out["slip"] = slip
        out["no_slip_tolerance"] = tol["tolerance"] + tol["relative_tolerance"] * size
        out["no_slip"] = bool(abs(slip) <= out["no_slip_tolerance"])
        return out

    def _trajectory(self, step: Step) -> dict[str, Any]:
        data, t0, t_drive_end, t_end = self._drive_from_start_mark(step)
        t = np.asarray(data.t, dtype=float)
        V = np.array([np.nan if v is None else v for v in data.V], dtype=float)
        I = np.array([np.nan if v is None else v for v in data.I], dtype=float)
        ok = np.isfinite(V) & np.isfinite(I)
        # an external ammeter reads less often than the telemetry: integrate over its readings
        has_current = bool(ok.sum() >= 2)
        rec: dict[str, Any] = {"t_start": t0, "t_drive_end": t_drive_end, "t_end": t_end,
                               "samples_rejected": data.rejected, "has_current": has_current, "current_samples": int(ok.sum())}
        if has_current:
            tt, P, II = t[ok], V[ok] * I[ok], I[ok]
            rec.update(energy=float(np.trapezoid(P, tt)), charge=float(np.trapezoid(II, tt)),
                       I_batt_mean=float(II.mean()), I_batt_peak=float(np.abs(II).max()))
        else:
            rec.update(energy=None, charge=None, I_batt_mean=None, I_batt_peak=None)
        return rec


def safe_stop(board: Any, attempts: int = 3) -> bool:
    """Stop the motors, retrying; never raises (used on every exit path). True if confirmed."""
    for _ in range(attempts):
        try:
            board.stop()
            return True
        except KeyboardInterrupt:
            continue
        except Exception:  # noqa: BLE001 - the link may be half broken; try again
            continue
    return False


def sigterm_as_interrupt() -> Callable[[], Any]:
    """Make SIGTERM behave like Ctrl-C for the duration of a run; returns a restore function."""
    def handler(signum, frame):
        raise Terminated()

    try:
        old = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not in the main thread
        return lambda: None
    return lambda: signal.signal(signal.SIGTERM, old)
