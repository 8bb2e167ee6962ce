"""The firmware's actuation chain as data: applied duties and the firmware timing record."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from omnibench.model import actuation
from omnibench.model.timing import PACKET_9600
from omnibench.runs.tfm import SQUARE_SKETCH

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(("u", "step"), [(0.3, 38), (0.5, 64), (0.7, 89), (1.0, 127), (0.0, 0), (0.002, 0)])
def test_applied_duty_is_the_drivers_step(u: float, step: int) -> None:
    assert actuation.applied_duty(u) == pytest.approx(step / 127, abs=0)
    assert actuation.applied_duty(-u) == pytest.approx(-step / 127, abs=0)


def test_applied_duty_is_within_half_a_step_and_monotone() -> None:
    u = np.linspace(-1.2, 1.2, 20001)
    a = actuation.applied_duty(u)
    assert np.all(np.abs(a - np.clip(u, -1, 1)) <= 0.5 / 127 + 1e-4)
    assert np.all(np.diff(a) >= 0)
    assert set(np.round(np.abs(a) * 127, 9)) == set(range(128))


def test_the_firmware_rounds_as_the_description_says() -> None:
    d = actuation.chain()["driver"]
    src = (ROOT / "firmware/avr/sabertooth.c").read_text()
    expr = f"(x * {d['steps']} + {d['wire_scale'] // 2}) / {d['wire_scale']}"
    assert expr in src
    assert re.search(r"next_wheel = 0;\s*/\* a new command goes out FL, FR, RL, RR", src)
    assert actuation.chain()["timing"]["command_order"] == [1, 2, 3, 4]


def test_firmware_timing_record_has_the_2019_sketches_keys() -> None:
    ft = actuation.firmware_timing()
    assert ft["packet_s"] == pytest.approx(PACKET_9600)
    assert ft["packet_s"] == pytest.approx(4.1667e-3, rel=1e-4)
    assert {"sketch", "command_order", "packet_s", "command_offset_s"} <= set(ft) & set(SQUARE_SKETCH)
    assert ft["command_order"] == [1, 2, 3, 4]
    assert not str(ft["source"]).startswith("assumed")  # recorded, not a guess the analysis profiles over


def test_a_firmware_run_is_replayed_with_the_applied_duties(tmp_path: Path) -> None:
    import dataclasses
    from types import SimpleNamespace

    import pandas as pd

    from omnibench.analysis.observations import applied_duties
    ft = actuation.firmware_timing()
    frame = pd.DataFrame({"step": [1, 2, 3], "u1": [0.3, 0.5, 0.7], "u2": [-0.3, 0.0, float("nan")],
                          "u3": [0.3] * 3, "u4": [1.0] * 3})
    @dataclasses.dataclass
    class FakeRun:
        info: object
        samples: pd.DataFrame
        steps: pd.DataFrame

    got = applied_duties(FakeRun(SimpleNamespace(firmware_timing=ft), frame, frame))  # type: ignore[arg-type]
    assert got.steps["u1"].tolist() == pytest.approx([38 / 127, 64 / 127, 89 / 127], abs=0)
    assert got.samples["u2"].iloc[0] == -38 / 127 and got.samples["u2"].iloc[1] == 0.0
    assert np.isnan(got.samples["u2"].iloc[2])
    assert frame["u1"].iloc[0] == 0.3  # the run read is not changed in place
    ideal = FakeRun(SimpleNamespace(firmware_timing=None), frame, frame)
    assert applied_duties(ideal) is ideal  # type: ignore[arg-type]
