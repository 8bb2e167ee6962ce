"""Core parameters as diagnosis candidates: a wrong declared I_w is re-estimated (reported as a
re-estimate, with its evidence), and a command latency is found with its wheel order."""

from __future__ import annotations

from omnibench.analysis.diagnosis import diagnose
from omnibench.analysis.diagnosis.campaign import REVEALING, CampaignSpec, SquareWave, campaign


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


def test_a_latency_with_an_insignificant_extra_parameter_gives_way_to_the_one_it_contains():
    """serial_command_latency with tau_packet = 0 is command_latency: it leads only when its
    packet delay is significant given the simpler one, not on an AIC drop of 2."""
    from types import SimpleNamespace

    from omnibench.analysis.diagnosis.core import Candidate, _prefer_nested

    def cand(name, q, deviance, aic):
        return Candidate(name, 1, 0.0, fitted=True, q=q, aic_drop=aic, fit=SimpleNamespace(deviance=deviance))

    serial, single = cand("serial_command_latency", 2, -100.0, 4838.3), cand("command_latency", 1, -96.3, 4836.5)
    assert [c.name for c in _prefer_nested([serial, single], 1e-3 / 16)] == ["command_latency", "serial_command_latency"]
    serial.fit.deviance = -130.0  # a packet delay the data insist on (LR 33.7 for 1)
    assert [c.name for c in _prefer_nested([serial, single], 1e-3 / 16)] == ["serial_command_latency", "command_latency"]
    per_wheel = cand("per_wheel_latency", 4, -101.0, 4835.0)  # contains both: the chain ends at the simplest
    assert _prefer_nested([per_wheel, single], 1e-3 / 16)[0].name == "command_latency"
