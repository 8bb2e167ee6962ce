"""-q says nothing but errors and the run's path; -v says every operator action; log.txt keeps it all either way."""

from __future__ import annotations

from pathlib import Path

from omnibench.cli import main

FORWARD = Path(__file__).parent / "person_procedures" / "forward.toml"


def test_quiet_and_verbose(tmp_path, capsys) -> None:
    main(["-q", "forward", "--port", "sim://?seed=3", "--procedure", str(FORWARD), "--out", str(tmp_path / "q")])
    quiet = capsys.readouterr()
    main(["-v", "forward", "--port", "sim://?seed=3", "--procedure", str(FORWARD), "--out", str(tmp_path / "v")])
    loud = capsys.readouterr()
    (run_dir,) = list((tmp_path / "q").iterdir())
    assert quiet.out == f"{run_dir}\n" and quiet.err == ""  # -q: only the one line a script needs
    assert "operator: Put the robot on the ground" in loud.out and "run complete" in loud.out
    log = next((tmp_path / "q").iterdir()) / "log.txt"
    text = log.read_text()
    assert "operator: Put the robot on the ground" in text and "run complete" in text
