"""The robot description file: defaults, units, and one-line errors naming file, line and key."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from omnibench.errors import UserError
from omnibench.model.robot import DEFAULT_ROBOT_FILE, load_robot


def test_default_robot_has_the_real_omnibots_numbers(omnibot):
    assert omnibot.L == omnibot.l == pytest.approx(0.2096)
    assert omnibot.r == pytest.approx(0.0667)
    assert omnibot.m == pytest.approx(15.75)
    assert omnibot.alpha == pytest.approx((math.pi / 4, -math.pi / 4, -math.pi / 4, math.pi / 4))
    assert omnibot.k_e == pytest.approx(24 / (7000 * 2 * math.pi / 60) * 49, rel=1e-3)
    assert omnibot.k_t == pytest.approx(4.250 * 0.01 * 9.80665 / 13 * 49, rel=1e-3)
    assert omnibot.R_a == pytest.approx(24 / 13, rel=1e-3)
    assert omnibot.eta == 0.6 and omnibot.I_0 == 0.0
    assert omnibot.counts_per_rev == 980


def _edit(tmp_path: Path, old: str, new: str) -> Path:
    text = DEFAULT_ROBOT_FILE.read_text()
    assert old in text
    path = tmp_path / "robot.toml"
    path.write_text(text.replace(old, new, 1))
    return path


def test_values_with_units_are_converted_to_si(tmp_path):
    robot = load_robot(_edit(tmp_path, "m = 15.75 ", 'm = "15750 g" '))
    assert robot.m == pytest.approx(15.75)
    robot = load_robot(_edit(tmp_path, "r = 0.0667 ", 'r = "66.7 mm" '))
    assert robot.r == pytest.approx(0.0667)


def _line_of(path: Path, key: str) -> int:
    return next(n for n, line in enumerate(path.read_text().splitlines(), 1) if line.split("=")[0].strip() == key)


@pytest.mark.parametrize(
    "old, new, expect",
    [
        ("m = 15.75 ", 'm = "15.75 m" ', "[mass] m: '15.75 m' is not in units compatible with kg"),
        ("m = 15.75 ", "m = -15.75 ", "[mass] m: must be positive"),
        ("eta = 0.6 ", "eta = 1.6 ", "[motor] eta: must be at most 1.0"),
        ("b = 0.5 ", "b = -0.5 ", "[friction] b: must not be negative"),
        ("I_z = 0.461 ", "Iz = 0.461 ", "[mass] Iz: unknown key (did you mean I_z?)"),
        ("counts_per_rev = 980", "counts_per_rev = 980.5", "expected a whole number"),
        ('alpha = ["45 deg", "-45 deg", "-45 deg", "45 deg"]', 'alpha = ["45 deg", "-45 deg"]', "expected a list of 4 values"),
    ],
)
def test_bad_values_name_file_line_and_key(tmp_path, old, new, expect):
    path = _edit(tmp_path, old, new)
    with pytest.raises(UserError) as err:
        load_robot(path)
    message = str(err.value)
    assert expect in message
    assert "\n" not in message
    line = _line_of(path, new.split("=")[0].strip())
    assert message.startswith(f"{path}:{line}: ")


def test_missing_values_are_listed(tmp_path):
    path = tmp_path / "robot.toml"
    path.write_text('[geometry]\nL = 0.2\nl = 0.2\nr = 0.05\nalpha = ["45 deg", "-45 deg", "-45 deg", "45 deg"]\n')
    with pytest.raises(UserError, match=r"missing values: \[mass\] m, \[mass\] I_z"):
        load_robot(path)


def test_unknown_section_and_bad_toml(tmp_path):
    with pytest.raises(UserError, match=r"\[frction\]|frction: unknown section \(did you mean \[friction\]\?\)"):
        load_robot(_edit(tmp_path, "[friction]", "[frction]"))
    bad = tmp_path / "bad.toml"
    bad.write_text("[mass\nm = 1\n")
    with pytest.raises(UserError, match="not valid TOML"):
        load_robot(bad)
    with pytest.raises(UserError, match="robot file not found"):
        load_robot(tmp_path / "nope.toml")


def test_robot_round_trips_through_its_toml_dict(omnibot, tmp_path):
    import tomli_w

    path = tmp_path / "copy.toml"
    path.write_text(tomli_w.dumps(omnibot.to_toml_dict()))
    assert load_robot(path) == omnibot


def test_a_model_file_with_provenance_tables_loads_as_a_robot(omnibot, tmp_path):
    """A fitted model = robot tables + [fit]/[diagnosis] provenance; load_robot accepts it."""
    path = tmp_path / "model.toml"
    path.write_text(DEFAULT_ROBOT_FILE.read_text() + '\n[fit]\nruns = ["a"]\n[fit.a]\nvalue = 0.01\nse = 0.001\n')
    assert load_robot(path) == omnibot
