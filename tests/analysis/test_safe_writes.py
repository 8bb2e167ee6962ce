"""Writes that cannot destroy: a file the tool did not write is not overwritten without --force,
outputs are renamed into place, and an unwritable output is refused before any work."""

from __future__ import annotations

import pytest

from omnibench.cli import main
from omnibench.files import MARKER, written_by_tool

from .conftest import DATA


def _run(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
        raise SystemExit(0)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


HAND_EDITED = "# my robot, tuned by hand\nname = \"mine\"\nm = 3.0  # weighed on the lab scale\n"


@pytest.mark.parametrize("name", ["myrobot.toml", "notes.txt"])
@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_a_file_the_tool_did_not_write_is_refused_naming_force(command, name, real_runs, tmp_path, capsys):
    target = tmp_path / name
    target.write_text(HAND_EDITED)
    args = ["fit", str(real_runs["results_jacked"]), "--out", str(target)]
    if command == "diagnose":
        args = ["diagnose", "--model", str(target), str(real_runs["results_jacked"]), "--out", str(target)]
    code, out, err = _run(args, capsys)
    assert code == 2, err
    assert "--force" in err and "not written by omnibench" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert target.read_text() == HAND_EDITED


def test_the_tool_overwrites_its_own_model_file_and_force_overwrites_any(real_runs, tmp_path, capsys):
    model = tmp_path / "model.toml"
    code, _, err = _run(["fit", str(real_runs["results_jacked"]), "--out", str(model), "--no-per-wheel"], capsys)
    assert code == 0, err
    assert model.read_text().startswith(MARKER) and written_by_tool(model)
    code, _, err = _run(["fit", str(real_runs["results_jacked"]), "--out", str(model), "--no-per-wheel"], capsys)
    assert code == 0, err  # its own file: rewritten without --force
    notes = tmp_path / "notes.txt"
    notes.write_text("keep?\n")
    code, _, err = _run(["fit", str(real_runs["results_jacked"]), "--out", str(notes), "--no-per-wheel",
                         "--force"], capsys)
    assert code == 0, err
    assert notes.read_text().startswith(MARKER)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]  # renamed into place


@pytest.mark.parametrize("command", ["fit", "diagnose", "fit-plots", "import"])
def test_an_unwritable_output_is_refused_before_the_work(command, real_runs, tmp_path, capsys, monkeypatch):
    afile = tmp_path / "afile"
    afile.write_text("x")
    where = afile / "sub"  # under a file: no user (not even root) can create it
    run = str(real_runs["results_jacked"])
    import omnibench.campaign.analysis_commands as ac

    def no_fit(*a, **k):
        raise AssertionError("the fit ran although its output cannot be written")

    monkeypatch.setattr(ac, "fit", no_fit)
    args = {"fit": ["fit", run, "--out", str(where / "m.toml")],
            "diagnose": ["diagnose", "--model", "omnibench/model/omnibot.toml", run, "--out", str(where / "m.toml")],
            "fit-plots": ["fit", run, "--out", str(tmp_path / "m.toml"), "--plots", str(where)],
            "import": ["import", "tfm", str(DATA / "results_jacked.mat"), "--out", str(where)]}[command]
    if command == "diagnose":
        import omnibench.campaign.diagnose_command as dc

        monkeypatch.setattr(dc, "diagnose", no_fit)
    code, out, err = _run(args, capsys)
    assert code == 2, err
    assert "cannot write there" in err and "internal error" not in err
    assert len(err.strip().splitlines()) == 1
