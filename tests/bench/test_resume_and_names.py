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
