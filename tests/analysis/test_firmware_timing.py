"""Command timing as a property of the run's firmware (issue 36): latencies follow the send
order the run's sketch used, a model file keeps the firmware timing apart from the robot's own
effects, and a run of unknown firmware is predicted under each documented sketch's timing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from omnibench.model import Scenario, simulate_batch
from omnibench.model.timing import FIRMWARE_TERMS, wheel_delays

TAUS = {"tau_1": 0.002, "tau_2": 0.006, "tau_3": 0.011, "tau_4": 0.015}
RC_ORDER = (1, 2, 4, 3)  # ardu.ino.ino: FL, FR, BR, BL


def test_per_wheel_latency_belongs_to_the_place_in_the_send_order():
    """tau_k is the k-th packet's latency: the square-wave sketch (FL, FR, RL, RR) gives wheel k
    tau_k, the RC sketch (FL, FR, RR, RL) gives RR tau_3 and RL tau_4."""
    np.testing.assert_allclose(wheel_delays({"per_wheel_latency": TAUS}, (1, 2, 3, 4)), [0.002, 0.006, 0.011, 0.015])
    np.testing.assert_allclose(wheel_delays({"per_wheel_latency": TAUS}, RC_ORDER), [0.002, 0.006, 0.015, 0.011])
    np.testing.assert_allclose(wheel_delays({"per_wheel_latency": TAUS}, None), [0.002, 0.006, 0.011, 0.015])


def test_independent_world_applies_the_same_send_order():
    from omnibench.worlds.independent import _latencies

    for order in ((1, 2, 3, 4), RC_ORDER, (4, 3, 2, 1)):
        ef = {"per_wheel_latency": TAUS, "serial_command_latency": {"tau": 0.001, "tau_packet": 0.004}}
        np.testing.assert_allclose(_latencies(ef, order), wheel_delays(ef, order))


def test_a_model_predicts_an_rc_sketch_run_with_the_rc_send_order(robot):
    """Closed form: the model replaying a run recorded with the RC order is the model whose
    wheel latencies are permuted by hand (RR gets the third packet's, RL the fourth's)."""
    t = np.array([0.0, 0.2, 0.5])
    U = np.array([[0.6, 0.6, 0.6, 0.6], [-0.5, -0.5, -0.5, -0.5], [0.0, 0.0, 0.0, 0.0]])
    by_order = simulate_batch(robot, [Scenario(mode="upside_down", effects={"per_wheel_latency": TAUS},
                                               command_order=RC_ORDER)], t, U, 0.8)
    swapped = {**TAUS, "tau_3": TAUS["tau_4"], "tau_4": TAUS["tau_3"]}
    by_hand = simulate_batch(robot, [Scenario(mode="upside_down", effects={"per_wheel_latency": swapped})], t, U, 0.8)
    for j in range(1, 5):
        np.testing.assert_allclose(by_order.signal(f"phi{j}"), by_hand.signal(f"phi{j}"), atol=1e-12)
    # and it is not the square-wave sketch's: RL and RR differ
    square = simulate_batch(robot, [Scenario(mode="upside_down", effects={"per_wheel_latency": TAUS})], t, U, 0.8)
    assert np.max(np.abs(square.signal("phi3") - by_order.signal("phi3"))) > 1e-3


def test_model_file_keeps_firmware_timing_apart_from_the_robots_effects(robot, tmp_path):
    import tomllib

    from omnibench.analysis.model_file import load_model
    from omnibench.errors import UserError
    from omnibench.model.robot import load_robot

    rb = robot.replace(effects={"actuator_lag": {"tau_a": 0.019}, "per_wheel_latency": dict(TAUS)})
    assert set(rb.firmware_timing) == {"per_wheel_latency"} and set(rb.own_effects) == {"actuator_lag"}
    import tomli_w

    p = tmp_path / "m.toml"
    p.write_text(tomli_w.dumps(rb.to_toml_dict()))
    data = tomllib.loads(p.read_text())
    assert set(data["effects"]) == {"actuator_lag"}
    assert data["firmware_timing"]["per_wheel_latency"]["tau_3"] == pytest.approx(0.011)
    back, _ = load_model(p)
    assert back.effects["per_wheel_latency"]["tau_4"] == pytest.approx(0.015)
    assert back.effects["actuator_lag"]["tau_a"] == pytest.approx(0.019)
    assert all(t in FIRMWARE_TERMS for t in back.firmware_timing)
    bad = tmp_path / "bad.toml"
    bad.write_text(p.read_text() + "\n[firmware_timing.actuator_lag]\ntau_a = 0.01\n")
    with pytest.raises(UserError, match="belongs in \\[effects\\]") as err:
        load_robot(bad)
    assert "\n" not in str(err.value)


DATA = Path("/work/shared/data/omnibot-tfm")
for _p in Path(__file__).resolve().parents:
    if (_p / "shared" / "data" / "omnibot-tfm").is_dir():
        DATA = _p / "shared" / "data" / "omnibot-tfm"
        break


@pytest.mark.skipif(not (DATA / "results_ground_x.mat").is_file(), reason="2019 TFM data not available")
def test_unknown_firmware_is_profiled_over_the_documented_sketches_and_named(robot, tmp_path):
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.predict import predict_runs
    from omnibench.runs import read_run
    from omnibench.runs.tfm import RC_SKETCH, SQUARE_SKETCH, import_tfm

    path = import_tfm(DATA / "results_ground_x.mat", tmp_path, where="floor")  # where: unknown from the data alone
    ft = read_run(path).metadata["firmware_timing"]
    assert ft["sketch"] == "unknown" and ft["profiled_over"] == [SQUARE_SKETCH["sketch"], RC_SKETCH["sketch"]]
    obs = Observations.from_runs([path], robot)
    plain = predict_runs(robot, obs)[0]
    prof = predict_runs(robot, obs, profile_timing=True)[0]
    assert set(prof.firmware_profiled) == {SQUARE_SKETCH["sketch"], RC_SKETCH["sketch"]}
    best = min(prof.firmware_profiled, key=prof.firmware_profiled.get)
    assert prof.firmware == best and prof.nrmse["wheel_speed"] == pytest.approx(prof.firmware_profiled[best])
    assert plain.nrmse["wheel_speed"] == pytest.approx(prof.firmware_profiled[SQUARE_SKETCH["sketch"]])
    assert "firmware unknown" in prof.firmware_text() and best in prof.firmware_text()
    # a run of a documented sketch is replayed with that sketch's timing only
    sq = predict_runs(robot, Observations.from_runs([import_tfm(DATA / "inputs.mat", tmp_path)], robot),
                      profile_timing=True)[0]
    assert sq.firmware == RC_SKETCH["sketch"] and not sq.firmware_profiled


@pytest.mark.skipif(not (DATA / "inputs.mat").is_file(), reason="2019 TFM data not available")
def test_leave_one_firmware_out_fits_on_the_other_sketch_only(robot, tmp_path):
    """Folds by sketch: the square-wave sketch's logs are predicted from the RC log and the RC
    log from the square-wave sketch's logs; the floor run (unknown firmware) is in no fold."""
    import types

    from omnibench.analysis.diagnosis.loro import leave_one_firmware_out, run_sketch
    from omnibench.analysis.observations import Observations
    from omnibench.runs.tfm import RC_SKETCH, SQUARE_SKETCH, import_tfm

    for f in ("results_jacked.mat", "square_small.mat", "inputs.mat", "results_ground_x.mat"):
        import_tfm(DATA / f, tmp_path)
    obs = Observations.from_runs([tmp_path], robot)
    diag = types.SimpleNamespace(declared=robot, base_fit=types.SimpleNamespace(free=["a", "b"]), selected=[],
                                 final_fit=types.SimpleNamespace(robot=robot, free=["a", "b"]))
    h = leave_one_firmware_out(diag, obs, max_nfev=10)
    assert len(h.errors) == 3 and len(h.left_out) == 1 and run_sketch(obs, h.left_out[0]) == "unknown"
    for e in h.errors:
        own = h.sketch[e.run]
        assert own in (SQUARE_SKETCH["sketch"], RC_SKETCH["sketch"])
        assert h.trained_on[e.run] and all(run_sketch(obs, r) not in (own, "unknown") for r in h.trained_on[e.run])
        assert 0 < e.nrmse["declared"] < 1
    assert not h.worse and "no log of another sketch worse" in h.text()
