"""Model predictions of every observation, for many parameter sets at once.

`Predictor(obs, procedures)` flattens the observations into one measurement vector (one entry
per measured number: a steady wheel speed, a mean current, a drive speed, a displacement, an
energy, a step-response speed sample) and knows which simulations reproduce each entry.
`predict(robots)` runs those simulations for every robot in one `simulate_batch` call per
group of equal command timing, and returns the predictions (P robots x n entries).

How each procedure is reproduced (always through the simulator, so any declared term counts):

- sweep: the step's duties held for `SWEEP_HOLD` s upside down with the step's wheel masses;
  the prediction is the final wheel speed (the model reaches steady state in tens of ms) and,
  for the current entries, the final motor current.
- forward / lateral: the duties for `duration` s then zero until `t_total`, on the ground with
  the payload (simulated until COAST s after the stop); the drive speeds use the same straight-line fit over [w_t0, w_t1] as the
  measurement (on the model's angle at 100 Hz), the displacement is the model's final pose
  in the start frame (forward runs: signed distance).
- energy: the logged duties (zero-order hold between samples) on the ground; E_batt at t_total.
- step_response: the whole run's logged duties upside down; wheel speeds by the same
  finite difference of successive angle samples as the measurement.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import pandas as pd

from omnibench.analysis.observations import Observations, slope_fit
from omnibench.errors import UserError
from omnibench.model.scenario import Mode, Scenario
from omnibench.model.simulator import decay_rates_of, simulate_batch, stable_substeps

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

SWEEP_HOLD = 0.3  # s simulated per sweep steady state
PHYSICS_DT = 1e-3  # s
RECORD_DT = 0.01  # s, model angle sampling for the drive-speed fit
#: s simulated after the motors stop in a timed run: the robot is at rest well before (back-EMF
#: braking, ~13 ms, and dry friction); on a clean campaign's forward and lateral runs the
#: predictions at 0.1 s equal those at 0.5 s bit for bit (0.5 before issue 34: 20 % of a ground
#: fit's simulation, at the full sub-step count of a robot at rest)
COAST = 0.2
#: Physics steps between the recorded samples of an energy run, whose energy is interpolated at
#: the trace's first and last sample times. 1 before issue 34; 5 (recording every step was ~20 %
#: of an energy simulation): on a clean campaign's four energy runs, the declared model and two
#: with effects, the energies moved by 1e-13 J (the runs start and end at rest, where E grows
#: linearly); while moving, linear interpolation over 5 ms is off by at most |dP/dt| h^2 / 8,
#: ~3e-3 J at 1000 W/s, against ~0.6 J of noise.
ENERGY_RECORD_EVERY = 5
#: Predictions kept per Predictor (numbers, over all cached parameter sets): a fit asks again for
#: parameter sets it has simulated (the start of each settle pass, the Jacobian at the solution,
#: the next fit's start), and the kernel's numbers do not depend on the batch (kernel._groups)
CACHE_NUMBERS = 10_000_000

#: Observation-vector columns (metadata of every entry)
ENTRY_COLUMNS = ["procedure", "run", "step", "wheel", "signal", "unit", "measured", "sigma", "speed", "F_N",
                 "direction", "time", "current", "u", "payload"]


@dataclass
class _Group:
    """Trajectories simulated in one batch: their schedules are merged into one command time
    base (`union_schedule`), shifted by `shift` s so the earliest command is at 0."""

    record_every: int = 10
    schedules: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # (t_cmd (K,), U (K, 4))
    t_ends: list[float] = field(default_factory=list)  # s, in the schedules' frame
    scen: list[Scenario] = field(default_factory=list)
    v_batt: list[float] = field(default_factory=list)  # V, logged supply per trajectory (NaN: the robot's)
    # after simulating: how to turn the recorded signals of trajectory k into entries
    extract: list[Any] = field(default_factory=list)
    #: simulate to a whole number of record intervals (the last sample is then recorded)
    round_end: bool = False
    _built: tuple | None = None
    _distinct: tuple[list[int], np.ndarray] | None = None

    def add(self, t_cmd, U, t_end: float, scen: Scenario, extract: Any, v_batt: float = float("nan")) -> None:
        self.schedules.append((np.asarray(t_cmd, dtype=float), np.asarray(U, dtype=float)))
        self.t_ends.append(float(t_end))
        self.scen.append(scen)
        self.v_batt.append(float(v_batt))
        self.extract.append(extract)
        self._built = None
        self._distinct = None

    def distinct(self) -> tuple[list[int], np.ndarray]:
        """(first index of every distinct trajectory, index into those of each trajectory):
        trajectories with the same duties, world and supply (a campaign repeats a forward run at
        one duty) are one simulation, bit for bit the same numbers."""
        if self._distinct is None:
            _, U, _, _ = self.built()
            seen: dict[tuple, int] = {}
            first: list[int] = []
            inverse = np.empty(U.shape[0], dtype=int)
            for b in range(U.shape[0]):
                key = (U[b].tobytes(), id(self.scen[b]), np.float64(self.v_batt[b]).tobytes())
                if key not in seen:
                    seen[key] = len(first)
                    first.append(b)
                inverse[b] = seen[key]
            self._distinct = (first, inverse)
        return self._distinct

    def built(self) -> tuple[np.ndarray, np.ndarray, float, float]:
        """(t_cmd, U (B, K, 4), shift s, t_end s in the simulation's frame)."""
        if self._built is None:
            t_cmd, U, shift = union_schedule(self.schedules)
            t_end = max(self.t_ends) + shift
            if self.round_end:
                rec = self.record_every * PHYSICS_DT
                t_end = math.ceil(t_end / rec - 1e-6) * rec
            self._built = (t_cmd, U, shift, t_end)
        return self._built


class Predictor:
    """The measurement vector of `obs` (restricted to `procedures`) and its model predictions."""

    def __init__(self, obs: Observations, procedures: Sequence[str] | None = None, *,
                 effects: dict | None = None) -> None:
        self.obs = obs
        self.procedures = [p for p in (procedures or obs.procedures()) if len(obs.table(p))]
        self.world_effects = effects or {}
        self.entries: list[dict[str, Any]] = []
        self.groups: dict[tuple, _Group] = {}
        self._scenarios: list[Scenario] = []
        for p in self.procedures:
            getattr(self, f"_build_{p}")(obs.table(p))
        self.table = pd.DataFrame(self.entries, columns=ENTRY_COLUMNS)
        self.measured = self.table["measured"].to_numpy(dtype=float)
        self.sigma = self.table["sigma"].to_numpy(dtype=float)
        #: (group key, repr of the parameter set, the group's sub-steps) -> its block of predictions
        self._cache: OrderedDict[tuple[tuple, str, int | None], np.ndarray] = OrderedDict()
        self._cached_numbers = 0
        self._indices: dict[tuple, np.ndarray] = {}
        self._gathers: dict[int, tuple[_Group, np.ndarray, np.ndarray, np.ndarray, list[str]]] = {}
        self._substeps: dict[tuple[str, ...], int] = {}
        self._mode_substeps: dict[tuple[str, ...], int] = {}
        self._up_substeps: int | None = None
        self.simulated = 0  # trajectory-group simulations run (a parameter set in one group; cache misses)

    # ------------------------------------------------------------------------ building
    def _add(self, **e: Any) -> int:
        row = {c: e.get(c, np.nan) for c in ENTRY_COLUMNS}
        self.entries.append(row)
        return len(self.entries) - 1

    def _group(self, key: tuple, record_every: int) -> _Group:
        g = self.groups.get(key)
        if g is None:
            g = self.groups[key] = _Group(record_every=record_every)
        return g

    def timing(self, run: str) -> str:
        """Duty timing convention of a run (see DUTY_TIMINGS)."""
        return str(self.obs.runs.get(run, {}).get("duty_timing", "from_sample"))

    def commands(self, tr: pd.DataFrame, run: str) -> tuple[np.ndarray, np.ndarray]:
        """The run's logged duties as a schedule (`run_commands`)."""
        return run_commands(self.obs, run, tr)

    def supply(self, run: str) -> float:
        """The run's measured supply at rest, V (observations.supply_at_rest; NaN: the robot's)."""
        return float(self.obs.runs.get(run, {}).get("V_batt", float("nan")))

    def scenario(self, run: str, **kw: Any) -> Scenario:
        """The run's world: `kw` (mode, payload, wheel masses), the world effects, and the
        firmware's send order when the run records one. Equal worlds are one object, so that
        simulate_batch prepares each (parameter set, world) pair once, not once per step."""
        info = self.obs.runs.get(run, {})
        delays = info.get("command_delays")
        sc = Scenario(effects=self.world_effects, command_order=info.get("command_order"),
                      command_delays=tuple(delays) if delays is not None else None, **kw)
        for seen in self._scenarios:
            if seen == sc:
                return seen
        self._scenarios.append(sc)
        return sc

    def _build_sweep(self, df: pd.DataFrame) -> None:
        # the steps' rows as plain dicts, grouped by (run, step) in order of appearance (as
        # groupby(sort=False), which drops a missing key too): pandas' per-row access costs ~10 x
        steps: dict[tuple[Any, Any], list[dict[str, Any]]] = {}
        for rec in df.to_dict("records"):
            if pd.notna(rec["run"]) and pd.notna(rec["step"]):
                steps.setdefault((rec["run"], rec["step"]), []).append(rec)
        for (run, step), recs in steps.items():
            U = np.zeros(4)
            masses: list[float | None] = [None] * 4
            for r in recs:
                U[int(r["wheel"]) - 1] = r["u"]
                masses[int(r["wheel"]) - 1] = float(r["wheel_mass"])
            fill = next((m for m in masses if m is not None), 1.0)
            wheel_mass = tuple(m if m is not None else fill for m in masses)
            g = self._group(("sweep",), int(round(SWEEP_HOLD / PHYSICS_DT)))
            idx = []
            for r in recs:
                j = int(r["wheel"])
                meta = dict(procedure="sweep", run=run, step=int(step), wheel=j, speed=r["omega"], F_N=r["F_N"],
                            direction=r["direction"], time=r.get("time", np.nan), current=r["current"], u=r["u"],
                            payload=0.0)
                k = self._add(signal="omega", unit="rad/s", measured=r["omega"], sigma=r["omega_se"], **meta)
                idx.append(("omega", j, k))
                if math.isfinite(r["current"]):
                    k = self._add(signal="current", unit="A", measured=r["current"], sigma=r["current_se"], **meta)
                    idx.append(("current", j, k))
            vb = np.array([r["V_batt"] for r in recs], dtype=float) if "V_batt" in df else np.full(1, np.nan)
            g.add([0.0], U[None, :], SWEEP_HOLD, self.scenario(run, mode="upside_down", wheel_mass=wheel_mass),
                  ("sweep", idx), float(np.nanmedian(vb)) if np.isfinite(vb).any() else self.supply(run))

    def _build_timed(self, df: pd.DataFrame, proc: str) -> None:
        for r in df.to_dict("records"):  # plain dicts: pandas' per-row Series access costs ~10 x
            u = np.array([r[f"u{j}"] for j in range(1, 5)], dtype=float)
            dur, tot = float(r["duration"]), float(r["t_total"])
            if not (math.isfinite(dur) and math.isfinite(tot)):
                continue
            g = self._group((proc,), int(round(RECORD_DT / PHYSICS_DT)))
            tr = self.obs.traces.get((r["run"], int(r["step"])))
            if tr is not None and len(tr) >= 3:
                t_cmd, U = self.commands(tr, r["run"])
                # motors off after the last logged sample (the schedule ends with the trace)
                t_cmd, U = np.append(t_cmd, max(tot, float(tr["t"].iloc[-1])) + RECORD_DT), np.vstack([U, np.zeros(4)])
            else:
                t_cmd, U = np.array([0.0, dur]), np.stack([u, np.zeros(4)])
            meta = dict(procedure=proc, run=r["run"], step=int(r["step"]), F_N=np.nan, time=r.get("time", np.nan),
                        current=np.nan, payload=r["payload"])
            idx = []
            for j in range(1, 5):
                if math.isfinite(r[f"w{j}"]):
                    k = self._add(signal="w", unit="rad/s", wheel=j, measured=r[f"w{j}"], sigma=r[f"w_se{j}"],
                                  speed=r[f"w{j}"], direction=float(np.sign(r[f"u{j}"])), u=r[f"u{j}"], **meta)
                    idx.append(("w", j, k))
            for sig, col in (("forward", "measured_forward"), ("left", "measured_left")):
                if math.isfinite(r[col]):
                    k = self._add(signal=sig, unit="m", wheel=0, measured=r[col], sigma=r["measured_se"],
                                  speed=np.nan, direction=float(np.sign(r[col])), u=np.nan, **meta)
                    idx.append((sig, 0, k))
            # after the motors stop the robot is braked by the back-EMF and rests within ~0.1 s:
            # simulate COAST s of it, not the whole settle time the operator waited
            nz = np.flatnonzero(np.any(U != 0, axis=1))
            t_off = float(t_cmd[nz[-1] + 1]) if nz.size and nz[-1] + 1 < len(t_cmd) else tot
            t_end = min(tot, max(t_off + COAST, float(r["w_t1"])))
            g.add(t_cmd, U, t_end, self.scenario(r["run"], mode="ground", payload=float(r["payload"])),
                  (proc, idx, (float(r["w_t0"]), float(r["w_t1"]))), self.supply(r["run"]))

    def _build_forward(self, df: pd.DataFrame) -> None:
        self._build_timed(df, "forward")

    def _build_lateral(self, df: pd.DataFrame) -> None:
        self._build_timed(df, "lateral")

    def _build_energy(self, df: pd.DataFrame) -> None:
        for _, r in df.iterrows():
            tr = self.obs.traces.get((r["run"], int(r["step"])))
            if tr is None or not math.isfinite(r["t_total"]):
                continue
            t_cmd, U = self.commands(tr, r["run"])
            key = ("energy", r["run"], int(r["step"]))
            g = self._group(key, ENERGY_RECORD_EVERY)
            g.round_end = True
            t_last = float(tr["t"].iloc[-1])
            k = self._add(procedure="energy", run=r["run"], step=int(r["step"]), wheel=0, signal="energy", unit="J",
                          measured=r["measured_J"], sigma=np.nan, payload=r["payload"])
            g.add(t_cmd, U, t_last + PHYSICS_DT, self.scenario(r["run"], mode="ground", payload=float(r["payload"])),
                  ("energy", [("energy", 0, k)], tr["t"].to_numpy(dtype=float)), self.supply(r["run"]))

    def _build_step_response(self, df: pd.DataFrame) -> None:
        for run, rows in df.groupby("run", sort=False):
            parts = [self.obs.traces[(run, int(s))] for s in rows["step"] if (run, int(s)) in self.obs.traces]
            if not parts:
                continue
            tr = pd.concat(parts, ignore_index=True).sort_values("t").reset_index(drop=True)
            t = tr["t"].to_numpy(dtype=float)
            t0 = t[0]
            ts = t - t0
            t_cmd, U = self.commands(tr.assign(t=ts), run)
            key = ("step_response", run)
            g = self._group(key, 1)
            phi = tr[[f"phi{j}" for j in range(1, 5)]].to_numpy(dtype=float)
            dt = np.diff(ts)
            w = np.diff(phi, axis=0) / dt[:, None]
            tm = 0.5 * (ts[1:] + ts[:-1])
            u_log = tr[[f"u{j}" for j in range(1, 5)]].to_numpy(dtype=float)
            idx = []
            for j in range(4):
                for n in range(len(tm)):
                    k = self._add(procedure="step_response", run=run, step=-1, wheel=j + 1, signal="omega",
                                  unit="rad/s", measured=w[n, j], sigma=np.nan, speed=w[n, j], F_N=np.nan,
                                  direction=float(np.sign(u_log[n, j])), time=tm[n] + t0, u=u_log[n, j],
                                  payload=0.0)
                    idx.append(("omega_fd", j + 1, k))
            g.add(t_cmd, U, float(ts[-1]) + PHYSICS_DT, self.scenario(run, mode=run_mode(self.obs, run)),
                  ("step_response", idx, ts), self.supply(run))

    # ------------------------------------------------------------------------ predicting
    def __len__(self) -> int:
        return len(self.entries)

    def substeps(self, robots: Sequence[Any]) -> int:
        """Integrator sub-steps that keep every robot's friction regularisation stable."""
        key = tuple(repr(r) for r in robots)
        if key not in self._substeps:
            pairs = [(r, s) for g in self.groups.values() for s in {(sc.mode, sc.payload): sc for sc in g.scen}.values()
                     for r in robots]
            lam = decay_rates_of(pairs)
            up = np.array([s.mode == "upside_down" for _, s in pairs], dtype=bool)
            if len(self._substeps) > 4096:
                self._substeps.clear()
                self._mode_substeps.clear()
            self._substeps[key] = stable_substeps(float(lam.max(initial=0.0)), PHYSICS_DT)
            # upside down alone (exact sign, no regularised stiffness): the sweep's groups need
            # not take the ground's sub-steps
            self._mode_substeps[key] = stable_substeps(float(lam[up].max(initial=0.0)), PHYSICS_DT)
        return self._substeps[key]

    def _group_substeps(self, g: "_Group", substeps: int | None) -> int | None:
        """Sub-steps of one group: `substeps`, or fewer for a group that is all upside down
        when `substeps` came from `substeps([robot])` of the call's first robot (the ground's
        stiffness); the same for every parameter set of the call."""
        if not substeps or self._up_substeps is None or any(sc.mode != "upside_down" for sc in g.scen):
            return substeps
        return min(substeps, self._up_substeps)

    def group_entries(self) -> dict[tuple, np.ndarray]:
        """Entry indices each simulation group predicts."""
        out = {}
        for key, g in self.groups.items():
            out[key] = np.array(sorted(k for ex in g.extract for _, _, k in ex[1]), dtype=int)
        return out

    def predict(self, robots: Sequence[Any], *, substeps: int | None = None,
                same_as_first: Mapping[tuple, set[int]] | None = None) -> np.ndarray:
        """Predictions (len(robots), len(self)) of every entry, one simulate_batch call per group.

        A parameter set predicted before in a group (same robot, same sub-steps of that group)
        is not simulated again there: the block is the cached one, bit for bit what a new
        simulation would give. The cache is per group, so a Jacobian's parameter set whose
        other groups were copied (same_as_first) is still found for the groups it simulated.

        same_as_first: {group key: robot indices} whose predictions in that group are known to
        equal robot 0's (a parameter the group does not depend on); they are not simulated."""
        keys = [repr(r) for r in robots]
        self._up_substeps = self._mode_substeps.get((keys[0],)) if robots else None
        out = np.full((len(robots), len(self.entries)), np.nan)
        for gkey, g in self.groups.items():
            idx = self._group_index(gkey, g)
            sub = self._group_substeps(g, substeps)
            skip = {p for p in (same_as_first or {}).get(gkey, set()) if p != 0}
            todo: list[int] = []  # first index of every parameter set not in the cache
            first: dict[str, int] = {}
            for p, key in enumerate(keys):
                if p in skip:
                    continue
                hit = self._cache.get((gkey, key, sub))
                if hit is not None:
                    out[p, idx] = hit
                    self._cache.move_to_end((gkey, key, sub))
                elif key not in first:
                    first[key] = p
                    todo.append(p)
            if todo:
                sim = self._simulate_group(g, [robots[p] for p in todo], sub, idx)
                for q, p in enumerate(todo):
                    out[p, idx] = sim[q]
                    self._store((gkey, keys[p], sub), sim[q])
            for p, key in enumerate(keys):
                if p in skip:
                    out[p, idx] = out[0, idx]
                elif key in first and first[key] != p:  # a parameter set asked for twice in this call
                    out[p, idx] = out[first[key], idx]
        return out

    def _group_index(self, key: tuple, g: _Group) -> np.ndarray:
        """Entry indices (sorted) one group predicts."""
        got = self._indices.get(key)
        if got is None:
            got = self._indices[key] = np.array(sorted(k for ex in g.extract for _, _, k in ex[1]), dtype=int)
        return got

    def _store(self, key: tuple[tuple, str, int | None], f: np.ndarray) -> None:
        self._cache[key] = f.copy()
        self._cached_numbers += f.size
        while self._cached_numbers > CACHE_NUMBERS and len(self._cache) > 16:
            self._cached_numbers -= self._cache.popitem(last=False)[1].size

    def _simulate_group(self, g: _Group, robots: Sequence[Any], substeps: int | None,
                        idx: np.ndarray) -> np.ndarray:
        """Predictions (len(robots), len(idx)) of one group's entries, simulated (no cache)."""
        t_cmd, U, shift, t_end = g.built()
        n = U.shape[0]
        P = len(robots)
        self.simulated += P
        first, inverse = g.distinct()
        m = len(first)
        # trajectory-major: the kernel's lane groups (kernel.WIDTH neighbours) then hold one
        # trajectory under several parameter sets, which take the same adaptive sub-steps and
        # stick-slip branches (issue 34: ~5 % of a fit's kernel time); a trajectory's numbers do
        # not depend on its lane (tests/analysis/test_predictor_cache.py)
        rob = [with_supply(r, g.v_batt[k]) for k in first for r in robots]
        res = simulate_batch(rob, [g.scen[k] for k in first for _ in range(P)], t_cmd, np.repeat(U[first], P, axis=0),
                             t_end, dt=PHYSICS_DT, record_every=g.record_every, substeps=substeps, adaptive=True)
        # back to parameter-set-major rows (set q, trajectory k at q * n + k), repeats copied from their first
        if P > 1 or m < n:
            res.array = res.array[(np.arange(P)[:, None] + inverse[None, :] * P).ravel()]
        if g.extract and all(ex[0] == "sweep" for ex in g.extract):
            # steady states: every entry is one recorded signal's last sample, gathered at once
            traj, col, pos = self._sweep_gather(g, res.columns, idx)
            out = np.empty((P, len(idx)))
            out[:, pos] = res.array[(np.arange(P) * n)[:, None] + traj[None, :], -1, col[None, :]]
            return out
        slopes = self._drive_slopes(g, res, shift, P)
        row = np.full(len(self.entries), np.nan)
        out = np.empty((P, len(idx)))
        for q in range(P):
            for k, ex in enumerate(g.extract):
                self._extract(row, res, q * n + k, ex, shift, None if slopes is None else slopes[q * n + k])
            out[q] = row[idx]
        return out

    def _sweep_gather(self, g: _Group, columns: list[str], idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(trajectory, recorded column, position in `idx`) of every entry of a sweep group: the
        entry is that column's last sample (`_extract`'s "sweep" case, all entries at once)."""
        got = self._gathers.get(id(g))
        if got is None or got[0] is not g or got[4] != columns:
            where = {int(k): i for i, k in enumerate(idx)}
            rows = [(b, columns.index(f"phi_dot{j}_free" if sig == "omega" else f"i{j}"), where[k])
                    for b, ex in enumerate(g.extract) for sig, j, k in ex[1]]
            traj, col, pos = (np.array(c, dtype=int) for c in zip(*rows)) if rows else (np.zeros(0, dtype=int),) * 3
            got = self._gathers[id(g)] = (g, traj, col, pos, list(columns))
        return got[1], got[2], got[3]

    @staticmethod
    def _drive_slopes(g: _Group, res, shift: float, copies: int) -> np.ndarray | None:
        """Drive speeds (B, 4) of a timed-run group: the straight-line fit of each trajectory's
        wheel angles over its window, all trajectories sharing a window at once."""
        if not g.extract or g.extract[0][0] not in ("forward", "lateral"):
            return None
        t = res.t - shift
        cols = [res.columns.index(f"phi{j}") for j in range(1, 5)]
        phi = res.array[:, :, cols]  # (B, n_rec, 4)
        n = len(g.extract)
        out = np.full((n * copies, 4), np.nan)
        windows: dict[tuple[float, float], list[int]] = {}
        for k, ex in enumerate(g.extract):
            windows.setdefault(ex[2], []).append(k)
        for (a, b), ks in windows.items():
            sel = (t >= a - 1e-9) & (t <= b + 1e-9)
            if sel.sum() < 3:
                continue
            tc = t[sel] - t[sel].mean()
            rows = np.array([q * n + k for q in range(copies) for k in ks])
            ph = phi[rows][:, sel, :]
            out[rows] = np.einsum("t,btj->bj", tc, ph - ph.mean(axis=1, keepdims=True)) / float(tc @ tc)
        return out

    def _extract(self, out: np.ndarray, res, b: int, ex: tuple, shift: float,
                 slope: np.ndarray | None = None) -> None:
        kind = ex[0]
        if kind == "sweep":
            for sig, j, k in ex[1]:
                name = f"phi_dot{j}_free" if sig == "omega" else f"i{j}"
                out[k] = res.signal(name)[b, -1]
        elif kind in ("forward", "lateral"):
            idx, (a, bb) = ex[1], ex[2]
            if slope is None:
                t = res.t - shift
                sel = (t >= a - 1e-9) & (t <= bb + 1e-9)
                phi = np.stack([res.signal(f"phi{j}")[b] for j in range(1, 5)], axis=1)
                slope, _ = slope_fit(t[sel], phi[sel])
            w = slope
            x, y = res.array[b, -1, res.columns.index("x")], res.array[b, -1, res.columns.index("y")]
            for sig, j, k in idx:
                if sig == "w":
                    out[k] = w[j - 1]
                elif sig == "forward":
                    out[k] = (math.copysign(math.hypot(x, y), x) if kind == "forward" else x)
                else:
                    out[k] = y
        elif kind == "energy":
            ts = ex[2]
            E = np.interp(ts + shift, res.t, res.signal("E_batt")[b])
            for _, _, k in ex[1]:
                out[k] = E[-1] - E[0]
        elif kind == "step_response":
            ts = ex[2]
            ph = [np.interp(ts + shift, res.t, res.signal(f"phi{j}")[b]) for j in range(1, 5)]
            dts = np.diff(ts)
            rates = [np.diff(p) / dts for p in ph]
            m = len(dts)
            for n, (_, j, k) in enumerate(ex[1]):
                out[k] = rates[j - 1][n % m]


#: How a logged duty relates to its sample time.
#: "interval_before": sample k reports the duty that acted over (t_k-1, t_k] (omnibench boards:
#: a command sent after reading sample k-1 acts from t_k-1); "from_sample": the duty logged at t_k
#: acts from t_k on (the 2019 Arduino logs: command printed, then applied).
DUTY_TIMINGS = ("interval_before", "from_sample")


def run_commands(obs: Observations, run: str, tr: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """A run's logged duties as a zero-order-hold schedule: `commands_from_trace` with the run's
    duty timing, shifted by its firmware's command offset (s; runs.tfm: the 2019 RC sketch sent
    a log line's commands before reading the encoders)."""
    info = obs.runs.get(run, {})
    t_cmd, U = commands_from_trace(tr, str(info.get("duty_timing", "from_sample")))
    off = float(info.get("command_offset", 0.0) or 0.0)
    return (t_cmd + off if math.isfinite(off) else t_cmd), U


class UnknownMode(UserError):
    """A trace-replay run whose `mode` (where the robot was) is unknown."""


def run_mode(obs: Observations, run: str) -> Mode:
    """Where a trace-replay run was: 'upside_down' (wheels in the air) or 'ground', as recorded
    (the run schema allows only these two, and Scenario checks the value again). A run read from
    disk that does not say (`mode` None: its import could not read it off the data) raises
    UnknownMode, a one-line UserError asking for --where: it is never replayed in a mode taken by
    default. predict (predict.predict_runs), fit and diagnose (analysis/modes.py) give it each mode
    in turn before it gets here; only a caller that does not profile meets the error.
    Observations built in memory without the key (the simulated square waves) are in the air."""
    info = obs.runs.get(run, {})
    if "mode" in info and info["mode"] is None:
        raise UnknownMode(f"run {run}: where the robot was is unknown (its import could not read it off the "
                          "data, run.json conditions.where): import it again with --where air|floor, or leave it out")
    return cast(Mode, str(info.get("mode", "upside_down")))


def with_supply(robot: Robot, v_batt: float) -> Robot:
    """`robot` with its supply voltage set to the logged one (unchanged when none was logged):
    a campaign's battery sags, and a fixed nominal voltage biases a and k_e."""
    if not math.isfinite(v_batt) or v_batt <= 0 or v_batt == robot.V_batt:
        return robot
    return robot.replace(V_batt=float(v_batt))


def commands_from_trace(tr: pd.DataFrame, timing: str = "from_sample") -> tuple[np.ndarray, np.ndarray]:
    """(t_cmd (K,), U (K, 4)): the logged duties as a zero-order-hold schedule in the trace's time
    frame (only changes kept; with "interval_before" each change starts one sample earlier,
    the first one a sample interval before the first sample, so t_cmd may start below 0)."""
    if timing not in DUTY_TIMINGS:
        raise ValueError(f"timing must be one of {DUTY_TIMINGS}")
    t = tr["t"].to_numpy(dtype=float)
    # column by column (a list selection reindexes the whole trace); the schedule's numbers do
    # not depend on the array's memory order
    U = np.nan_to_num(np.stack([tr[f"u{j}"].to_numpy(dtype=float) for j in range(1, 5)], axis=1))
    keep = np.ones(len(t), dtype=bool)
    keep[1:] = np.any(np.diff(U, axis=0) != 0, axis=1)
    starts = t.copy()
    if timing == "interval_before" and len(t) > 1:
        starts[1:] = t[:-1]
        starts[0] = t[0] - (t[1] - t[0])
    return starts[keep], U[keep]


def union_schedule(schedules: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, float]:
    """Several schedules (t_cmd, U) in one time frame -> (common t_cmd from 0, U (B, K, 4), shift):
    shift (s) is added to every time so that the earliest command is at 0; before its first
    command a trajectory's duty is 0."""
    shift = max(0.0, -min(float(tc[0]) for tc, _ in schedules)) if schedules else 0.0
    times = np.unique(np.concatenate([np.asarray(tc, dtype=float) + shift for tc, _ in schedules] + [np.zeros(1)]))
    Us = []
    for tc, U in schedules:
        idx = np.searchsorted(np.asarray(tc, dtype=float) + shift, times + 1e-12, side="right") - 1
        Ub = np.where(idx[:, None] >= 0, np.asarray(U, dtype=float)[np.maximum(idx, 0)], 0.0)
        Us.append(Ub)
    return times, np.stack(Us) if Us else np.zeros((0, len(times), 4)), shift
