"""The report's answer gives each coefficient the fit's own 95 % interval (the one of the fit
table), not a second one from value ± 1.96 SE."""

from __future__ import annotations

from omnibench.campaign.answer import campaign_answer


def test_the_answer_uses_the_fits_own_interval() -> None:
    # a t-quantile interval (few degrees of freedom): wider than ± 1.96 SE
    params = {"a": {"value": 0.02, "se": 0.001, "ci95": [0.0175, 0.0225], "unit": "N m s/rad",
                    "verdict": "identified", "identifiable": True}}
    ans = campaign_answer({"fit": {"status": "ok", "result": {"parameters": params}}})
    (coef,) = ans.coefficients
    assert coef.ci95() == (0.0175, 0.0225)
    assert coef.cells()["ci95"] == "[0.0175, 0.0225]"


def test_without_the_fits_interval_it_falls_back_to_the_normal_one() -> None:
    params = {"a": {"value": 0.02, "se": 0.001, "unit": "", "verdict": "identified", "identifiable": True}}
    (coef,) = campaign_answer({"fit": {"status": "ok", "result": {"parameters": params}}}).coefficients
    lo, hi = coef.ci95()  # type: ignore[misc]
    assert abs(hi - 0.02 - 1.959964e-3) < 1e-12
