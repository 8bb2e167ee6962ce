"""Bad input across the commands: each case must give one clear line and a non-zero exit,
write over nothing and leave the disk as it was (issue 12). Used by test_bad_input.py and
benchmarks/reliability.py.

Outcomes: clear (non-zero exit, one line on stderr, no traceback, no "internal error"),
silent (exit 0: bad input accepted), internal ("internal error" or a traceback), hang (no
answer within HANG_S), overwrite (a file of an existing run changed).
"""

from __future__ import annotations

import hashlib
import io
import shutil
import signal
import tempfile
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

HANG_S = 20
PROC = Path(__file__).parent / "procedures" / "stall_sweep.toml"
ROOT = Path(__file__).resolve().parents[2]


class _Hang(BaseException):
    pass


def _digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def run_cli(args: list[str]) -> tuple[int | None, str]:
    """(exit code or None if it hung, stderr) of `omnibench ARGS` in this process."""
    from omnibench.cli import main

    err, out = io.StringIO(), io.StringIO()

    def alarm(signum, frame):  # noqa: ARG001
        raise _Hang()

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(HANG_S)
    code: int | None = 0
    try:
        with redirect_stderr(err), redirect_stdout(out):
            main(args)
    except SystemExit as e:
        code = int(e.code or 0) if not isinstance(e.code, str) else 1
    except _Hang:
        code = None
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    return code, err.getvalue()


def make_fixture(root: Path) -> Path:
    """A complete small sweep run under root/runs (sim://, fast clock)."""
    code, err = run_cli(["sweep", "--port", "sim://?seed=3", "--procedure", str(PROC), "--out", str(root / "runs")])
    assert code == 0, err
    (run,) = (root / "runs").iterdir()
    return run


def cases(root: Path, run: Path) -> list[tuple[str, list[str]]]:
    """(name, argv) of every bad input; files they need are written under `root`."""
    def copy(name: str, edit) -> str:
        d = root / "bad" / name
        shutil.copytree(run, d)
        edit(d)
        return str(d)

    def write(name: str, text: str | bytes) -> str:
        p = root / "files" / name
        p.parent.mkdir(parents=True, exist_ok=True)
        (p.write_bytes if isinstance(text, bytes) else p.write_text)(text)
        return str(p)

    proc_text = PROC.read_text()
    hold = 'max_hold = "2 s"'
    out = str(root / "model.toml")
    sweep = ["sweep", "--port", "sim://?seed=3", "--out", str(root / "new"), "--procedure"]
    return [
        ("fit --out the run's run.json", ["fit", str(run), "--out", str(run / "run.json")]),
        ("fit --out the run's samples.csv", ["fit", str(run), "--out", str(run / "samples.csv")]),
        ("fit --out a directory", ["fit", str(run), "--out", str(run)]),
        ("fit the same run twice", ["fit", str(run), str(run), "--out", out]),
        ("fit a run with broken run.json", ["fit", copy("json", lambda d: (d / "run.json").write_text("{ broken")),
                                            "--out", out]),
        ("fit a run with a garbage steps.jsonl line",
         ["fit", copy("steps", lambda d: (d / "steps.jsonl").write_text("{\"step\": 0}\nnot json\n" +
                                                                        (run / "steps.jsonl").read_text())), "--out", out]),
        ("fit a run with a cut samples.csv",
         ["fit", copy("cut", lambda d: (d / "samples.csv").write_text((run / "samples.csv").read_text()[:400])),
          "--out", out]),
        ("fit a run with samples.csv missing", ["fit", copy("nosamples", lambda d: (d / "samples.csv").unlink()),
                                                "--out", out]),
        ("fit an unfinished run", ["fit", copy("running", lambda d: (d / "run.json").write_text(
            (run / "run.json").read_text().replace('"status": "complete"', '"status": "running"'))), "--out", out]),
        ("fit a binary file as a run", ["fit", write("bin.dat", bytes(range(256))), "--out", out]),
        ("validate-energy without samples.csv",
         ["validate-energy", copy("ve", lambda d: (d / "samples.csv").unlink()), "--model", write("m.toml", "")]),
        ("procedure unit that computes", sweep + [write("p1.toml", proc_text.replace(hold, 'max_hold = "9**9**9 s"')),
                                                  "--dry-run"]),
        ("procedure unit with NaN", sweep + [write("p2.toml", proc_text.replace(hold, 'max_hold = "nan s"')),
                                             "--dry-run"]),
        ("procedure hold of 1e9 s", sweep + [write("p3.toml", proc_text.replace(hold, 'max_hold = "1e9 s"')),
                                             "--dry-run"]),
        ("procedure duty NaN", sweep + [write("p4.toml", proc_text.replace("[0.06, 0.1, 0.15, 0.2]", "[nan, 0.1]")),
                                        "--dry-run"]),
        ("forward with 10^7 repetitions",
         ["forward", "--port", "sim://?seed=3", "--out", str(root / "new"), "--dry-run", "--procedure",
          write("f1.toml", (ROOT / "procedures" / "forward_runs.toml").read_text().replace(
              "repetitions = ", "repetitions = 10000000 # "))]),
        ("procedure binary file", sweep + [write("p5.toml", bytes(range(256))), "--dry-run"]),
        ("sweep --out an existing file", ["sweep", "--port", "sim://?seed=3", "--procedure", str(PROC), "--out",
                                          str(run / "run.json")]),
        ("sweep --out a run directory", ["sweep", "--port", "sim://?seed=3", "--procedure", str(PROC), "--out",
                                         str(run)]),
        ("resume a complete run", ["sweep", "--port", "sim://?seed=3", "--resume", str(run)]),
        ("board monitor --duration nan", ["board", "monitor", "--port", "sim://?seed=1", "--duration", "nan"]),
        ("board monitor --duration -1", ["board", "monitor", "--port", "sim://?seed=1", "--duration", "-1"]),
        ("board monitor --every inf", ["board", "monitor", "--port", "sim://?seed=1", "--every", "inf"]),
        ("sim overcurrent_limit=nan", ["board", "info", "--port", "sim://?seed=1&overcurrent_limit=nan"]),
        ("sim unknown effect", ["board", "info", "--port", "sim://?seed=1&effects.nosuch.k=1"]),
        ("simulate --payload 1e9", ["simulate", "--commands", write("c.csv", "t,u1,u2,u3,u4\n0,0.2,0.2,0.2,0.2\n"),
                                    "--out", str(root / "sim.csv"), "--payload", "1e9"]),
        ("simulate --duration nan", ["simulate", "--commands", write("c2.csv", "t,u1,u2,u3,u4\n0,0.2,0.2,0.2,0.2\n"),
                                     "--out", str(root / "sim2.csv"), "--duration", "nan"]),
        ("simulate --out the run's samples.csv",
         ["simulate", "--commands", write("c3.csv", "t,u1,u2,u3,u4\n0,0.2,0.2,0.2,0.2\n"),
          "--out", str(run / "samples.csv")]),
    ]


def classify(code: int | None, err: str, changed: bool) -> str:
    if changed:
        return "overwrite"
    if code is None:
        return "hang"
    if "internal error" in err or "Traceback" in err:
        return "internal"
    if code == 0:
        return "silent"
    lines = [x for x in err.strip().splitlines() if x.strip()]
    return "clear" if len(lines) == 1 else "internal"


def run_all(root: Path | None = None) -> tuple[dict[str, int], list[str]]:
    """Run every case; returns counts per outcome and the lines of the cases not 'clear'."""
    own = root is None
    root = Path(tempfile.mkdtemp(prefix="omnibench-badinput-")) if own else root
    try:
        run = make_fixture(root)
        counts = {k: 0 for k in ("clear", "silent", "internal", "hang", "overwrite")}
        worst = []
        for name, argv in cases(root, run):
            before = _digest(run)
            code, err = run_cli(argv)
            outcome = classify(code, err, _digest(run) != before)
            counts[outcome] += 1
            if outcome != "clear":
                worst.append(f"{outcome}: {name}: exit {code}: {err.strip().splitlines()[-1:] or ''}")
            if _digest(run) != before:  # restore for the next case
                shutil.rmtree(run)
                run = make_fixture(root / f"again{len(worst)}")
        return counts, worst
    finally:
        if own:
            shutil.rmtree(root, ignore_errors=True)
