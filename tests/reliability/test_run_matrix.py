"""Run files you cannot trust (issue 38): one validating reader; every damaged field of run.json
and steps.jsonl is a one-line error naming file, line and field, or a correct result; never an
internal error, a silent drop or a write outside --out/--plots.

The matrix test runs a subset (every refused case of every 13th damage through the commands, and
a few accepted ones); benchmarks/reliability.py --only runs runs the whole matrix.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from omnibench.errors import UserError
from omnibench.runs import read_run
from omnibench.runs.check import run_problem
from omnibench.runs.record import check_resumable, is_safe_name
from reliability.badinput import SIM, make_fixture, run_cli
from reliability.runmatrix import COMMANDS, ESCAPE, Damage, apply, damages, run_matrix, total

MODEL = str(Path(__file__).resolve().parents[2] / "omnibench" / "model" / "omnibot.toml")


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    return make_fixture(tmp_path_factory.mktemp("fixture"))


def _copy(runs: dict[str, Path], tmp: Path, which: str = "sweep") -> Path:
    d = tmp / "runs" / runs[which].name
    shutil.copytree(runs[which], d)
    return d


def _edit_step(d: Path, line: int, **kv) -> None:
    lines = (d / "steps.jsonl").read_text().splitlines()
    rec = json.loads(lines[line])
    rec.update(kv)
    lines[line] = json.dumps(rec, allow_nan=True)
    (d / "steps.jsonl").write_text("\n".join(lines) + "\n")


def _edit_meta(d: Path, **kv) -> None:
    meta = json.loads((d / "run.json").read_text())
    meta.update(kv)
    (d / "run.json").write_text(json.dumps(meta, indent=2, allow_nan=True))


def test_every_field_damage_is_refused_by_the_reader_or_accepted_as_valid(runs, tmp_path) -> None:
    """The reader over the whole matrix (fast, no command): a refusal is one line naming the
    file and the field; what it accepts reads back with the same rows as the good run."""
    refused = accepted = 0
    # one copy of each run, each damage applied to a pristine one: apply() rewrites one file, which
    # is restored from the good run afterwards (an rmtree + copytree of the folder per damage was a
    # third of the test's time here: a directory's removal costs ~3 ms on this file system)
    copies: dict[str, Path] = {}
    pristine = {which: {p.name: p.read_bytes() for p in src.iterdir()} for which, src in runs.items()}
    for dmg, good in damages(runs):
        src = runs[dmg.run]
        d = copies.get(dmg.run)
        if d is None:
            d = copies[dmg.run] = tmp_path / dmg.run / src.name
            shutil.copytree(src, d)
        assert {p.name: p.read_bytes() for p in d.iterdir()} == pristine[dmg.run]  # as a fresh copy
        apply(d, dmg, good)
        why = run_problem(d)
        shutil.copy2(src / dmg.file, d / dmg.file)  # pristine again for the next damage
        if why is None:
            accepted += 1
            assert dmg.kind not in ("nan", "inf", "huge", "path trick") or (isinstance(good, str) and dmg.kind == \
                "path trick") or good is None, dmg.name
            continue
        refused += 1
        assert "\n" not in why and dmg.file in why, (dmg.name, why)
        assert dmg.field in why or dmg.kind == "missing" or dmg.field in ("status", "format"), (dmg.name, why)
    assert refused > 600 and accepted > 100


@pytest.mark.parametrize("which, file, field, value, says", [
    ("sweep", "run.json", "counts_per_rev", "abc", 'counts_per_rev: "abc" is not a number'),
    ("sweep", "steps.jsonl", "w1", 1e308, "w1: 1e+308 is outside"),
    ("sweep", "steps.jsonl", "w1", "fast", 'w1: "fast" is not a number'),
    ("sweep", "steps.jsonl", "w1", float("nan"), "w1: nan is not a finite number"),
    ("sweep", "steps.jsonl", "step", 99, "step: 99 is out of range"),
    ("energy", "steps.jsonl", "energy", "lots", 'energy: "lots" is not a number'),
    ("sweep", "run.json", "run_id", f"x/../../../../{ESCAPE}", "is not a safe run id"),
])
def test_the_issues_cases_one_line_naming_file_line_field(runs, tmp_path, which, file, field, value, says) -> None:
    d = _copy(runs, tmp_path, which)
    if file == "run.json":
        _edit_meta(d, **{field: value})
    else:
        _edit_step(d, 0, **{field: value})
    commands = (["validate-energy", str(d), "--model", MODEL] if which == "energy" else
                ["fit", str(d), "--out", str(tmp_path / "m.toml")])
    plots = tmp_path / "out" / "plots"
    for argv in (commands, ["predict", str(d), "--model", MODEL, "--plots", str(plots)]):
        code, err = run_cli(argv)
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert f"{d / file}:" in err and says in err, err
    assert not list(tmp_path.rglob(f"*{ESCAPE}*")) and not list(tmp_path.parent.glob(f"*{ESCAPE}*"))


def test_two_folders_with_one_run_id_are_refused(runs, tmp_path) -> None:
    a = _copy(runs, tmp_path / "a")
    _copy(runs, tmp_path / "b")
    code, err = run_cli(["fit", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(tmp_path / "m.toml")])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "is also the id of" in err, err
    assert not (tmp_path / "m.toml").exists() and read_run(a).run_id in err


def test_samples_with_a_word_nan_or_huge_value_name_line_and_column(runs, tmp_path) -> None:
    for k, bad in enumerate(("fast", "nan", "1e308", "inf")):
        d = _copy(runs, tmp_path / str(k))
        lines = (d / "samples.csv").read_text().splitlines()
        cells = lines[5].split(",")
        cells[12] = bad  # phi1
        lines[5] = ",".join(cells)
        (d / "samples.csv").write_text("\n".join(lines) + "\n")
        with pytest.raises(UserError, match=r"samples.csv:6: phi1: '[^']+' is not a number"):
            read_run(d)


def test_resume_validates_before_writing_anything(runs, tmp_path) -> None:
    d = _copy(runs, tmp_path)
    _edit_meta(d, status="aborted")
    (d / "steps.jsonl").write_text("garbage\n" + (d / "steps.jsonl").read_text())
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    code, err = run_cli(["sweep", "--port", SIM, "--resume", str(d)])
    assert code == 2 and f"{d / 'steps.jsonl'}:1: not a JSON line" in err, err
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before  # run.json not switched to running
    (d / "run.json").write_text("[]")
    code, err = run_cli(["sweep", "--port", SIM, "--resume", str(d)])
    assert code == 2 and "not a run description" in err and "internal" not in err
    code, err = run_cli(["campaign", "--port", SIM, "--out", str(tmp_path), "--resume"])
    assert code == 2 and len(err.strip().splitlines()) == 1 and f"{d / 'run.json'}:1: not a run description" in err


def test_resume_refuses_a_step_index_out_of_range_before_writing(runs, tmp_path) -> None:
    d = _copy(runs, tmp_path)
    _edit_meta(d, status="aborted")
    _edit_step(d, 1, step=99)
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    code, err = run_cli(["sweep", "--port", SIM, "--resume", str(d)])
    assert code == 2 and f"{d / 'steps.jsonl'}:2: step: 99 is out of range" in err, err
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before


def test_resume_of_a_run_cut_inside_the_csv_header_gives_a_run_fit_accepts(runs, tmp_path) -> None:
    """Killed before its first sample, samples.csv cut inside the header: the resumed run has a
    header and every step, and fit reads it."""
    d = _copy(runs, tmp_path)
    _edit_meta(d, status="running", steps_complete=0,
               segments=[{"segment": 0, "started": None, "ended": None, "status": "running"}])
    (d / "steps.jsonl").write_text("")
    (d / "samples.csv").write_text("segment,step,t,se")
    (d / "events.jsonl").write_text("")
    info, done = check_resumable(d, "upside_down_sweep")
    assert done == set()
    code, err = run_cli(["sweep", "--port", SIM, "--resume", str(d)], 120)
    assert code == 0, err
    assert (d / "samples.csv").read_text().startswith("segment,step,t,seq,")
    assert run_problem(d) is None and read_run(d).status == "complete"


def test_answers_distance_must_be_a_length_of_at_least_zero(tmp_path) -> None:
    from reliability.badinput import PROCEDURES

    proc = tmp_path / "forward.toml"
    proc.write_text(PROCEDURES["forward"])
    answers = tmp_path / "answers.toml"
    answers.write_text('actions = "done"\n[distance]\n0 = "-1 m"\n')
    code, err = run_cli(["forward", "--port", SIM, "--procedure", str(proc), "--out", str(tmp_path / "runs"),
                         "--answers", str(answers)])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "-1 m" in err, err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_safe_names() -> None:
    assert is_safe_name("upside_down_sweep-20261121-123456-1a2b3c4d")
    for bad in ("x/../y", "..", "a..b", "/abs", "a\\b", "", ".hidden", "-opt", "a b", "x" * 201, 5, None):
        assert not is_safe_name(bad), bad


def test_run_matrix_subset_every_case_clear_or_correct(tmp_path) -> None:
    """Refused cases of every 13th damage through all six commands, accepted ones of a few damages
    through fit, predict, validate-energy and resume: counted, and none internal, silent, unclear
    or escaped."""
    accepted = {("steps.jsonl", "label", "path trick"), ("run.json", "procedure_file", "path trick"),
                ("run.json", "port", "missing")}

    def run_accepted(dmg: Damage) -> bool:
        return (dmg.file, dmg.field, dmg.kind) in accepted

    counts, worst = run_matrix(tmp_path, select=lambda i, dmg, cmd: i % 13 == 0 or run_accepted(dmg),
                               run_accepted=run_accepted)
    assert worst == []
    t = total(counts)
    assert t["clear"] > 120 and t["correct"] >= 3
    assert all(sum(counts[c].values()) > 0 for c in COMMANDS), counts
