"""Operators: console prompts re-ask on a bad answer; world changes give the right actions."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from omnibench.bench.operator import ConsoleOperator, actions_for, parse_displacement
from omnibench.errors import UserError
from omnibench.procedures import Step, World


def _step(measure):
    return Step(index=3, kind="timed", label="x", world=World(), params={}, schedule=[(0.0, (0.1,) * 4)],
                duration=1.0, measure=measure)


def test_console_operator_reasks_until_a_length_is_given():
    runner = CliRunner()
    with runner.isolation(input="about a metre\n123 cm\n"):
        assert ConsoleOperator().measure(_step("distance")) == pytest.approx(1.23)
    with runner.isolation(input="0.5\n0.5 m, 20 cm\n"):
        assert ConsoleOperator().measure(_step("displacement")) == pytest.approx((0.5, 0.2))
    with runner.isolation(input="y\n"):
        assert ConsoleOperator().start_mark(_step("distance")) == "done"


def test_actions_follow_world_changes():
    flat = World("ground", "standard", None, 0.0)
    heavy = World("upside_down", "weighted", (1.9,) * 4, 0.0)
    assert [a.key for a in actions_for(None, heavy)] == ["flip", "wheels"]
    assert [a.key for a in actions_for(heavy, heavy)] == []
    assert [a.key for a in actions_for(flat, World("ground", "standard", None, 2.0))] == ["payload"]
    assert "Place 2 kg" in actions_for(flat, World("ground", "standard", None, 2.0))[0].prompt
    assert [a.key for a in actions_for(heavy, flat)] == ["flip", "wheels"]  # payload unchanged (0 kg)


def test_displacement_parsing():
    assert parse_displacement(["0.4 m", "-3 cm"], "w") == pytest.approx((0.4, -0.03))
    with pytest.raises(UserError, match="expected two lengths"):
        parse_displacement("0.4", "w")
    with pytest.raises(UserError, match="not in units compatible"):
        parse_displacement("0.4 kg, 1 m", "w")
