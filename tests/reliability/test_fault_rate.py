"""The link rides out a bad cable: a sweep at 2 % corrupted bytes (both directions) completes,
with the same steady speeds as on a clean link (issue 12)."""

from __future__ import annotations

from omnibench.runs import read_run
from reliability.test_stale_samples import run_sweep


def test_sweep_completes_at_two_percent_byte_errors(tmp_path) -> None:
    clean = read_run(run_sweep("sim://?seed=5", tmp_path / "clean"))
    bad = read_run(run_sweep("sim://?seed=5&corrupt=0.02", tmp_path / "bad"))
    assert bad.status == "complete" and len(bad.steps) == len(clean.steps)
    link = bad.metadata["link"]
    assert link["crc_errors"] > 50 and link["lost"] > 50 and link["retries"] > 0  # the cable was bad
    assert clean.metadata["link"]["crc_errors"] == 0
    for j in range(1, 5):
        w, w0 = bad.steps[f"w{j}"].to_numpy(), clean.steps[f"w{j}"].to_numpy()
        # encoder quantisation of a 0.2 s fit with half the samples lost: ~0.02 rad/s
        assert (abs(w - w0) <= 0.01 * abs(w0) + 0.03).all()
