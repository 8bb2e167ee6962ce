"""Run storage: written as it goes, readable after a crash, atomic metadata, resume segments."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from omnibench.errors import UserError
from omnibench.runs import SAMPLE_COLUMNS, RunWriter, find_runs, read_run


def _row(step: int, k: int) -> dict:
    return {"step": step, "t": 0.01 * k, "seq": k, "u1": 0.5, "u2": 0.5, "u3": 0.5, "u4": 0.5,
            "enc1": 10 * k, "enc2": 10 * k, "enc3": 10 * k, "enc4": 10 * k, "V_batt": 24.7}


def test_round_trip(tmp_path):
    w = RunWriter.create(tmp_path, "upside_down_sweep", counts_per_rev=980,
                         procedure_text="procedure = 'x'\n", board={"name": "sim"})
    for k in range(50):
        w.sample(_row(0, k))
    w.event("step_start", t=0.0, step=0, duty=0.5)
    w.operator_answer(0, "flip", "Turn the robot upside down", "done", "file")
    w.step_complete({"step": 0, "kind": "hold", "duty": 0.5, "w1": 3.2})
    w.finish("complete")
    run = read_run(w.path)
    assert run.status == "complete"
    assert run.metadata["steps_complete"] == 1
    assert run.metadata["operator_answers"][0]["answer"] == "done"
    assert list(run.samples.columns) == list(SAMPLE_COLUMNS)
    assert len(run.samples) == 50
    # phi derived from counts: 490 counts = half a revolution
    np.testing.assert_allclose(run.samples["phi1"].iloc[49], 490 * 2 * np.pi / 980)
    assert run.steps["w1"].iloc[0] == 3.2
    assert set(run.events["kind"]) >= {"step_start", "operator", "run_end"}
    assert (w.path / "procedure.toml").read_text() == "procedure = 'x'\n"
    assert find_runs(tmp_path, "upside_down_sweep") == [w.path]
    assert find_runs(tmp_path, "forward_runs") == []


def test_exception_marks_failed_and_ctrl_c_aborted(tmp_path):
    with pytest.raises(RuntimeError):
        with RunWriter.create(tmp_path, "a") as w:
            w.sample(_row(0, 1))
            raise RuntimeError("board went away")
    run = read_run(w.path)
    assert run.status == "failed" and "board went away" in run.metadata["reason"]
    assert len(run.samples) == 1
    with pytest.raises(KeyboardInterrupt):
        with RunWriter.create(tmp_path, "b") as w2:
            raise KeyboardInterrupt
    assert read_run(w2.path).status == "aborted"


def test_crash_leaves_readable_running_run(tmp_path):
    """A killed writer process leaves run.json valid ('running') and the flushed samples."""
    script = textwrap.dedent(f"""
        import os, time
        from omnibench.runs import RunWriter
        w = RunWriter.create({str(tmp_path)!r}, "crash", counts_per_rev=980)
        for k in range(2000):
            w.sample({{"step": 0, "t": k * 0.01, "seq": k, "enc1": k}})
        w.flush()
        w.sample({{"step": 0, "t": 99.0, "seq": 9999}})  # may be lost (not flushed)
        print(w.path, flush=True)
        os.kill(os.getpid(), 9)
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    path = out.stdout.strip().splitlines()[0]
    run = read_run(path)
    assert run.status == "running"
    assert len(run.samples) >= 2000
    assert run.samples["seq"].iloc[1999] == 1999


def test_partial_last_line_is_ignored_and_resume_appends_segment(tmp_path):
    w = RunWriter.create(tmp_path, "sweep", counts_per_rev=980)
    for k in range(10):
        w.sample(_row(0, k))
    w.step_complete({"step": 0, "duty": 0.1})
    w.sample(_row(1, 10))
    w.flush()
    # simulate a crash mid-line
    with open(w.path / "samples.csv", "a") as fh:
        fh.write("0,1,0.2,11,0.5")
    run = read_run(w.path)
    assert len(run.samples) == 11
    w2 = RunWriter.resume(w.path)
    w2.sample(_row(1, 0))
    w2.step_complete({"step": 1, "duty": 0.2})
    w2.finish("complete")
    run = read_run(w.path)
    assert run.status == "complete"
    assert list(run.steps["step"]) == [0, 1]
    assert list(run.steps["segment"]) == [0, 1]
    # step 1's interrupted attempt (segment 0) is kept in samples but left out of step_samples
    assert len(run.samples[run.samples["step"] == 1]) == 2
    assert list(run.step_samples(1)["segment"]) == [1]
    assert len(run.clean_samples()) == 11
    assert [s["segment"] for s in run.metadata["segments"]] == [0, 1]
    with pytest.raises(UserError):
        RunWriter.resume(w.path)  # complete runs cannot be resumed


def test_metadata_is_atomic(tmp_path):
    w = RunWriter.create(tmp_path, "x")
    for k in range(20):
        w.update(counter=k)
        json.loads((w.path / "run.json").read_text())
    assert not (w.path / "run.json.tmp").exists()
    w.finish("complete")


def test_not_a_run(tmp_path):
    with pytest.raises(UserError, match="not a run directory"):
        read_run(tmp_path)


def test_run_ids_unique_and_a_copied_run_is_refused_not_counted_twice(tmp_path):
    """Two runs started in the same second in two folders differ in id; two run folders that
    share an id (a copy) are refused with a line naming both, never counted twice (issue 38)."""
    import shutil

    from omnibench.analysis.observations import Observations
    from omnibench.runs.check import checked_runs

    paths = []
    for folder in ("a", "b"):
        w = RunWriter.create(tmp_path / folder, "step_response", counts_per_rev=980,
                             run_dir=tmp_path / folder / "step_response-20261123-061635")
        with w:
            for k in range(5):
                w.sample({**_row(0, k), "enc1": (1 if folder == "a" else -1) * 10 * k})
            w.step_complete({"step": 0, "duty": 0.5, "t_start": 0.0, "t_end": 0.04})
        paths.append(w.path)
    ids = [read_run(p).metadata["run_id"] for p in paths]
    assert ids[0] != ids[1] and all(i.startswith("step_response-20261123-061635-") for i in ids)
    obs = Observations.from_runs(paths)
    assert sorted(obs.run_ids) == sorted(ids)
    shutil.copytree(paths[0], tmp_path / "c" / paths[0].name)
    for reader in (Observations.from_runs, checked_runs):
        with pytest.raises(UserError, match=f"run_id {ids[0]} is also the id of") as exc:
            reader([paths[1], tmp_path / "c", paths[0]])
        assert "\n" not in str(exc.value)


def test_run_id_from_an_unsafe_folder_name_is_made_safe(tmp_path):
    w = RunWriter.create(tmp_path, "x", run_dir=tmp_path / "my run: 1 ..")
    w.finish("complete")
    rid = read_run(w.path).run_id
    assert "/" not in rid and " " not in rid and ".." not in rid and rid.startswith("my_run__1_")


def test_a_sample_under_no_steps_command_does_not_make_the_run_unusable(tmp_path):
    """The runner writes telemetry that queued before a step's ACK with an empty step (counted in
    the step's samples_rejected): fit must not refuse the run for it."""
    from omnibench.runs.check import run_problem

    w = RunWriter.create(tmp_path, "step_response", counts_per_rev=980, extra={"steps_planned": 1})
    w.sample({**_row(0, 0), "step": None})
    for k in range(1, 6):
        w.sample(_row(0, k))
    w.step_complete({"step": 0, "duty": 0.5, "t_start": 0.01, "t_end": 0.05, "samples_rejected": 1})
    w.finish("complete")
    assert run_problem(w.path) is None
    assert len(read_run(w.path).step_samples(0)) == 5


def test_run_info_types_the_fields_readers_use(tmp_path):
    """The typed record: what the campaign report, the importer and the analysis read from
    run.json, as RunInfo fields (no reader outside omnibench.runs parses run.json)."""
    from omnibench.runs import is_run_dir, run_dirs
    from omnibench.runs.record import read_info

    path = tmp_path / "r1"
    path.mkdir()
    doc = {"format": "omnibench-run", "format_version": 1, "procedure": "step_response", "status": "complete",
           "port": "sim://", "procedure_file": "p.toml", "robot_file": "robot.toml", "board": {"board_id": 7},
           "mode": "ground", "source": "a log", "source_sha256": "ab" * 32, "sign_map": [1, -1, 1, -1],
           "direction": "forward", "firmware_timing": {"sketch": "square"}, "duty_timing": "from_sample",
           "imported": True}
    (path / "run.json").write_text(json.dumps(doc))
    info = read_info(path)
    assert (info.port, info.procedure_file, info.robot_file, info.board) == ("sim://", "p.toml", "robot.toml",
                                                                             {"board_id": 7})
    assert (info.mode, info.source, info.source_sha256, info.direction) == ("ground", "a log", "ab" * 32, "forward")
    assert info.sign_map == [1, -1, 1, -1] and info.firmware_timing == {"sketch": "square"}
    assert info.duty_timing == "from_sample" and info.imported and info.file == path / "run.json"
    assert run_dirs(tmp_path) == [path] and is_run_dir(path) and not is_run_dir(tmp_path)
    assert run_dirs(tmp_path / "missing") == []
    doc.update(sign_map=[2, 0, 1, 1], source=3)  # not a sign map, not text: absent rather than wrong
    (path / "run.json").write_text(json.dumps(doc))
    info = read_info(path)
    assert info.sign_map is None and info.source is None


def test_step_samples_from_the_completing_segment_and_after_new_samples():
    """step_samples: the samples of the segment that completed the step (an interrupted attempt
    left out), in file order, as the boolean mask over all samples gives them; a new samples
    table is indexed again (the per-step index is built once per table)."""
    import pandas as pd

    from omnibench.runs.store import Run

    samples = pd.DataFrame({"t": [0.0, 0.1, 0.2, 0.3, 0.4, 0.5], "step": [0, 1, 1, 0, 1, 2],
                            "segment": [0, 0, 0, 1, 1, 1]})
    steps = pd.DataFrame({"step": [0, 1, 0], "segment": [0, 1, 1]})
    run = Run(path=None, metadata={}, samples=samples, events=pd.DataFrame(), steps=steps, info=None)  # type: ignore[arg-type]
    assert run.step_samples(0)["t"].tolist() == [0.3]  # the step's last row: completed in segment 1
    assert run.step_samples(1)["t"].tolist() == [0.4]
    assert run.step_samples(2)["t"].tolist() == [0.5]  # never completed: all its samples
    assert run.step_samples(7).empty and list(run.step_samples(7).columns) == ["t", "step", "segment"]
    assert run.step_samples(1).index.tolist() == [0]
    run.samples = samples.iloc[[0, 1, 2]].reset_index(drop=True)
    assert run.step_samples(1)["t"].tolist() == []  # segment 1 has no samples left
    assert run.step_samples(2).empty


def test_ctrl_c_while_samples_are_read_is_a_ctrl_c_not_a_bad_file(tmp_path, monkeypatch):
    """pandas' C reader swallows a KeyboardInterrupt raised in its read and reports a ParserError
    ("Calling read(nbytes) on source failed"); a campaign then called the run bad and went on.
    The stand-in below does what pandas does with a Ctrl-C that arrives mid-read."""
    import os
    import signal

    import pandas as pd

    from omnibench.runs import record

    w = RunWriter.create(tmp_path, "upside_down_sweep", counts_per_rev=980,
                         procedure_text="procedure = 'x'\n", board={"name": "sim"})
    for k in range(20):
        w.sample(_row(0, k))
    w.finish("complete")
    real_read_csv = pd.read_csv

    def read_csv_hit_by_ctrl_c(*args, **kwargs):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # the handler runs at the next bytecode boundary
                pass
        except KeyboardInterrupt:
            raise pd.errors.ParserError("Error tokenizing data. C error: Calling read(nbytes) on source failed.") from None
        return real_read_csv(*args, **kwargs)

    # Python's own Ctrl-C handler, as in a terminal (a suite run in the background, as CI's
    # xdist workers, inherits SIGINT ignored, and an ignored Ctrl-C is rightly held and dropped)
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        monkeypatch.setattr(record.pd, "read_csv", read_csv_hit_by_ctrl_c)
        with pytest.raises(KeyboardInterrupt):
            record.read_samples(w.path / "samples.csv")
        monkeypatch.setattr(record.pd, "read_csv", real_read_csv)
        assert len(record.read_samples(w.path / "samples.csv")) == 20  # and the handler is back as it was
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, outer)
