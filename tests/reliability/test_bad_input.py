"""Bad input across every command (tests/reliability/badinput.py builds the cases from tables):
each gets one clear line and a non-zero exit, or is an input listed as acceptable; nothing
hangs, nothing writes over a run, a refused command changes nothing on disk (issue 12).

The test runs every fourth case (about 220, ~15 s CPU); benchmarks/reliability.py runs all.
"""

from __future__ import annotations

from reliability.badinput import ACCEPTABLE, SLOW, classify, run_all


def test_every_bad_input_is_refused_clearly(tmp_path) -> None:
    counts, worst = run_all(tmp_path, select=lambda i, case: i % 4 == 0 and case.name not in SLOW)
    assert worst == []
    assert counts["clear"] >= 200
    assert sum(counts.values()) == counts["clear"] + counts["handled"]


def test_the_classifier_tells_the_outcomes_apart() -> None:
    assert classify(2, "omnibench: error: --rate nan: not a number\n", False) == "clear"
    assert classify(2, "Usage: omnibench x\nTry 'omnibench x -h'\n\nError: bad\n", False) == "internal"
    assert classify(1, "omnibench: internal error: KeyError: 'x'\n", False) == "internal"
    assert classify(0, "", False, "fit a cut run") == "silent"
    name = next(iter(ACCEPTABLE))
    assert classify(0, "", False, name) == "handled"
    assert classify(0, "", False, name, wrote_nan=True) == "silent"
    assert classify(None, "", False) == "hang"
    assert classify(2, "omnibench: error: refused\n", True) == "overwrite"


def test_runs_of_one_robot_no_overwrite_and_resume_only_what_is_there(tmp_path) -> None:
    """Every mix (two worlds, the 2019 logs with a simulated run, a model of another encoder, a
    resume on another board), every file the tool did not write, every resume of a folder holding
    no campaign: refused in one line, nothing on disk changed."""
    counts, worst = run_all(tmp_path, select=lambda i, case: case.group == "one robot")
    assert worst == []
    assert sum(counts.values()) == counts["clear"] >= 16 and counts["mixed"] == counts["silent"] == counts["overwrite"] == 0
