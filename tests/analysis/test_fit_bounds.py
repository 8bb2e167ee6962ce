"""`fit` never calls a parameter pinned at a bound (or at zero) "identified"."""

from __future__ import annotations

import json
from pathlib import Path

from omnibench.analysis.fitting import _pinned
from omnibench.cli import main
from omnibench.model.robot import DEFAULT_ROBOT_FILE

SMALL = Path(__file__).parents[1] / "bench" / "procedures" / "small_forward.toml"


def test_pinned_names_the_bound() -> None:
    assert _pinned(3.6e-17, (0.0, float("inf")), 0.002) == "pinned at its lower bound 0"
    assert _pinned(1.0, (1e-3, 1.0), 0.1) == "pinned at its upper bound 1"
    assert _pinned(-1e-12, (-1.0, 1.0), 0.01) == "pinned at zero"
    assert _pinned(0.0199, (0.0, float("inf")), 0.002) == ""


def test_rolling_resistance_pushed_below_zero_is_at_bound_not_identified(tmp_path, capsys) -> None:
    """A robot rolling more freely than the fitted model's transmission friction allows drives the
    rolling resistance to its bound 0; before, fit called C_r = 3.6e-17 "identified"."""
    slick = tmp_path / "slick.toml"
    text = DEFAULT_ROBOT_FILE.read_text(encoding="utf-8")
    slick.write_text(text.replace("\nb = 0.5 ", "\nb = 0.25").replace("\nC_r = 0.02 ", "\nC_r = 0.0  "),
                     encoding="utf-8")
    runs = tmp_path / "runs"
    main(["forward", "--port", f"sim://?robot={slick}&seed=2", "--procedure", str(SMALL), "--out", str(runs)])
    capsys.readouterr()
    main(["fit", str(runs), "--out", str(tmp_path / "model.toml"), "--json"])
    res = json.loads(capsys.readouterr().out)
    c_r = res["parameters"]["C_r"]
    assert c_r["verdict"] == "at bound" and not c_r["identifiable"]
    assert "lower bound 0" in c_r["reason"]
