"""Every bad-input case gets one clear line and a non-zero exit; nothing hangs, nothing
writes over a run, a refused command changes nothing (issue 12; cases in badinput.py)."""

from __future__ import annotations

from reliability.badinput import run_all


def test_every_bad_input_is_refused_clearly(tmp_path) -> None:
    counts, worst = run_all(tmp_path)
    assert worst == []
    assert counts["clear"] >= 28 and sum(counts.values()) == counts["clear"]
