"""Outputs of a diagnosis: the extended model file and the plots (residual against the variable
that exposed each effect, before and after; unexplained structure; held-out errors)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from omnibench.analysis.diagnosis import structure
from omnibench.analysis.diagnosis.core import Diagnosis
from omnibench.errors import UserError
from omnibench.files import save_figure


def model_toml(diag: Diagnosis) -> str:
    """The extended model as a robot TOML text (the refitted coefficients and the added effects)."""
    import tomli_w

    data = diag.extended.to_toml_dict()
    name = data.pop("name", diag.declared.name)
    from omnibench import __version__
    from omnibench.files import MARKER

    head = [f"{MARKER} {__version__} diagnose: {name}, extended by `omnibench diagnose`.",
            "# Added effects (value ± standard error):"]
    for c in diag.selected:
        vals = ", ".join(f"{p.split('.')[-1]} = {c.values[p]:.5g} ± {c.se[p]:.2g}" for p in c.values)
        head.append(f"#   {c.name}: {vals}   (LR {c.lr:.1f}, p {c.p:.1e})")
    if not diag.selected:
        head.append("#   none: no candidate earned its parameters; coefficients refitted only.")
    head.append("# SI units (see docs/robot-file.md and docs/effects.md). [fit]: the refitted coefficients'")
    head.append("# standard errors and 95 % intervals (value ± 1.96 SE), as `omnibench fit` writes them.")
    return "\n".join(head) + "\n" + tomli_w.dumps({"name": name, **data, "fit": fit_table(diag)})


def fit_table(diag: Diagnosis) -> dict[str, Any]:
    """The extended model's [fit] table: each refitted coefficient's value, standard error and
    95 % interval (TOML has no NaN: an unknown SE is left out)."""
    from omnibench import __version__

    params: dict[str, Any] = {}
    fit = diag.final_fit
    for name in fit.free:
        v, se = float(fit.values[name]), float(fit.se.get(name, math.nan))
        entry: dict[str, Any] = {"value": v}
        if math.isfinite(se):
            entry.update(se=se, ci95=[v - 1.959964 * se, v + 1.959964 * se])
        params[name] = entry
    return {"tool": f"omnibench {__version__} diagnose", "procedures": list(diag.problem.procedures),
            "added": [c.name for c in diag.selected], "parameters": params}


def write_model(diag: Diagnosis, path: str | Path) -> Path:
    """Write the extended model; the file loads back with omnibench.model.load_robot."""
    p = Path(path)
    from omnibench.files import write_atomic

    return write_atomic(p, model_toml(diag), "extended model")


def _variable_values(diag: Diagnosis, variable: str, predicted: np.ndarray) -> np.ndarray:
    t = diag.problem.table
    col = structure.VARIABLES[variable][0]
    if col == "wheel_direction":
        return t["wheel"].to_numpy(float) * np.sign(t["direction"].to_numpy(float))
    v = t[col].to_numpy(float)
    sig = t["signal"].astype(str).to_numpy()
    if variable == "speed":
        v = np.where(np.isin(sig, structure.SPEED_SIGNALS), predicted, v)
    if variable == "current":
        v = np.where(np.isin(sig, structure.CURRENT_SIGNALS), predicted, v)
    return v


def _panel(ax, x, r, title: str, xlabel: str, ylabel: str) -> None:
    ax.scatter(x, r, s=6, alpha=0.5, color="tab:blue", label="residual")
    ux = np.unique(x[np.isfinite(x)])
    if len(ux) > 1:
        if len(ux) <= 8:
            centers, means = ux, np.array([r[x == u].mean() for u in ux])
        else:
            edges = np.unique(np.quantile(x, np.linspace(0, 1, 9)))
            idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
            centers = np.array([x[idx == k].mean() for k in range(len(edges) - 1) if np.any(idx == k)])
            means = np.array([r[idx == k].mean() for k in range(len(edges) - 1) if np.any(idx == k)])
        ax.plot(centers, means, "o-", color="tab:red", label="binned mean")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=7)


def write_plots(diag: Diagnosis, folder: str | Path) -> list[Path]:
    """PNG figures in `folder`; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(folder)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{out_dir}: cannot create the plot folder ({exc.strerror or exc.__class__.__name__})") from None
    prob = diag.problem
    paths: list[Path] = []
    fin_r = diag.final_fit.residual(prob)
    steps: list[tuple[str, Any, Any, Any]] = []  # (name, finding, fit before, fit after)
    prev = diag.base_fit
    for c in diag.selected:
        f = diag.exposed_by.get(c.name)
        if f is not None:
            steps.append((c.name, f, prev, c.fit))
        prev = c.fit
    for name, f, before, after in steps:
        m = prob.used & (prob.group == f.group)
        fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
        unit = str(prob.table.loc[m, "unit"].iloc[0]) if m.any() else ""
        vunit = structure.VARIABLES[f.variable][1]
        for ax, fit, label in ((axes[0], before, "before"), (axes[1], after, f"after adding {name}")):
            x = _variable_values(diag, f.variable, fit.f)[m]
            _panel(ax, x, fit.residual(prob)[m], f"{f.group.replace('/no-se', '')}: {label}",
                   f"{f.variable} ({vunit})" if vunit else f.variable, f"measured - model ({unit})")
        fig.suptitle(f"{name}: exposed by the residual against {f.variable}")
        fig.tight_layout()
        p = out_dir / f"diagnose_{name}.png"
        save_figure(fig, p, dpi=110)
        plt.close(fig)
        paths.append(p)
    for k, f in enumerate(diag.unexplained[:4]):
        m = prob.used & (prob.group == f.group)
        fig, ax = plt.subplots(figsize=(6, 4))
        unit = str(prob.table.loc[m, "unit"].iloc[0]) if m.any() else ""
        x = _variable_values(diag, f.variable, diag.final_fit.f)[m]
        _panel(ax, x, fin_r[m], f"unexplained: {f.location()[:90]}", f.variable, f"measured - model ({unit})")
        fig.tight_layout()
        p = out_dir / f"diagnose_unexplained_{k + 1}.png"
        save_figure(fig, p, dpi=110)
        plt.close(fig)
        paths.append(p)
    # held-out error per procedure, before and after
    procs = list(diag.before)
    if procs:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        xb = np.arange(len(procs))
        b = [100 * diag.before[p]["nrmse"] for p in procs]
        a = [100 * diag.after.get(p, {}).get("nrmse", math.nan) for p in procs]
        ax.bar(xb - 0.2, b, 0.4, label="declared model")
        ax.bar(xb + 0.2, a, 0.4, label="extended model")
        ax.set_xticks(xb, procs)
        ax.set_ylabel("held-out error (% of RMS measured)")
        ax.legend()
        fig.tight_layout()
        p = out_dir / "diagnose_heldout_error.png"
        save_figure(fig, p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths
