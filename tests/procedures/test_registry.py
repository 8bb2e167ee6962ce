"""A fifth procedure is one registry entry plus its own module and TOML file (docs/architecture.md,
"Adding a procedure"): registered from outside the package, with no other edit, it is a command of
`omnibench --help`, runs a dry run through its own expander, and is in the campaign's procedure
list, the labels and the analysis's table of run procedures."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: the toy procedure's own module: forward runs under another name (its expander, as forward_runs.py)
MODULE = '''
from omnibench.procedures import forward_runs
from omnibench.procedures.plan import Plan


def expand(pf, robot):
    plan = forward_runs.expand(pf, robot)
    return Plan("toy_runs", plan.path, plan.text, plan.steps, plan.settings)
'''

#: registers the toy procedure, then runs `omnibench ARGS...` or prints the derived tables ("tables")
RUNNER = '''
import json, sys
from omnibench.procedures.registry import Procedure, register

register(Procedure("toy_runs", "toy", "V", "V toy runs", "V      toy runs (a fifth procedure).",
                   "V  Toy runs: forward runs under another name.", "toy_runs.toml", "toy_module", "forward"))
if sys.argv[1:] == ["tables"]:
    from omnibench.campaign.run import procedure_files
    from omnibench.procedures import LABELS, PROCEDURES, RUN_PROCEDURES

    print(json.dumps({"campaign": list(procedure_files(None)), "labels": LABELS, "procedures": PROCEDURES,
                      "observes": RUN_PROCEDURES}))
else:
    from omnibench.cli import main

    main(sys.argv[1:])
'''


def _run(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    (tmp_path / "toy_module.py").write_text(MODULE)
    (tmp_path / "runner.py").write_text(RUNNER)
    return subprocess.run([sys.executable, str(tmp_path / "runner.py"), *args], cwd=tmp_path, text=True,
                          capture_output=True, timeout=300, env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin",
                                                                 "NUMBA_NUM_THREADS": "1"})


def test_a_fifth_procedure_is_a_command_with_its_own_expander(tmp_path: Path) -> None:
    helped = _run(tmp_path, "--help")
    assert helped.returncode == 0, helped.stderr
    lines = helped.stdout.splitlines()
    toy = next(i for i, line in enumerate(lines) if line.split()[:1] == ["toy"])
    assert "toy runs (a fifth procedure)." in lines[toy]
    energy = next(i for i, line in enumerate(lines) if line.split()[:1] == ["energy"])
    assert toy == energy + 1  # after the paper's four, in registry order

    text = (ROOT / "procedures" / "forward_runs.toml").read_text().replace(
        'procedure = "forward_runs"', 'procedure = "toy_runs"')
    (tmp_path / "toy.toml").write_text(text)
    dry = _run(tmp_path, "toy", "--procedure", "toy.toml", "--dry-run", "--port", "sim://")
    assert dry.returncode == 0, dry.stderr
    assert "V toy runs from toy.toml: 12 steps" in dry.stdout  # its label and its expander's 3 x 2 x 2 steps

    wrong = _run(tmp_path, "forward", "--procedure", "toy.toml", "--dry-run")
    assert wrong.returncode != 0 and "this file describes toy_runs" in wrong.stderr


def test_a_fifth_procedure_is_in_every_derived_list(tmp_path: Path) -> None:
    done = _run(tmp_path, "tables")
    assert done.returncode == 0, done.stderr
    tables = json.loads(done.stdout)
    assert tables["campaign"] == ["upside_down_sweep", "forward_runs", "lateral_runs", "energy_trajectories",
                                  "toy_runs"]
    assert tables["procedures"] == tables["campaign"]
    assert tables["labels"]["toy_runs"] == "V toy runs"
    assert tables["observes"]["toy_runs"] == "forward"


def test_the_package_names_every_public_name_once() -> None:
    import omnibench.procedures as procedures

    assert sorted(procedures.__all__) == sorted(procedures._HOME)
    assert all(getattr(procedures, name) is not None for name in procedures.__all__)


def test_help_lists_the_procedures_without_loading_the_model() -> None:
    """`omnibench --help` reads the registry, which names expanders by module: the model (numba,
    numpy) is not imported for it."""
    code = ("import sys\nfrom omnibench.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in sys.modules if m in ('numpy', 'numba', 'omnibench.model', "
            "'omnibench.procedures.plan')), file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", code], text=True, capture_output=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "sweep" in done.stdout and "energy" in done.stdout
    assert done.stderr.strip() == "[]"
