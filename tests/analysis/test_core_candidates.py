"""Core parameters as diagnosis candidates: a wrong declared I_w is re-estimated (reported as a
re-estimate, with its evidence), and a command latency is found with its wheel order."""

from __future__ import annotations

from omnibench.analysis.diagnosis import diagnose
from omnibench.analysis.diagnosis.campaign import REVEALING, SquareWave, CampaignSpec, campaign


def test_a_wrong_wheel_inertia_is_re_estimated_not_replaced_by_an_effect(omnibot):
    world = omnibot.replace(I_w=4 * omnibot.I_w)  # the rotor seen through the gearbox, missing
    spec = CampaignSpec((), SquareWave(duties=(0.5, -0.5), half_period=0.25, duration=3.0, sample_dt=0.02,
                                       jitter=0.005))
    d = diagnose(omnibot, campaign(world, spec, {}, seed=5))
    assert d.selected and d.selected[0].name == "I_w"
    c = d.selected[0]
    assert abs(c.values["I_w"] - world.I_w) <= 3 * c.se["I_w"]
    assert "I_w re-estimated: 0.00266 →" in d.text()
    assert d.to_json()["selected"][0]["kind"] == "core parameter re-estimated"
    assert d.after["step_response"]["nrmse"] < 0.5 * d.before["step_response"]["nrmse"]


def test_per_wheel_latency_reports_the_order_the_wheels_are_served(omnibot):
    from omnibench.effects import EFFECTS

    eff = EFFECTS["per_wheel_latency"]
    d = diagnose(omnibot, campaign(omnibot, REVEALING["per_wheel_latency"], eff.world(), seed=3))
    assert d.selected[0].name == "per_wheel_latency"
    # example: FL 15, FR 4, RL 10, RR 2 ms -> served RR, FR, RL, FL
    note = d.to_json()["selected"][0]["note"]
    assert note.startswith("wheel order: RR") and note.index("FR") < note.index("RL") < note.index("FL")
    assert "wheel order: RR" in d.text()
