"""Paper IV: the whole model against the battery energy an ammeter measured.

For every energy run step, the duties the board logged are replayed through the model on the
ground (zero-order hold between samples, the step's payload), the model's battery current
I_batt(t) = sum(u_i i_i) + I_0 and V_batt(t) are read at the step's sample times and the
predicted energy is the same trapezoid of V_batt I_batt over those samples as the measured one
(so the sampling of current spikes at duty changes affects both alike), and compared:

    error % = 100 (predicted_J - measured_J) / measured_J

The measured energy is the trapezoid of V_batt I_batt over the step's samples (omnibench.bench).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from omnibench.analysis.observations import Observations
from omnibench.analysis.predict import duty_timing, nrmse, replay
from omnibench.errors import UserError
from omnibench.model.scenario import Scenario

if TYPE_CHECKING:
    from omnibench.model.robot import Robot


@dataclass
class EnergyValidation:
    """Per-run table (run, step, trajectory, duration_s, measured_J, predicted_J, error_pct,
    current_nrmse) and the replayed traces keyed by (run, step)."""

    table: pd.DataFrame
    traces: dict[tuple[str, int], pd.DataFrame] = field(default_factory=dict)

    @property
    def mean_abs_error_pct(self) -> float:
        e = self.table["error_pct"].to_numpy(dtype=float)
        e = e[np.isfinite(e)]
        return float(np.mean(np.abs(e))) if len(e) else float("nan")

    @property
    def max_abs_error_pct(self) -> float:
        e = self.table["error_pct"].to_numpy(dtype=float)
        e = e[np.isfinite(e)]
        return float(np.max(np.abs(e))) if len(e) else float("nan")

    def to_json(self) -> dict[str, Any]:
        def f(x: Any) -> Any:
            return float(x) if isinstance(x, (float, np.floating)) and math.isfinite(x) else (
                None if isinstance(x, (float, np.floating)) else x)

        return {"runs": [{k: f(v) for k, v in row.items()} for row in self.table.to_dict("records")],
                "mean_abs_error_pct": f(self.mean_abs_error_pct), "max_abs_error_pct": f(self.max_abs_error_pct)}


def validate_energy(robot: Robot, obs: Observations) -> EnergyValidation:
    """Predicted vs measured energy for every energy-run step of `obs` (UserError if there is none)."""
    if not len(obs.energy):
        raise UserError("no energy runs given (run `omnibench energy` with the ammeter first)")
    rows, traces = [], {}
    for _, r in obs.energy.iterrows():
        key = (r["run"], int(r["step"]))
        tr = obs.traces.get(key)
        row = {"run": r["run"], "step": int(r["step"]), "trajectory": r["trajectory"],
               "duration_s": float(r["duration"]), "measured_J": float(r["measured_J"]),
               "predicted_J": float("nan"), "error_pct": float("nan"), "current_nrmse": float("nan"),
               "predicted_exact_J": float("nan")}
        if tr is not None and len(tr) >= 3:
            payload = float(r["payload"]) if math.isfinite(r["payload"]) else 0.0
            info = obs.runs.get(r["run"], {})
            delays = info.get("command_delays")
            sc = Scenario(mode="ground", payload=payload, command_order=info.get("command_order"),
                          command_delays=tuple(delays) if delays is not None else None)
            rep = replay(robot, tr, sc, duty_timing(obs, r["run"]), float(info.get("command_offset", 0.0) or 0.0))
            traces[key] = rep
            # the model's energy by the same trapezoid over the same samples as the measurement
            t = rep["t"].to_numpy()
            E_pred = float(np.trapezoid(rep["V_batt_pred"].to_numpy() * rep["I_batt_pred"].to_numpy(), t))
            row["predicted_exact_J"] = float(rep["E_pred"].iloc[-1])
            row["predicted_J"] = E_pred
            if math.isfinite(row["measured_J"]) and row["measured_J"] != 0:
                row["error_pct"] = 100.0 * (E_pred - row["measured_J"]) / row["measured_J"]
            row["current_nrmse"] = nrmse(rep["I_batt_meas"].to_numpy(), rep["I_batt_pred"].to_numpy())
        rows.append(row)
    return EnergyValidation(pd.DataFrame(rows), traces)
