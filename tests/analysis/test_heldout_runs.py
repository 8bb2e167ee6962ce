"""Leave-one-run-out bookkeeping: stages of a diagnosis, trade-offs never silent, bad input."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from omnibench.analysis.diagnosis import loro
from omnibench.analysis.heldout_runs import RunError, table


def _diag(robot):
    final = robot.replace(I_w=0.0175, effects={"per_wheel_latency": {f"tau_{j}": 0.004 * j for j in range(1, 5)},
                                               "asymmetric_coulomb": {"db": -0.03}})
    sel = [SimpleNamespace(name=n) for n in ("I_w", "per_wheel_latency", "asymmetric_coulomb")]
    free = ["a", "b", "I_w"] + [f"per_wheel_latency.tau_{j}" for j in range(1, 5)] + ["asymmetric_coulomb.db"]
    return SimpleNamespace(declared=robot, selected=sel, base_fit=SimpleNamespace(free=["a", "b"]),
                           final_fit=SimpleNamespace(robot=final, free=free))


def test_stages_add_one_addition_at_a_time(robot):
    m = loro.stage_models(_diag(robot))
    assert list(m) == ["declared", "declared + I_w", "+ per_wheel_latency", "+ asymmetric_coulomb"]
    assert m["declared"].free == ["a", "b"] and not m["declared"].robot.effects
    assert m["declared + I_w"].robot.I_w == 0.0175 and "I_w" in m["declared + I_w"].free
    assert set(m["+ per_wheel_latency"].robot.effects) == {"per_wheel_latency"}
    assert m["+ asymmetric_coulomb"].free[-1] == "asymmetric_coulomb.db"


def test_an_addition_that_costs_a_run_is_reported_as_a_trade_off(robot, monkeypatch):
    labels = ["declared", "declared + I_w", "+ per_wheel_latency", "+ asymmetric_coulomb"]
    errs = [RunError("rc", "in-air trace", "wheel speed", dict(zip(labels, [0.025, 0.023, 0.0252, 0.026]))),
            RunError("fast", "in-air trace", "wheel speed", dict(zip(labels, [0.40, 0.16, 0.127, 0.113])))]
    monkeypatch.setattr(loro, "leave_one_run_out", lambda *a, **k: errs)
    h = loro.heldout_runs(_diag(robot), obs=None)
    # compared with the declared model: +0.8 % on rc is noise, +4 % is a trade-off
    assert [t["addition"] for t in h.tradeoffs] == ["asymmetric_coulomb"]
    assert h.tradeoffs[0]["worse"] == {"rc": (0.025, 0.026)} and "fast" in h.tradeoffs[0]["better"]
    assert h.stages[h.accepted] == "+ per_wheel_latency"
    text = h.text()
    assert "trade-off: asymmetric_coulomb makes rc 2.50 % -> 2.60 % worse" in text
    assert "accepted on held-out runs: I_w, per_wheel_latency" in text
    assert "mean over in-air traces" in table(errs)


def test_baseline_needs_two_runs(tmp_path, capsys):
    from omnibench.runs import RunWriter

    with RunWriter.create(tmp_path, "step_response", counts_per_rev=980) as w:
        for k in range(5):
            w.sample({"step": 0, "t": 0.02 * k, "u1": 0.5, "u2": 0.5, "u3": 0.5, "u4": 0.5,
                      "enc1": k, "enc2": k, "enc3": k, "enc4": k})
        w.step_complete({"step": 0, "duty": 0.5, "t_start": 0.0, "t_end": 0.08})
    from omnibench.cli import main

    model = Path(__file__).resolve().parents[2] / "omnibench" / "model" / "omnibot.toml"
    with pytest.raises(SystemExit) as exit_:
        main(["predict", "--model", str(model), str(w.path), "--baseline"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "at least two runs" in err and len(err.strip().splitlines()) == 1
