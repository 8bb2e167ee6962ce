"""What the estimators see: measurements of every procedure as pandas tables, decoupled from
run storage.

`Observations` holds one DataFrame per procedure (SI units throughout) plus the sample traces
the simulation-based fits replay:

``sweep`` (III.i, robot upside down; one row per steady state and wheel)
    run, step, wheel (1-4), u (duty), direction (+1/-1), wheel_mass (kg), F_N (N, axle load =
    wheel_mass g), omega (rad/s, steady wheel speed), omega_se (rad/s, its standard error;
    NaN if unknown), current (A, mean motor current; NaN if not logged), current_se (A),
    n (samples averaged), steady (bool), omega_s2 (rad^2, the residual scatter per reading of the
    angle line fit omega comes from; NaN if the samples were not logged).
``forward`` (III.ii) and ``lateral`` (III.iii) (one row per run step, robot on the ground)
    run, step, u1..u4 (duties), duration (s driving), t_total (s driving + settle), payload (kg),
    heading (rad), measured_forward / measured_left (m, operator's tape, body frame at the start;
    NaN if not measured), measured_se (m), enc_forward / enc_left (m, encoder displacement
    through pinv(R)), dphi1..4 (rad), w1..w4 (rad/s, mean drive speed from the encoder trace over
    [w_t0, w_t1] s after the start), w_se1..4 (rad/s), w_t0, w_t1 (s), time (s, board time of the
    start).
``energy`` (IV; one row per trajectory)
    run, step, trajectory, duration (s), t_total (s), payload (kg), measured_J (J, trapezoid of
    V_batt I_batt over the step; NaN if no current was logged), has_current.
``step_response`` (imported traces replayed whole: square waves in the air or on the floor, the
    random-duty RC log; one row per constant-duty step; the run's `mode`, firmware timing and
    measured supply are in ``runs``)
    run, step, duty, t_start, t_end (s, board time), n.

``windows[(run, step)]``: the board times (s) of the readings a sweep step's steady speeds were
fitted over: with omega_s2 they give each speed's standard error at any speed
(`sweep_speed_se`), which the fit evaluates at the model's prediction.

``traces[(run, step)]``: the step's samples as a DataFrame with t (s since the step start; for
``step_response`` board time), u1..u4, phi1..4 (rad since the step start), i1..i4 (A), V_batt (V),
I_batt (A); columns are NaN where the board did not log them.

Build it from run directories (`Observations.from_runs`, through omnibench.runs.read_run) or
straight from the model (`omnibench.analysis.simcampaign.simulated_observations`: same procedures, same estimators, sensor
noise of the simulated board) for tests and benchmarks.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from omnibench.analysis.quantisation import encoder_slope_fit, line_fit, slope_se_at
from omnibench.errors import UserError
from omnibench.model.context import GRAVITY
from omnibench.procedures import RUN_PROCEDURES  # run.json `procedure` -> Observations table

if TYPE_CHECKING:
    from omnibench.model.robot import Robot
    from omnibench.runs import Run

PROCEDURES = ("sweep", "forward", "lateral", "energy", "step_response")

SWEEP_COLUMNS = ["run", "step", "wheel", "u", "direction", "wheel_mass", "F_N", "omega", "omega_se",
                 "current", "current_se", "n", "steady", "time", "V_batt", "omega_s2"]
RUN_COLUMNS = (["run", "step", "u1", "u2", "u3", "u4", "duration", "t_total", "payload", "heading",
                "measured_forward", "measured_left", "measured_se", "enc_forward", "enc_left"]
               + [f"dphi{j}" for j in range(1, 5)] + [f"w{j}" for j in range(1, 5)]
               + [f"w_se{j}" for j in range(1, 5)] + ["w_t0", "w_t1", "time"])
ENERGY_COLUMNS = ["run", "step", "trajectory", "duration", "t_total", "payload", "measured_J", "has_current"]
STEP_RESPONSE_COLUMNS = ["run", "step", "duty", "t_start", "t_end", "n"]
TRACE_COLUMNS = ["t", "u1", "u2", "u3", "u4", "phi1", "phi2", "phi3", "phi4", "i1", "i2", "i3", "i4",
                 "V_batt", "I_batt"]

#: Default operator tape noise (one standard deviation), m, when a run does not say.
DEFAULT_TAPE_SE = 0.002
#: Window over which a steady speed is taken (s), as in procedures/upside_down_sweep.toml: a run's
#: sweep steps record their own (`average`); runs that do not (older logs) were taken over this.
STEADY_AVERAGE = 0.3


def _empty(columns: list[str]) -> pd.DataFrame:
    """An empty table of float columns: a copy of one built once per column list (building it
    costs ~10 ms of CPU, and every Observations() makes five: 0.3 s of an `omnibench fit`)."""
    key = tuple(columns)
    got = _EMPTY.get(key)
    if got is None:
        got = _EMPTY[key] = pd.DataFrame({c: pd.Series(dtype=float) for c in columns})
    return got.copy()


_EMPTY: dict[tuple[str, ...], pd.DataFrame] = {}


def quantisation_se(counts_per_rev: float) -> float:
    """Standard deviation of an encoder angle reading from quantisation alone, rad: lsb/sqrt(12)."""
    return 2.0 * math.pi / float(counts_per_rev) / math.sqrt(12.0)


def slope_fit(t: np.ndarray, phi: np.ndarray, *, floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Straight-line fit of wheel angle against time: slope (rad/s) and its standard error per
    column of phi (n, k). The residual scatter is floored at `floor` rad (quantisation)."""
    t = np.asarray(t, dtype=float)
    phi = np.asarray(phi, dtype=float)
    if phi.ndim == 1:
        phi = phi[:, None]
    n = len(t)
    if n < 3:
        return np.full(phi.shape[1], np.nan), np.full(phi.shape[1], np.nan)
    tc = t - t.mean()
    sxx = float(np.sum(tc * tc))
    slope = (tc @ (phi - phi.mean(axis=0))) / sxx
    res = phi - phi.mean(axis=0) - np.outer(tc, slope)
    s = np.sqrt(np.maximum(np.sum(res * res, axis=0) / (n - 2), floor * floor))
    return slope, s / math.sqrt(sxx)


@dataclass
class Observations:
    """Measurements of every procedure (see the module docstring for the columns)."""

    sweep: pd.DataFrame = field(default_factory=lambda: _empty(SWEEP_COLUMNS))
    forward: pd.DataFrame = field(default_factory=lambda: _empty(RUN_COLUMNS))
    lateral: pd.DataFrame = field(default_factory=lambda: _empty(RUN_COLUMNS))
    energy: pd.DataFrame = field(default_factory=lambda: _empty(ENERGY_COLUMNS))
    step_response: pd.DataFrame = field(default_factory=lambda: _empty(STEP_RESPONSE_COLUMNS))
    traces: dict[tuple[str, int], pd.DataFrame] = field(default_factory=dict)
    #: (run, step) -> times (s) of the readings a sweep step's speeds were fitted over
    windows: dict[tuple[str, int], np.ndarray] = field(default_factory=dict)
    #: run id -> facts about the run (procedure, path, source, counts_per_rev, ...)
    runs: dict[str, dict[str, Any]] = field(default_factory=dict)

    # ----------------------------------------------------------------------------- queries
    def table(self, procedure: str) -> pd.DataFrame:
        """The DataFrame of one procedure ('sweep', 'forward', 'lateral', 'energy', 'step_response')."""
        if procedure not in PROCEDURES:
            raise KeyError(f"unknown procedure {procedure!r}; known: {', '.join(PROCEDURES)}")
        return getattr(self, procedure)

    def procedures(self) -> list[str]:
        """Procedures with at least one row."""
        return [p for p in PROCEDURES if len(self.table(p))]

    @property
    def run_ids(self) -> list[str]:
        """Every run id that contributes a row."""
        ids: list[str] = []
        for p in PROCEDURES:
            for r in self.table(p)["run"].tolist():
                if r not in ids:
                    ids.append(r)
        return ids

    @property
    def has_current(self) -> bool:
        """True when the sweep logged motor currents (separates friction from motor constants)."""
        return bool(len(self.sweep)) and bool(np.isfinite(self.sweep["current"].to_numpy(dtype=float)).any())

    def select(self, *, runs: Iterable[str] | None = None, procedures: Iterable[str] | None = None,
               wheels: Iterable[int] | None = None, steps: Iterable[tuple[str, int]] | None = None) -> "Observations":
        """A subset: only these runs / procedures / sweep wheels / (run, step) pairs."""
        runs = set(runs) if runs is not None else None
        procs = set(procedures) if procedures is not None else None
        wheels = set(int(w) for w in wheels) if wheels is not None else None
        steps = set(steps) if steps is not None else None
        out: dict[str, pd.DataFrame] = {}
        for p in PROCEDURES:
            df = self.table(p)
            keep = np.ones(len(df), dtype=bool)
            if procs is not None and p not in procs:
                keep[:] = False
            if runs is not None:
                keep &= df["run"].isin(runs).to_numpy()
            if steps is not None:
                keep &= np.array([(r, int(s)) in steps for r, s in zip(df["run"], df["step"])], dtype=bool)
            if wheels is not None and p == "sweep":
                keep &= df["wheel"].isin(wheels).to_numpy()
            out[p] = df[keep].reset_index(drop=True)
        used = {(r, int(s)) for p in PROCEDURES for r, s in zip(out[p]["run"], out[p]["step"])}
        traces = {k: v for k, v in self.traces.items() if k in used}
        windows = {k: v for k, v in self.windows.items() if k in used}
        return replace(self, traces=traces, windows=windows, runs={k: v for k, v in self.runs.items()
                                                  if any(k == r for r, _ in used)}, **out)

    def split(self, fraction: float = 0.5, seed: int = 0) -> tuple["Observations", "Observations"]:
        """(fit, held-out) by whole run steps, each procedure split separately (for held-out errors)."""
        rng = np.random.default_rng(seed)
        a: set[tuple[str, int]] = set()
        b: set[tuple[str, int]] = set()
        for p in PROCEDURES:
            keys = sorted({(r, int(s)) for r, s in zip(self.table(p)["run"], self.table(p)["step"])})
            if not keys:
                continue
            order = rng.permutation(len(keys))
            n_a = max(1, int(round(fraction * len(keys)))) if len(keys) > 1 else 1
            for k, idx in enumerate(order):
                (a if k < n_a else b).add(keys[idx])
        return self.select(steps=a), self.select(steps=b)

    def summary(self) -> str:
        """One line per procedure: how many rows, runs, and whether current was logged."""
        parts = []
        for p in self.procedures():
            df = self.table(p)
            parts.append(f"{p}: {len(df)} rows from {df['run'].nunique()} run(s)")
        return "; ".join(parts) if parts else "no observations"

    @staticmethod
    def concat(items: Sequence["Observations"]) -> "Observations":
        """Merge several Observations (e.g. one per run)."""
        out: dict[str, Any] = {}
        for p in PROCEDURES:
            frames = [o.table(p) for o in items if len(o.table(p))]
            out[p] = pd.concat(frames, ignore_index=True) if frames else Observations().table(p)
        traces: dict = {}
        windows: dict = {}
        runs: dict = {}
        for o in items:
            traces.update(o.traces)
            windows.update(o.windows)
            runs.update(o.runs)
        return Observations(traces=traces, windows=windows, runs=runs, **out)

    # ----------------------------------------------------------------------------- from runs
    @classmethod
    def from_runs(cls, paths: Iterable[str | Path], robot: Robot | None = None) -> "Observations":
        """Read run directories written by omnibench.runs (any procedure; folders are searched
        recursively). `robot` gives the wheel masses and counts per revolution when a run does
        not record them (default: the run's own robot, else the default Omnibot)."""
        from omnibench.runs import find_runs, read_run

        dirs: list[Path] = []
        for p in paths:
            p = Path(p)
            if not p.exists():
                raise UserError(f"{p}: no such run directory")
            found = find_runs(p)
            if not found:
                raise UserError(f"{p}: no run directory here (no run.json)")
            dirs.extend(found)
        from omnibench.runs.record import refuse_duplicate_ids

        runs = [read_run(d) for d in dict.fromkeys(Path(x).resolve() for x in dirs)]
        refuse_duplicate_ids([r.info for r in runs if r.info is not None])  # a copied run counts once
        return cls.concat([_from_run(run, robot, run.run_id) for run in runs])


# --------------------------------------------------------------------------------- readers
def _num(v: Any) -> float:
    """float, NaN for None/empty/non-numbers."""
    try:
        x = float(v)
    except (TypeError, ValueError):
        return float("nan")
    return x


def _run_robot(run: Run, robot: Robot | None) -> Robot:
    if robot is not None:
        return robot
    from omnibench.model import default_robot
    from omnibench.model.robot import robot_from_dict

    data = run.info.robot
    if isinstance(data, dict):
        try:
            return robot_from_dict(data, path=str(run.info.file))
        except UserError:
            pass
    return default_robot()


def _trace(samples: pd.DataFrame, t0: float | None, cpr: float, relative: bool = True) -> pd.DataFrame:
    """Samples -> trace columns (t from t0, phi from the first sample)."""
    return pd.DataFrame(_trace_values(samples, t0, cpr, relative).T, columns=TRACE_COLUMNS)


def _trace_values(samples: pd.DataFrame, t0: float | None, cpr: float, relative: bool = True,
                  rows: np.ndarray | None = None) -> np.ndarray:
    """The trace columns (TRACE_COLUMNS, n) of the samples (only `rows`, a boolean mask, when
    given) in time order: `_trace`'s numbers as one array. The columns are gathered once and a
    trace is one block: a DataFrame from 15 arrays, each its own sanitised column and then
    consolidated, was most of the CPU of reading a run (~0.3 s of an `omnibench fit`)."""
    s = samples if rows is None else samples[rows]
    t = s["t"].to_numpy(dtype=float)
    if len(t) > 1 and not bool(np.all(np.diff(t) > 0)):
        # not strictly increasing (or NaN times): pandas' sort, as ever (with distinct times the
        # order is already the sorted one, whatever the algorithm)
        s = s.sort_values("t")
        t = s["t"].to_numpy(dtype=float)
    out = np.empty((len(TRACE_COLUMNS), len(t)))
    out[0] = t - t0 if (relative and t0 is not None and math.isfinite(t0)) else t
    for j in range(1, 5):
        out[j] = s[f"u{j}"].to_numpy(dtype=float)
    for j in range(1, 5):
        phi = s[f"phi{j}"].to_numpy(dtype=float)
        if not np.isfinite(phi).any():
            phi = s[f"enc{j}"].to_numpy(dtype=float) * 2 * math.pi / cpr
        out[4 + j] = phi - phi[0] if (relative and len(phi)) else phi
    for k, c in enumerate(("i1", "i2", "i3", "i4", "V_batt", "I_batt")):
        out[9 + k] = s[c].to_numpy(dtype=float)
    return out


def run_key(run: Run) -> str:
    """The key a run's rows carry: its run id (validated by omnibench.runs: a file-name safe
    name; two folders holding one id are refused, never merged or counted twice)."""
    return str(run.run_id)


#: a reading further than this fraction from the median supply is a glitch, not the supply
SUPPLY_GLITCH = 0.02


def supply_at_rest(samples: pd.DataFrame) -> float:
    """The run's measured supply, V: mean logged V_batt while every duty is 0 (no motor current,
    so no sag through the battery's resistance), else over all samples; NaN if never logged.

    The mean, not the median: a board reads its battery through an ADC, and the median of
    quantised readings is one code (through the firmware's 6:1 divider on a 10-bit ADC, up to
    half a code off: 14.6 mV, 0.06 % of 24.7 V, which k_e and R_a take up), while the mean averages
    the conversion noise's dither between neighbouring codes. Readings more than SUPPLY_GLITCH
    from the median are left out of it."""
    if not len(samples) or "V_batt" not in samples:
        return float("nan")
    v = samples["V_batt"].to_numpy(dtype=float)
    u = samples[["u1", "u2", "u3", "u4"]].to_numpy(dtype=float)
    ok = np.isfinite(v) & (v > 0)
    rest = ok & np.all(np.nan_to_num(u) == 0, axis=1)
    sel = rest if rest.any() else ok
    if not sel.any():
        return float("nan")
    v = v[sel]
    mid = float(np.median(v))
    return float(np.mean(v[np.abs(v - mid) <= SUPPLY_GLITCH * mid]))


def _firmware_timing(mode: str | None, ft: Mapping[str, Any] | None) -> dict[str, Any]:
    """Where the robot was and how its firmware timed the commands (runs.tfm records both):
    `mode` of a trace-replay run, `command_order` (wheels in send order), `command_offset` (s),
    `command_delays` (s per wheel, when the firmware's send latency is known),
    and, when the timing is assumed, `timing_sketch` (the sketch assumed) and `timing_alternatives`
    (the other documented timings)."""
    out: dict[str, Any] = {}
    if mode in ("ground", "upside_down"):
        out["mode"] = mode
    if isinstance(ft, Mapping):
        order = ft.get("command_order")
        if isinstance(order, (list, tuple)) and sorted(order) == [1, 2, 3, 4]:
            out["command_order"] = tuple(int(w) for w in order)
        out["command_offset"] = _num(ft.get("command_offset_s", 0.0))
        delays = ft.get("wheel_delays_s")  # the firmware's known per-wheel send latency, s
        if isinstance(delays, (list, tuple)) and len(delays) == 4:
            d = tuple(_num(x) for x in delays)
            if all(math.isfinite(x) and x >= 0 for x in d):
                out["command_delays"] = d
        out["sketch"] = str(ft.get("sketch") or "unknown")  # the firmware that recorded it (issue 36)
        if str(ft.get("source", "")).startswith("assumed") or ft.get("sketch") == "unknown":
            # the run's timing is a guess: the sketch assumed and the other documented timings
            out["timing_sketch"] = str(ft.get("default_sketch", ft.get("sketch", "the assumed timing")))
            out["timing_alternatives"] = [
                {"sketch": str(a.get("sketch", "?")), "command_order": tuple(int(w) for w in a["command_order"]),
                 "command_offset": _num(a.get("command_offset_s", 0.0))}
                for a in ft.get("alternatives", []) if isinstance(a, Mapping) and "command_order" in a]
    return out


DUTY_COLUMNS = ("u1", "u2", "u3", "u4")


def applied_duties(run: Run) -> Run:
    """The run with its duties (steps and samples) as the motor drivers applied them, when its
    firmware_timing names a driver resolution (`driver.steps`, runs through the project's
    firmware): the commanded duty rounded to the driver's step; otherwise the run unchanged."""
    from omnibench.model.actuation import applied_duty

    ft = run.info.firmware_timing
    driver = ft.get("driver") if isinstance(ft, Mapping) else None
    if not isinstance(driver, Mapping) or not driver.get("steps"):
        return run
    kw = {"steps": int(driver["steps"]), "wire_scale": int(driver.get("wire_scale", 32767))}

    def table(df: pd.DataFrame) -> pd.DataFrame:
        cols = [c for c in DUTY_COLUMNS if c in df]
        if not len(df) or not cols:
            return df
        out = df.copy()
        for c in cols:
            v = pd.to_numeric(out[c], errors="coerce").to_numpy(dtype=float)
            out[c] = np.where(np.isfinite(v), applied_duty(np.nan_to_num(v), **kw), v)
        return out

    return replace(run, samples=table(run.samples), steps=table(run.steps))


def _from_run(run: Run, robot: Robot | None, rid: str | None = None) -> Observations:
    run = applied_duties(run)
    proc = RUN_PROCEDURES.get(run.procedure)
    if proc is None:
        raise UserError(f"{run.path}: procedure {run.procedure!r} is not one the analysis reads "
                        f"({', '.join(RUN_PROCEDURES)})")
    rid = rid or run_key(run)
    rb = _run_robot(run, robot)
    cpr = float(run.info.counts_per_rev or rb.counts_per_rev)
    imported = run.info.imported
    # omnibench boards report, with each sample, the duty that acted over the interval before it;
    # the 2019 Arduino logs printed the command that acts from the sample on (predictor.DUTY_TIMINGS)
    info = {"procedure": run.procedure, "path": str(run.path), "status": run.status,
            "counts_per_rev": cpr, "source": run.info.source, "imported": imported,
            "duty_timing": str(run.info.duty_timing or ("from_sample" if imported else "interval_before"))}
    info.update(_firmware_timing(run.info.mode, run.info.firmware_timing))
    if proc == "step_response" and "mode" not in info:
        # a trace replayed whole whose run does not say where the robot was (an import that could
        # not read it off the data): unknown, never a default (predictor.run_mode)
        info["mode"] = None
    info["V_batt"] = supply_at_rest(run.samples)
    info["current_lsb"] = current_resolution(run.samples)  # read off the logged values
    obs = Observations(runs={rid: info})
    steps = run.steps
    if not len(steps):
        return obs
    if proc == "sweep":
        obs.sweep = _sweep_rows(run, rid, rb, cpr, obs.windows)
    elif proc in ("forward", "lateral"):
        df, traces = _run_rows(run, rid, rb, cpr, proc)
        setattr(obs, proc, df)
        obs.traces.update(traces)
    elif proc == "energy":
        rows = []
        for _, st in steps.iterrows():
            k = int(st["step"])
            s = run.step_samples(k)
            t0 = _num(st.get("t_start"))
            if len(s):
                obs.traces[(rid, k)] = _trace(s, t0, cpr)
            rows.append({"run": rid, "step": k, "trajectory": str(st.get("trajectory", f"step {k}")),
                         "duration": _num(st.get("duration")),
                         "t_total": _num(st.get("t_end")) - t0, "payload": _num(st.get("payload")) if
                         st.get("payload") is not None else 0.0,
                         "measured_J": _num(st.get("energy")), "has_current": bool(st.get("has_current", False))})
        obs.energy = pd.DataFrame(rows, columns=ENERGY_COLUMNS)
    else:  # step_response
        rows = []
        for _, st in steps.iterrows():
            k = int(st["step"])
            s = run.step_samples(k)
            if len(s):
                obs.traces[(rid, k)] = _trace(s, None, cpr, relative=False)
            rows.append({"run": rid, "step": k, "duty": _num(st.get("duty")),
                         "t_start": _num(st.get("t_start")), "t_end": _num(st.get("t_end")), "n": len(s)})
        obs.step_response = pd.DataFrame(rows, columns=STEP_RESPONSE_COLUMNS)
    return obs


CURRENT_COLUMNS = ("i1", "i2", "i3", "i4")
PROTOCOL_CURRENT_LSB = 1e-3  #: A: the finest current the protocol carries


def current_resolution(samples: pd.DataFrame) -> float:
    """The motor currents' resolution, A, read off the run's samples: the median spacing of the
    distinct values logged (a 10-bit ADC on a 66 mV/A Hall sensor steps 74 mA; the simulated
    board's 1 mA); the protocol's 1 mA when too few values were logged to tell."""
    cols = [c for c in CURRENT_COLUMNS if c in samples]
    if not cols or not len(samples):
        return PROTOCOL_CURRENT_LSB
    v = samples[cols].to_numpy(dtype=float).ravel()
    u = np.unique(np.round(v[np.isfinite(v)], 6))
    d = np.diff(u)
    d = d[d > 0.5 * PROTOCOL_CURRENT_LSB]
    return float(max(np.median(d), PROTOCOL_CURRENT_LSB)) if len(d) >= 8 else PROTOCOL_CURRENT_LSB


def mean_se_quantised(x: np.ndarray, lsb: float) -> np.ndarray:
    """Standard error (per column) of the mean of readings `x` (n, k) quantised to `lsb`: the
    scatter's std/sqrt(n), plus the rounding error the scatter does not average away, lsb^2/12
    damped by exp(-2 pi^2 sigma^2 / lsb^2) for a noise sigma before the rounding (a quiet sensor
    reads one code throughout: its mean is off by up to half a code however long it is held)."""
    n = x.shape[0]
    std = x.std(axis=0, ddof=1)
    sigma2 = np.maximum(std ** 2 - lsb ** 2 / 12.0, 0.0)
    stuck = lsb ** 2 / 12.0 * np.exp(-2.0 * math.pi ** 2 * sigma2 / lsb ** 2)
    return np.sqrt(np.maximum(std, PROTOCOL_CURRENT_LSB / math.sqrt(12)) ** 2 / n + stuck)


def sweep_speed_se(obs: Observations, rows: pd.DataFrame, speeds: np.ndarray) -> np.ndarray:
    """Standard error (rad/s) of each sweep speed in `rows` (run, step, omega_s2: rows of
    obs.sweep) had its wheel turned at `speeds` (rad/s): the encoder's rounding at that speed over
    the step's window (obs.windows), plus the white scatter its line fit showed beyond rounding
    (`quantisation.slope_se_at`). NaN where the window or the scatter is unknown.

    The stated omega_se is this at the step's own estimate; near a whole number of counts per
    reading the rounding error swings sharply with the speed, so that SE follows the estimate's
    own error (a step whose rounding happened to pull it one way reads as the more precise) and a
    fit weighted by it is biased. At a speed the step's noise does not move (the model's
    prediction) the weight no longer depends on the step's own error."""
    out = np.full(len(rows), np.nan)
    for k, (run, step, s2, w) in enumerate(zip(rows["run"], rows["step"], rows["omega_s2"], speeds)):
        t = obs.windows.get((run, int(step)))
        cpr = obs.runs.get(run, {}).get("counts_per_rev")
        if t is not None and cpr and math.isfinite(float(s2)) and math.isfinite(float(w)):
            out[k] = slope_se_at(t, float(w), float(s2), float(cpr))
    return out


def _sweep_rows(run: Run, rid: str, robot: Robot, cpr: float,
                windows: dict[tuple[str, int], np.ndarray]) -> pd.DataFrame:
    rows = []
    floor = quantisation_se(cpr)
    lsb = current_resolution(run.samples)
    v_batt = supply_at_rest(run.samples)  # the run's, the same for every step
    for _, st in run.steps.iterrows():
        k = int(st["step"])
        s = run.step_samples(k)
        n = 0
        w_se = np.full(4, np.nan)
        w_s2 = np.full(4, np.nan)
        i_se = np.full(4, np.nan)
        average = _num(st.get("average"))  # the runner's averaging time (older runs: the default's)
        average = average if math.isfinite(average) and average > 0 else STEADY_AVERAGE
        if len(s) >= 4:
            t = s["t"].to_numpy(dtype=float)
            t_end = _num(st.get("t_end"))
            t_end = t_end if math.isfinite(t_end) else t[-1]
            sel = (t >= t_end - average) & (t <= t_end + 1e-9)
            if sel.sum() >= 4:
                tr = _trace_values(s, None, cpr, relative=False, rows=sel)  # (column, sample): _trace's block
                _, w_se = encoder_slope_fit(tr[0], tr[5:9].T, cpr)
                _, w_s2 = line_fit(tr[0], tr[5:9].T)
                windows[(rid, k)] = tr[0].copy()
                n = int(sel.sum())
                currents = tr[9:13].T
                if np.isfinite(currents).all() and n > 1:
                    i_se = mean_se_quantised(currents, lsb)
        if not np.isfinite(w_se).any():
            # only the record: spread of two-reading speeds -> slope error of a line fit
            for j in range(4):
                std = _num(st.get(f"w_std{j + 1}"))
                if math.isfinite(std):
                    dt = 0.01
                    m = max(3, int(round(average / dt)))
                    sig = std * dt / math.sqrt(2)
                    w_se[j] = max(sig, floor) * math.sqrt(12.0 / (m * average ** 2))
        for j in range(4):
            u = _num(st.get(f"u{j + 1}", st.get("duty")))
            if not math.isfinite(u):
                u = _num(st.get("duty"))
            mass = _num(st.get(f"wheel_mass{j + 1}"))
            if not math.isfinite(mass):
                mass = float(robot.wheel_mass[j])
            w = _num(st.get(f"w{j + 1}"))
            if not math.isfinite(w) or not math.isfinite(u):
                continue
            cur = _num(st.get(f"i{j + 1}"))
            rows.append({"run": rid, "step": k, "wheel": j + 1, "u": u,
                         "direction": float(np.sign(u)) if u else 0.0, "wheel_mass": mass,
                         "F_N": mass * GRAVITY, "omega": w, "omega_se": float(w_se[j]),
                         "current": cur, "current_se": float(i_se[j]) if math.isfinite(cur) else float("nan"),
                         "n": n, "steady": bool(st.get("steady", True)) if st.get("steady") is not None else True,
                         "time": _num(st.get("t_end")), "V_batt": v_batt, "omega_s2": float(w_s2[j])})
    df = pd.DataFrame(rows, columns=SWEEP_COLUMNS)
    return df


def drive_window(duration: float) -> tuple[float, float]:
    """Part of a timed run's drive phase used for its mean wheel speeds, s after the start:
    from a third of the drive (past the acceleration) to 90 % of it (clear of the stop, whose
    timing is known only to a sample interval)."""
    return duration / 3.0, 0.9 * duration


def timed_row(rid: str, k: int, u: Sequence[float], duration: float, t_total: float, payload: float,
              heading: float, measured_forward: float, measured_left: float, trace: pd.DataFrame | None,
              robot: Robot, cpr: float, dphi: np.ndarray | None = None,
              measured_se: float = DEFAULT_TAPE_SE, time: float = float("nan")) -> dict[str, Any]:
    """One `forward`/`lateral` row from a step's facts and its trace (t from the step start)."""
    from omnibench.model.geometry import inverse_kinematics

    R = inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha)
    row: dict[str, Any] = {"run": rid, "step": int(k), **{f"u{j + 1}": float(u[j]) for j in range(4)},
                           "duration": duration, "t_total": t_total, "payload": payload, "heading": heading,
                           "measured_forward": measured_forward, "measured_left": measured_left,
                           "measured_se": measured_se, "time": time}
    w = np.full(4, np.nan)
    w_se = np.full(4, np.nan)
    a, b = drive_window(duration)
    if dphi is None or not np.isfinite(dphi).all():
        dphi = np.full(4, np.nan)
    if trace is not None and len(trace) >= 4:
        t = trace["t"].to_numpy()
        phi = trace[[f"phi{j}" for j in range(1, 5)]].to_numpy()
        sel = (t >= a) & (t <= b + 1e-9)
        if sel.sum() >= 4:
            w, w_se = encoder_slope_fit(t[sel], phi[sel], cpr)
        if not np.isfinite(dphi).all():
            dphi = phi[-1]
    kin = np.linalg.pinv(R) @ dphi
    row.update({"enc_forward": float(kin[0]), "enc_left": float(kin[1]),
                **{f"dphi{j + 1}": float(dphi[j]) for j in range(4)},
                **{f"w{j + 1}": float(w[j]) for j in range(4)},
                **{f"w_se{j + 1}": float(w_se[j]) for j in range(4)}, "w_t0": a, "w_t1": b})
    return row


def _run_rows(run: Run, rid: str, robot: Robot, cpr: float, proc: str) -> tuple[pd.DataFrame, dict]:
    rows, traces = [], {}
    for _, st in run.steps.iterrows():
        k = int(st["step"])
        t0 = _num(st.get("t_start"))
        dur = _num(st.get("duration"))
        s = run.step_samples(k)
        u = [_num(st.get(f"u{j}")) for j in range(1, 5)]
        if proc == "forward":
            dist = _num(st.get("measured_distance"))
            sign = 1.0 if (np.nanmean(u) >= 0) else -1.0
            fwd, left = (sign * abs(dist) if math.isfinite(dist) else float("nan")), float("nan")
        else:
            fwd, left = _num(st.get("measured_forward")), _num(st.get("measured_left"))
        tr = _trace(s, t0, cpr) if len(s) >= 4 else None
        if tr is not None:
            traces[(rid, k)] = tr
        dphi = np.array([_num(st.get(f"dphi{j}")) for j in range(1, 5)])
        payload = _num(st.get("payload")) if st.get("payload") is not None else 0.0
        rows.append(timed_row(rid, k, u, dur, _num(st.get("t_end")) - t0, payload, _num(st.get("heading")),
                              fwd, left, tr, robot, cpr, dphi, time=t0))
    return pd.DataFrame(rows, columns=RUN_COLUMNS), traces
