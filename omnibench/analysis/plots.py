"""Figures a lab engineer looks at (matplotlib, Agg backend, PNG files).

- `plot_sweep_fit`: each sweep (steady speed against duty, per wheel and wheel load) with the
  fitted model's curve; points left out of the fit are hollow.
- `plot_residuals`: normalised residuals against speed, axle load and time (step order), per
  procedure and signal.
- `plot_energy`: measured and predicted battery current per energy run.
- `plot_prediction`: measured and predicted wheel speeds of a replayed run.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from omnibench.errors import UserError
from omnibench.files import save_figure

if TYPE_CHECKING:
    from omnibench.model.robot import Robot


def _out(folder: str | Path, name: str) -> Path:
    p = Path(folder)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{p}: cannot create the plot folder ({exc.strerror or exc})") from None
    return p / name


def plot_sweep_fit(robot: Robot, obs: Any, residuals: pd.DataFrame, folder: str | Path, name: str = "sweep_fit.png") -> Path:
    """Steady wheel speed vs duty: measured points and the model's steady speeds on a fine duty grid."""
    from omnibench.analysis.fitting import predict_observations
    from omnibench.analysis.observations import Observations

    sw = obs.sweep
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True, sharey=True)
    used = residuals[(residuals["procedure"] == "sweep") & (residuals["signal"] == "omega")]
    for j, ax in zip(range(1, 5), axes.ravel()):
        d = sw[sw["wheel"] == j]
        u_row = used[used["wheel"] == j]
        for k, (mass, g) in enumerate(d.groupby("wheel_mass")):
            colour = f"C{k}"
            keep = u_row[np.isclose(u_row["F_N"], g["F_N"].iloc[0])]
            fill = keep["used"].to_numpy(bool) if len(keep) == len(g) else np.ones(len(g), bool)
            # each wheel load its own marker and line style, drawn half transparent: the sets lie
            # close together and must not hide one another
            mk, ls = "o^sv"[k % 4], ("-", "--", ":", "-.")[k % 4]
            ax.scatter(g["u"][fill], g["omega"][fill], color=colour, s=22, marker=mk, alpha=0.7,
                       label=f"{mass:g} kg measured")
            ax.scatter(g["u"][~fill], g["omega"][~fill], facecolors="none", edgecolors=colour, s=22, marker=mk)
            # model curve
            grid = np.linspace(g["u"].min(), g["u"].max(), 40)
            grid = grid[np.abs(grid) > 1e-6]
            fake = pd.DataFrame({"run": "curve", "step": np.arange(len(grid)), "wheel": j, "u": grid,
                                 "direction": np.sign(grid), "wheel_mass": mass, "F_N": g["F_N"].iloc[0],
                                 "omega": 0.0, "omega_se": np.nan, "current": np.nan, "current_se": np.nan,
                                 "n": 0, "steady": True})
            cur = predict_observations(robot, Observations(sweep=fake), ["sweep"])
            ax.plot(grid, cur["predicted"], color=colour, lw=1.2, ls=ls, alpha=0.85, label=f"{mass:g} kg model")
        ax.set_title(f"wheel {j}")
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("duty u")
    for ax in axes[:, 0]:
        ax.set_ylabel("steady wheel speed (rad/s)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("III.i upside-down sweep: measured steady speeds and fitted model (hollow: not fitted)")
    fig.tight_layout()
    path = _out(folder, name)
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


def plot_residuals(residuals: pd.DataFrame, folder: str | Path, name: str = "residuals.png") -> Path:
    """Normalised residuals (or plain residuals when sigma is unknown) against speed, load and time."""
    df = residuals[np.isfinite(residuals["residual"])].copy()
    df["z"] = np.where(np.isfinite(df["normalised"]), df["normalised"], df["residual"])
    order = df.groupby("procedure").cumcount().to_numpy(float)
    tm = df["time"].to_numpy(float)
    df["order"] = np.where(np.isfinite(tm), tm, order)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for k, ((proc, sig), g) in enumerate(df.groupby(["procedure", "signal"], sort=False)):
        c = f"C{k % 10}"
        lab = f"{proc}/{sig}"
        hollow = ~g["used"].to_numpy(bool)
        for ax, x in zip(axes, ("speed", "F_N", "order")):
            xv = g[x].to_numpy(float)
            ax.scatter(xv[~hollow], g["z"].to_numpy()[~hollow], s=8, color=c, label=lab)
            if hollow.any():
                ax.scatter(xv[hollow], g["z"].to_numpy()[hollow], s=8, facecolors="none", edgecolors=c)
    for ax, lab in zip(axes, ("speed (rad/s)", "axle load F_N (N)", "board time (s; order where unknown)")):
        ax.axhline(0, color="k", lw=0.6)
        ax.set_xlabel(lab)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("residual / sigma")
    axes[0].legend(fontsize=7)
    fig.suptitle("Residuals of the fit (hollow: left out of the fit)")
    fig.tight_layout()
    path = _out(folder, name)
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


def plot_energy(validation: Any, folder: str | Path, name: str = "energy_current.png") -> Path:
    """Measured and predicted battery current of every energy run step."""
    items = list(validation.traces.items())
    n = max(1, len(items))
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.4 * n), squeeze=False)
    rows = validation.table.set_index(["run", "step"])
    for ax, ((run, step), rep) in zip(axes[:, 0], items):
        ax.plot(rep["t"] - rep["t"].iloc[0], rep["I_batt_meas"], lw=0.8, label="measured")
        ax.plot(rep["t"] - rep["t"].iloc[0], rep["I_batt_pred"], lw=1.0, label="model")
        r = rows.loc[(run, step)]
        ax.set_title(f"{r['trajectory']} ({run} step {step}): measured {r['measured_J']:.1f} J, "
                     f"model {r['predicted_J']:.1f} J ({r['error_pct']:+.2f} %)", fontsize=9)
        ax.set_ylabel("I_batt (A)")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    axes[-1, 0].set_xlabel("time since step start (s)")
    fig.tight_layout()
    path = _out(folder, name)
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


def plot_prediction(pred: Any, folder: str | Path, name: str | None = None) -> Path | None:
    """Measured and predicted wheel speeds of one replayed run (all its steps in sequence)."""
    if not pred.traces:
        return None
    rep = pd.concat(list(pred.traces.values()), ignore_index=True)
    fig, axes = plt.subplots(4, 1, figsize=(11, 8), sharex=True)
    t = rep["t"].to_numpy()
    for j, ax in zip(range(1, 5), axes):
        ax.plot(t, rep[f"w{j}_meas"], lw=0.7, label="measured (encoder differences)")
        ax.plot(t, rep[f"w{j}_pred"], lw=1.0, label="model")
        ax.set_ylabel(f"wheel {j} (rad/s)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("board time (s)")
    nr = ", ".join(f"{k} {v:.3f}" for k, v in pred.nrmse.items())
    fig.suptitle(f"{pred.run} ({pred.procedure}): NRMSE {nr}", fontsize=9)
    fig.tight_layout()
    path = _out(folder, name or f"predict_{pred.run}.png")
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path
