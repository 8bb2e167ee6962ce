"""A resume of a folder that holds no campaign is refused before any wheel turns; a mistyped
command name gets the closest command."""

from __future__ import annotations

import pytest

from omnibench.cli import main


def _run(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
        raise SystemExit(0)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


@pytest.mark.parametrize("made", [False, True])
def test_campaign_resume_of_a_folder_without_a_campaign_is_refused(made, tmp_path, capsys, monkeypatch):
    import omnibench.bench.session as session

    def no_run(*a, **k):
        raise AssertionError("a procedure ran although there was nothing to resume")

    monkeypatch.setattr(session, "run_command", no_run)
    typo = tmp_path / "campagin"
    if made:
        typo.mkdir()
        (typo / "notes.txt").write_text("not a campaign\n")
    code, out, err = _run(["campaign", "--resume", "--port", "sim://", "--out", str(typo)], capsys)
    assert code == 2, err
    assert f"nothing to resume in {typo}" in err
    assert len(err.strip().splitlines()) == 1
    assert typo.exists() == made and not (typo / "runs").exists()


def test_a_mistyped_command_gets_did_you_mean(capsys):
    code, out, err = _run(["campain"], capsys)
    assert code == 2
    assert "Did you mean 'campaign'?" in err
    code, out, err = _run(["zzzzz"], capsys)
    assert code == 2 and "Did you mean" not in err and "No such command" in err


SWEEP = __import__("pathlib").Path(__file__).parent / "procedures" / "campaign" / "upside_down_sweep.toml"


def _failed_sweep(tmp_path, capsys):
    """A sweep the motor driver stops 4 s into board time: failed, resumable, some steps done."""
    from omnibench.runs import read_run

    out = tmp_path / "runs"
    code, _, err = _run(["sweep", "--port", "sim://?seed=3&driver_fault_at=4", "--procedure", str(SWEEP),
                         "--out", str(out)], capsys)
    assert code == 3, err
    (run_dir,) = list(out.iterdir())
    run = read_run(run_dir)
    assert run.status == "failed" and 0 < len(run.steps) < 12
    return run_dir, (run_dir / "samples.csv").read_bytes(), (run_dir / "run.json").read_bytes()


@pytest.mark.parametrize("port, what", [
    ("sim://?seed=3&board_id=195887106", "board id"),           # 0x0BAD0002: another board
    ("sim://?seed=3&firmware_version=1.1.0", "firmware version"),
    ("sim://?seed=3&payload=2", "simulated world"),            # another robot's physics
])
def test_resume_on_another_board_is_refused_and_changes_nothing(port, what, tmp_path, capsys):
    run_dir, samples, meta = _failed_sweep(tmp_path, capsys)
    code, _, err = _run(["sweep", "--resume", str(run_dir), "--port", port], capsys)
    assert code == 2, err
    line, = err.strip().splitlines()
    assert f"is not the board {run_dir} was taken on ({what} " in line and "--allow-other-board" in line
    assert (run_dir / "samples.csv").read_bytes() == samples and (run_dir / "run.json").read_bytes() == meta


def test_resume_with_allow_other_board_records_a_new_segment_with_its_board(tmp_path, capsys):
    from omnibench.runs import read_run

    run_dir, _, _ = _failed_sweep(tmp_path, capsys)
    code, out, err = _run(["sweep", "--resume", str(run_dir), "--port", "sim://?seed=4&board_id=195887106",
                           "--allow-other-board"], capsys)
    assert code == 0, err
    assert "goes on on another board (board id 0B0B0001 -> 0BAD0002)" in out + err
    run = read_run(run_dir)
    first, second = run.metadata["segments"]
    assert run.status == "complete" and list(run.steps["step"]) == list(range(12))
    assert second["port"] == "sim://?seed=4&board_id=195887106"
    assert second["provenance"]["board_id"] == "0BAD0002" and second["board_changes"] == [
        "board id 0B0B0001 -> 0BAD0002"]
    assert second["rebooted"] is True  # a new board, a new boot id
    assert run.metadata["provenance"]["board_id"] == "0B0B0001"  # the first segment's board stays named
    assert run.metadata["board"]["board_id"] == "0B0B0001"
    assert [b["board_id"] for b in run.metadata["boards"]] == ["0BAD0002"]  # the boards of later segments


def test_resume_on_the_same_board_with_another_seed_or_link_faults_goes_on(tmp_path, capsys):
    """Seed, link faults and the board's reboot are not another board: the resume goes on."""
    from omnibench.runs import read_run

    run_dir, _, _ = _failed_sweep(tmp_path, capsys)
    code, out, err = _run(["sweep", "--resume", str(run_dir), "--port", "sim://?seed=5&drop=0.001"], capsys)
    assert code == 0, err
    assert "another board" not in out + err
    run = read_run(run_dir)
    assert run.status == "complete" and run.metadata["segments"][1]["board_changes"] == []


@pytest.mark.parametrize("inside_campaign", [False, True])
def test_ctrl_c_gives_one_resume_instruction_the_right_command(inside_campaign, tmp_path, capsys, monkeypatch):
    """Ctrl-C in a run names the command that continues it, with its port; inside a campaign the
    one instruction is the campaign's command (the run's own would leave the campaign unfinished)."""
    from omnibench.bench.runner import Runner

    def interrupted(self, steps):
        raise KeyboardInterrupt

    monkeypatch.setattr(Runner, "run", interrupted)
    port = "sim://?seed=8"
    if inside_campaign:
        out = tmp_path / "c"
        args = ["campaign", "--port", port, "--out", str(out), "--procedures", str(SWEEP.parent), "--analysis", "none"]
        expected = f"omnibench campaign --resume --port {port} --out {out}"
    else:
        out = tmp_path / "runs"
        args = ["sweep", "--port", port, "--procedure", str(SWEEP), "--out", str(out)]
    code, _, err = _run(args, capsys)
    assert code == 130, err
    (run_dir,) = list((out / "runs" if inside_campaign else out).iterdir())
    if not inside_campaign:
        expected = f"omnibench sweep --resume {run_dir} --port {port}"
    said = [line for line in err.splitlines() if "continue" in line]
    assert len(said) == 1 and said[0].endswith(f"continue with: {expected}"), err


@pytest.mark.parametrize("adaptive", [False, True])
def test_a_campaign_on_a_board_without_current_sensor_is_refused_before_the_first_procedure(
        adaptive, tmp_path, capsys, monkeypatch):
    import omnibench.bench.session as session

    def no_run(*a, **k):
        raise AssertionError("a procedure ran on a board that cannot measure the energy")

    monkeypatch.setattr(session, "run_command", no_run)
    out = tmp_path / "c"
    args = ["campaign", "--port", "sim://?seed=8&battery_current_sensor=false", "--out", str(out),
            "--procedures", str(SWEEP.parent)] + (["--adaptive", "--target-se", "b=10%"] if adaptive else [])
    code, _, err = _run(args, capsys)
    assert code == 2, err
    line, = err.strip().splitlines()
    assert "reports no battery current sensor and no --ammeter was given" in line
    assert "checked before the campaign's first procedure" in line
    assert not out.exists()
