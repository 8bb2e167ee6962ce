"""`energy` refuses to start without a battery current source, before any motor moves."""

from __future__ import annotations

from pathlib import Path

import pytest

from omnibench.cli import main
from omnibench.runs import read_run

SMALL = Path(__file__).parent / "person_procedures" / "energy.toml"
NO_SENSOR = "sim://?battery_current_sensor=false&seed=4"


def test_energy_without_a_current_source_is_refused(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["energy", "--port", NO_SENSOR, "--procedure", str(SMALL), "--out", str(tmp_path / "runs")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no battery current sensor" in err and "--without-current" in err
    assert not (tmp_path / "runs").exists()  # refused before a run was started


def test_energy_without_current_when_told(tmp_path) -> None:
    main(["energy", "--port", NO_SENSOR, "--procedure", str(SMALL), "--out", str(tmp_path / "runs"),
          "--without-current"])  # returns normally (exit 0)
    run = read_run(next((tmp_path / "runs").iterdir()))
    assert run.status == "complete" and not run.steps["has_current"].any()
