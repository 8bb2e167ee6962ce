"""The end-of-campaign summary on the terminal: what a person wants to read before opening the
report: the model the campaign ends with (coefficients with SE and 95 % interval, the declared
fit beside them when diagnosis changed them), the energy error before/after, what diagnose added
or left unexplained."""

from __future__ import annotations

import math
from typing import Any

from omnibench.campaign.answer import campaign_answer, inadequacy


def _pct(v: Any) -> str:
    return f"{v:.3g} %" if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else "–"


def campaign_summary(results: dict[str, Any]) -> list[str]:
    """Lines for the terminal from a campaign's results (see campaign.run.run_campaign)."""
    lines = ["", "== summary"]
    stages = results.get("analysis") or {}
    ans = campaign_answer(stages)
    wrong = inadequacy(ans)
    if wrong:  # before the numbers: they are this model's reading of runs it does not fit
        lines += [wrong[0]] + [f"  {w}" for w in wrong[1:]]
    if ans.coefficients:
        if ans.model == "diagnosed":
            added = ", ".join(str(s.get("effect")) for s in ans.added)
            lines.append(f"the model (diagnosed: declared model + {added}; value ± SE, 95 % interval; "
                         "before = the declared fit):")
        else:
            lines.append("the model (declared fit; value ± SE, 95 % interval, verdict):")
        for c in ans.coefficients:
            cell = c.cells()
            tail = (f"  before {cell['before']}" if ans.model == "diagnosed" else f"  {c.verdict}").rstrip()
            lines.append(f"  {c.name:<24} {cell['value']:>22} {cell['ci95']:>24} {cell['unit']:<14}{tail}")
        if ans.model_file:
            lines.append(f"  model file: {ans.model_file}")
    else:
        lines.append(f"fit: {(stages.get('fit') or {}).get('status', 'not run')}")
    if ans.energy_before is not None:
        ve = (stages.get("validate-energy") or {}).get("result") or {}
        if ans.energy_after is not None:
            lines.append(f"energy: predicted vs measured, mean |error| {_pct(ans.energy_before)} (declared fit) -> "
                         f"{_pct(ans.energy_after)} (diagnosed model)")
        else:
            lines.append(f"energy: predicted vs measured, mean |error| {_pct(ans.energy_before)}, "
                         f"max {_pct(ve.get('max_abs_error_pct'))}")
    else:
        lines.append(f"energy validation: {(stages.get('validate-energy') or {}).get('status', 'not run')}")
    dg = (stages.get("diagnose") or {}).get("result") or {}
    if "selected" in dg:
        lines.append("diagnose added: " + (", ".join(str(s.get("effect")) for s in ans.added) if ans.added
                                           else "nothing (no effect earned its parameters)"))
        for proc, (b, a) in ans.heldout.items():
            if b is not None and a is not None:
                lines.append(f"  held-out error {proc}: {100 * b:.3g} % -> {100 * a:.3g} %")
        for un in ans.unexplained:
            lines.append(f"  left unexplained: {un.get('group')} against {un.get('variable')}")
    else:
        lines.append(f"diagnose: {(stages.get('diagnose') or {}).get('status', 'not run')}")
    lines.append(f"report: {results.get('report')} and {results.get('report_html')}")
    return lines
