"""The end-of-campaign summary on the terminal: what a person wants to read before opening the
report: fitted values with SE, the energy error, what diagnose added or left unexplained."""

from __future__ import annotations

import math
from typing import Any


def _num(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else "–"


def campaign_summary(results: dict[str, Any]) -> list[str]:
    """Lines for the terminal from a campaign's results (see bench.campaign.run_campaign)."""
    lines = ["", "== summary"]
    stages = results.get("analysis") or {}
    fit = (stages.get("fit") or {}).get("result") or {}
    params = fit.get("parameters") or {}
    if params:
        lines.append("fitted (value ± SE, verdict):")
        for name, p in params.items():
            se = f" ± {_num(p.get('se'))}" if p.get("identifiable") else ""
            lines.append(f"  {name:<24} {_num(p.get('value'))}{se} {p.get('unit', '')}  {p.get('verdict', '')}")
    else:
        lines.append(f"fit: {(stages.get('fit') or {}).get('status', 'not run')}")
    ve = (stages.get("validate-energy") or {}).get("result") or {}
    if "mean_abs_error_pct" in ve:
        lines.append(f"energy: predicted vs measured, mean |error| {_num(ve['mean_abs_error_pct'])} %, "
                     f"max {_num(ve.get('max_abs_error_pct'))} %")
    else:
        lines.append(f"energy validation: {(stages.get('validate-energy') or {}).get('status', 'not run')}")
    dg = (stages.get("diagnose") or {}).get("result") or {}
    if "selected" in dg:
        added = [s.get("effect") for s in dg.get("selected") or []]
        lines.append("diagnose added: " + (", ".join(added) if added else "nothing (no effect earned its parameters)"))
        for proc, b in (dg.get("before") or {}).items():
            a = (dg.get("after") or {}).get(proc) or {}
            if isinstance(b, dict) and b.get("nrmse") is not None and a.get("nrmse") is not None:
                lines.append(f"  held-out error {proc}: {100 * b['nrmse']:.3g} % -> {100 * a['nrmse']:.3g} %")
        for un in dg.get("unexplained") or []:
            lines.append(f"  left unexplained: {un.get('group')} against {un.get('variable')}")
    else:
        lines.append(f"diagnose: {(stages.get('diagnose') or {}).get('status', 'not run')}")
    lines.append(f"report: {results.get('report')} and {results.get('report_html')}")
    return lines
