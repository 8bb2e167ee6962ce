"""The bad-input survey (issue 12): every command, every option, the bad kinds that apply.

Cases are generated from tables (options x bad values, procedure keys x bad units, run
corruptions x commands that read runs, ...), run in this process through `omnibench.cli.main`
and classified automatically:

- clear: non-zero exit, one line on stderr starting "omnibench: error:" (or "omnibench:"), no
  traceback, no "internal error", nothing on disk changed;
- handled: exit 0 on an input that is in fact acceptable; only cases listed in ACCEPTABLE (with
  the reason) may be handled, and their outputs must hold no NaN;
- silent: exit 0 on bad input (or a NaN in what an ACCEPTABLE case wrote);
- mixed: exit 0 on a case that combines runs (or a model and runs) of different robots, boards
  or worlds (names starting "mix: ");
- internal: "internal error", a traceback, or more than one line on stderr;
- hang: no answer within HANG_S;
- overwrite: a file that existed changed or vanished, or a refused command left anything new.

Used by tests/reliability/test_bad_input.py (a subset) and benchmarks/reliability.py (all).
"""

from __future__ import annotations

import io
import os
import re
import shutil
import signal
import tempfile
import tomllib
from collections.abc import Callable
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

import tomli_w

HANG_S = 15
HERE = Path(__file__).parent
PROC = HERE / "procedures" / "stall_sweep.toml"
ROOT = Path(__file__).resolve().parents[2]
OUTCOMES = ("clear", "handled", "silent", "mixed", "internal", "hang", "overwrite")
SIM = "sim://?seed=3"
TFM = Path("/work/shared/data/omnibot-tfm")  # the real 2019 logs (read-only), for `import tfm`

# The bad values of an option, by the kind of value it takes.
FLOAT_BAD = {"nan": "nan", "inf": "inf", "-inf": "-inf", "negative": "-1", "zero": "0", "huge": "1e9",
             "empty": "", "word": "abc"}
INT_BAD = {"negative": "-1", "zero": "0", "huge": "10000000", "empty": "", "word": "abc", "fraction": "0.5"}
# Bad unit strings for a procedure key in unit U ("{u}" is replaced by a unit of the right dimension).
UNIT_BAD = {"computes": "9**9**9 {u}", "nan": "nan {u}", "inf": "inf {u}", "negative": "-1 {u}",
            "huge": "1e9 {u}", "empty": "", "wrong dimension": "1 {w}", "word": "abc"}
COUNT_BAD = {"huge": 10**7, "negative": -1, "zero": 0, "fraction": 1.5, "word": "two", "nan": float("nan")}

# Inputs that are in fact acceptable: (case name -> why exit 0 is right).
ACCEPTABLE: dict[str, str] = {
    "simulate --payload zero": "no payload is the default",
    "diagnose --seed zero": "0 is the default seed",
    "diagnose --seed negative": "any integer seeds the fold assignment",
    "diagnose --seed huge": "any integer seeds the fold assignment",
    "sim serve --seed zero": "any integer seeds the simulator",
    "forward --measurement-noise zero": "a noise-free simulated tape is allowed",
    "energy procedure trajectories.0.yaw_rate negative": "a negative yaw rate turns clockwise",
    "sim serve --world empty": "an empty world file is the default world (the board is served until stopped)",
    **{f"{c} procedure with the telemetry table missing": "[telemetry] is optional: 100 Hz, watchdog 0.5 s"
       for c in ("sweep", "forward", "lateral", "energy")},
    **{f"{c} run.json robot missing": "analysis takes the robot from --robot/--model (imported 2019 runs "
       "carry none)" for c in ("fit", "validate-energy", "predict", "diagnose", "plan")},
    **{f"{c} procedure.toml missing": "procedure.toml is a copy: run.json holds procedure_text (imported "
       "2019 runs have none)" for c in ("fit", "validate-energy", "predict", "diagnose", "plan")},
}


#: Acceptable cases that do a whole analysis (seconds of CPU): the benchmark runs them, the test not.
SLOW = {f"{c} {what} missing" for c in ("plan", "diagnose") for what in ("procedure.toml", "run.json robot")}


@dataclass
class Case:
    name: str
    argv: list[str]
    timeout: float = HANG_S
    group: str = ""  #: "one robot": the cases of one_robot_cases


class _Hang(BaseException):
    pass


def _state(root: Path) -> dict[str, tuple[int, int]]:
    """(size, mtime_ns) of every file and folder under root: a change shows any write."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for n in dirnames + filenames:
            p = os.path.join(dirpath, n)
            st = os.lstat(p)
            out[p] = (st.st_size if n in filenames else -1, st.st_mtime_ns if n in filenames else 0)
    return out


def run_cli(args: list[str], timeout: float = HANG_S) -> tuple[int | None, str]:
    """(exit code or None if it hung, stderr) of `omnibench ARGS` in this process."""
    from omnibench.cli import main

    err, out = io.StringIO(), io.StringIO()

    def alarm(signum, frame):
        raise _Hang()

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    code: int | None = 0
    try:
        with redirect_stderr(err), redirect_stdout(out):
            main(args)
    except SystemExit as e:
        code = int(e.code or 0) if not isinstance(e.code, str) else 1
    except _Hang:
        code = None
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    return code, err.getvalue()


def _energy_procedure() -> str:
    return ('procedure = "energy_trajectories"\n[run]\nrepetitions = 1\nsettle = "0.2 s"\npayload = "0 kg"\n'
            '[[trajectories]]\nname = "spin"\nkind = "spin"\nyaw_rate = "90 deg/s"\nduration = "0.5 s"\n'
            '[telemetry]\nrate = "100 Hz"\nwatchdog = "0.5 s"\n')


def _forward_procedure() -> str:
    return ('procedure = "forward_runs"\n[runs]\nduties = [0.3]\ndirections = ["forward"]\nduration = "0.5 s"\n'
            'repetitions = 1\nsettle = "0.2 s"\n[no_slip]\ntolerance = "1 cm"\nrelative_tolerance = 0.02\n'
            '[simulated_operator]\nmeasurement_noise = "2 mm"\nseed = 1\n[telemetry]\nrate = "100 Hz"\n'
            'watchdog = "0.5 s"\n')


def _lateral_procedure() -> str:
    return ('procedure = "lateral_runs"\npayloads = ["0 kg"]\n[runs]\nduration = "0.5 s"\nrepetitions = 1\n'
            'both_ways = false\nsettle = "0.2 s"\n[[directions]]\nheading = "30 deg"\nspeed = "0.3 m/s"\n'
            '[no_slip]\ntolerance = "1 cm"\nrelative_tolerance = 0.02\n[telemetry]\nrate = "100 Hz"\n'
            'watchdog = "0.5 s"\n')


PROCEDURES = {"sweep": PROC.read_text(), "forward": _forward_procedure(), "lateral": _lateral_procedure(),
              "energy": _energy_procedure()}
# Procedure keys that carry a unit: (command, path in the TOML, unit, a unit of another dimension).
UNIT_KEYS = [
    ("sweep", ("steady_state", "window"), "s", "kg"), ("sweep", ("steady_state", "min_hold"), "s", "kg"),
    ("sweep", ("steady_state", "average"), "s", "kg"), ("sweep", ("steady_state", "max_hold"), "s", "kg"),
    ("sweep", ("rest", "between_directions"), "s", "kg"), ("sweep", ("telemetry", "rate"), "Hz", "m"),
    ("sweep", ("telemetry", "watchdog"), "s", "kg"), ("sweep", ("wheel_sets", 0, "wheel_mass"), "kg", "s"),
    ("forward", ("runs", "duration"), "s", "kg"), ("forward", ("runs", "settle"), "s", "kg"),
    ("forward", ("no_slip", "tolerance"), "cm", "s"), ("forward", ("simulated_operator", "measurement_noise"), "mm", "s"),
    ("forward", ("telemetry", "rate"), "Hz", "m"), ("forward", ("telemetry", "watchdog"), "s", "kg"),
    ("lateral", ("payloads", 0), "kg", "s"), ("lateral", ("runs", "duration"), "s", "kg"),
    ("lateral", ("runs", "settle"), "s", "kg"), ("lateral", ("directions", 0, "heading"), "deg", "kg"),
    ("lateral", ("directions", 0, "speed"), "m/s", "kg"),
    ("energy", ("run", "settle"), "s", "kg"), ("energy", ("run", "payload"), "kg", "s"),
    ("energy", ("trajectories", 0, "yaw_rate"), "deg/s", "kg"), ("energy", ("trajectories", 0, "duration"), "s", "kg"),
]
COUNT_KEYS = [("forward", ("runs", "repetitions")), ("lateral", ("runs", "repetitions")),
              ("energy", ("run", "repetitions"))]
DUTY_BAD = {"nan": [float("nan")], "above one": [2.0], "huge": [1e9], "word": ["a"], "none": [], "not a list": 0.1}


def _edit_toml(text: str, path: tuple, value) -> str:
    data = tomllib.loads(text)
    node = data
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return tomli_w.dumps(data)


# Ways a run directory can be broken: name -> edit of a copy of a good run.
def _set_json(d: Path, **kv) -> None:
    import json
    doc = json.loads((d / "run.json").read_text())
    doc.update(kv)
    (d / "run.json").write_text(json.dumps(doc))


RUN_DAMAGE: dict[str, Callable[[Path], None]] = {
    "run.json broken": lambda d: (d / "run.json").write_text("{ broken"),
    "run.json empty": lambda d: (d / "run.json").write_text(""),
    "run.json a list": lambda d: (d / "run.json").write_text("[1, 2]"),
    "run.json missing": lambda d: (d / "run.json").unlink(),
    "run.json binary": lambda d: (d / "run.json").write_bytes(bytes(range(256))),
    "run.json other format": lambda d: _set_json(d, format="something-else"),
    "run.json unknown procedure": lambda d: _set_json(d, procedure="nosuch"),
    "run.json status running": lambda d: _set_json(d, status="running"),
    "run.json status aborted": lambda d: _set_json(d, status="aborted"),
    "run.json robot missing": lambda d: _set_json(d, robot=None),
    "steps.jsonl garbage line": lambda d: (d / "steps.jsonl").write_text(
        '{"step": 0}\nnot json\n' + (d / "steps.jsonl").read_text()),
    "steps.jsonl missing": lambda d: (d / "steps.jsonl").unlink(),
    "steps.jsonl empty": lambda d: (d / "steps.jsonl").write_text(""),
    "steps.jsonl a step twice": lambda d: (d / "steps.jsonl").write_text(
        (d / "steps.jsonl").read_text() + (d / "steps.jsonl").read_text().splitlines()[0] + "\n"),
    "samples.csv cut": lambda d: (d / "samples.csv").write_text((d / "samples.csv").read_text()[:400]),
    "samples.csv cut mid-line": lambda d: (d / "samples.csv").write_text(
        (d / "samples.csv").read_text()[: len((d / "samples.csv").read_text()) // 2]),
    "samples.csv missing": lambda d: (d / "samples.csv").unlink(),
    "samples.csv empty": lambda d: (d / "samples.csv").write_text(""),
    "samples.csv header only": lambda d: (d / "samples.csv").write_text(
        (d / "samples.csv").read_text().splitlines()[0] + "\n"),
    "samples.csv binary": lambda d: (d / "samples.csv").write_bytes(bytes(range(256)) * 8),
    "samples.csv nan values": lambda d: (d / "samples.csv").write_text("\n".join(
        [ln if i < 3 else ",".join(x if j < 4 else "nan" for j, x in enumerate(ln.split(",")))
         for i, ln in enumerate((d / "samples.csv").read_text().splitlines())]) + "\n"),
    "samples.csv renamed column": lambda d: (d / "samples.csv").write_text(
        (d / "samples.csv").read_text().replace("enc1", "encX", 1)),
    "events.jsonl malformed": lambda d: (d / "events.jsonl").write_text("{{{\n"),
    "procedure.toml missing": lambda d: (d / "procedure.toml").unlink(),
}


#: a small log and its map for `import csv` (square wave, wheels in the air)
CSV_LOG = "t,u,e1,e2,e3,e4\n" + "".join(
    f"{0.03 * k:.2f},{0.5 if (k // 10) % 2 == 0 else -0.5},{c},{c},{c},{c}\n"
    for k, c in enumerate([0, 5, 15, 27, 40, 53, 66, 79, 92, 105, 112, 109, 99, 87, 74, 61, 48, 35, 22, 9]))
CSV_MAP = """[run]
procedure = "step_response"
where = "air"
counts_per_rev = 980
[columns]
time = { column = "t", unit = "s" }
duty = { column = "u", unit = "1" }
encoder = { columns = ["e1", "e2", "e3", "e4"], unit = "counts" }
"""


def _files(root: Path) -> dict[str, str]:
    """Bad files, written once: name -> path."""
    f = root / "files"
    f.mkdir(parents=True, exist_ok=True)
    (f / "a directory").mkdir(exist_ok=True)
    items = {
        "binary": bytes(range(256)) * 4,
        "empty": b"",
        "bad toml": b"this is = = not toml [[\n",
        "text": b"hello\n",
    }
    out = {"missing": str(f / "no such file.toml"), "directory": str(f / "a directory")}
    for name, data in items.items():
        p = f / (name.replace(" ", "_") + ".toml")
        p.write_bytes(data)
        out[name] = str(p)
    return out


def make_fixture(root: Path) -> dict[str, Path]:
    """A complete small sweep and energy run under root/runs (sim://, fast clock)."""
    runs = root / "runs"
    code, err = run_cli(["sweep", "--port", SIM, "--procedure", str(PROC), "--out", str(runs / "sweep")], 120)
    assert code == 0, err
    ep = root / "energy.toml"
    ep.write_text(_energy_procedure())
    code, err = run_cli(["energy", "--port", SIM, "--procedure", str(ep), "--out", str(runs / "energy")], 120)
    assert code == 0, err
    (sweep,) = (runs / "sweep").iterdir()
    (energy,) = (runs / "energy").iterdir()
    return {"sweep": sweep, "energy": energy}


def controls(root: Path, runs: dict[str, Path]) -> list[Case]:
    """The cases' bases with good values: each must succeed, so a refusal in the survey is the
    bad value's, not a broken base's (cheap bases only; `cases` writes the files they use)."""
    files = root / "files"
    model = str(ROOT / "omnibench" / "model" / "omnibot.toml")
    out = [Case("control simulate", ["simulate", "--commands", str(files / "commands.csv"), "--out",
                                     str(root / "control.csv")]),
           Case("control board info", ["board", "info", "--port", "sim://?seed=1"]),
           Case("control board monitor", ["board", "monitor", "--port", "sim://?seed=1", "--duration", "0.2"]),
           Case("control fit", ["fit", str(runs["sweep"]), "--out", str(root / "control.toml")]),
           Case("control validate-energy", ["validate-energy", str(runs["energy"]), "--model", model]),
           Case("control predict", ["predict", str(runs["sweep"]), "--model", model])]
    out += [Case(f"control {c} --dry-run", [c, "--port", SIM, "--out", str(root / "new"), "--dry-run", "--procedure",
                                           str(files / f"good_{c}.toml")]) for c in PROCEDURES]
    out += [Case(f"control {c} answers", ["forward", "--port", SIM, "--out", str(root / "new"), "--procedure",
                                          str(files / "good_forward.toml"), "--answers", str(files / "answers" / a)])
            for c, a in [("forward", "good.toml")]]
    out.append(Case("control import csv", ["import", "csv", str(files / "csv_log.csv"), "--map",
                                           str(files / "csv_map.toml"), "--out", str(root / "new")]))
    if TFM.is_dir():
        out.append(Case("control import tfm", ["import", "tfm", str(TFM / "square_fast.mat"), "--out",
                                               str(root / "new")]))
    return out


def cases(root: Path, runs: dict[str, Path]) -> list[Case]:
    """Every bad input; the files they need are written under `root` (before any case runs)."""
    run, erun = runs["sweep"], runs["energy"]
    files = _files(root)
    out: list[Case] = []

    def add(name: str, argv: list[str], timeout: float = HANG_S) -> None:
        # an acceptable input may do the command's whole work (plan: ~10 s of CPU)
        out.append(Case(name, argv, 120 if name in ACCEPTABLE and not name.startswith("sim serve") else timeout))

    def write(name: str, text: str | bytes) -> str:
        p = root / "files" / name
        p.parent.mkdir(parents=True, exist_ok=True)
        (p.write_bytes if isinstance(text, bytes) else p.write_text)(text)
        return str(p)

    new = str(root / "new")
    model = str(ROOT / "omnibench" / "model" / "omnibot.toml")
    cmds_csv = write("commands.csv", "t,u1,u2,u3,u4\n0,0.2,0.2,0.2,0.2\n")
    good_proc = {k: write(f"good_{k}.toml", v) for k, v in PROCEDURES.items()}
    csv_log = write("csv_log.csv", CSV_LOG)
    csv_map = write("csv_map.toml", CSV_MAP)

    # 1. Numeric options x bad numbers (each command with its other inputs good).
    float_opts = [
        ("simulate", ["simulate", "--commands", cmds_csv, "--out", str(root / "sim.csv")],
         ["--payload", "--duration", "--rate", "--dt"]),
        ("board monitor", ["board", "monitor", "--port", "sim://?seed=1"], ["--duration", "--every"]),
        ("board info", ["board", "info", "--port", "sim://?seed=1"], ["--timeout"]),
        ("plan", ["plan", str(run), "--out", str(root / "plan"), "--target-se", "a=5%"],
         ["--robot-second", "--floor-length", "--budget-minutes"]),
        ("campaign", ["campaign", "--port", SIM, "--out", str(root / "campaign"), "--adaptive",
                      "--target-se", "a=5%"], ["--robot-second", "--floor-length", "--budget-minutes"]),
        ("diagnose", ["diagnose", str(run), "--model", model], ["--alpha"]),
        ("sweep", ["sweep", "--port", SIM, "--procedure", good_proc["sweep"], "--out", new, "--dry-run"],
         ["--measurement-noise"]),
        ("forward", ["forward", "--port", SIM, "--procedure", good_proc["forward"], "--out", new],
         ["--measurement-noise"]),
        ("sim serve", ["sim", "serve", "--clock", "fast"], ["--speed"]),
    ]
    for cmd, base, opts in float_opts:
        for opt in opts:
            for kind, v in FLOAT_BAD.items():
                if (cmd, opt, kind) == ("sweep", "--measurement-noise", "zero"):
                    continue  # acceptable (forward has the case)
                add(f"{cmd} {opt} {kind}", base + [opt, v], 5 if cmd == "sim serve" else HANG_S)
    int_opts = [
        ("board monitor", ["board", "monitor", "--port", "sim://?seed=1", "--duration", "0.2"], ["--rate"]),
        ("plan", ["plan", str(run), "--out", str(root / "plan"), "--target-se", "a=5%"], ["--budget-actions"]),
        ("campaign", ["campaign", "--port", SIM, "--out", str(root / "campaign"), "--adaptive",
                      "--target-se", "a=5%"], ["--budget-actions"]),
        ("diagnose", ["diagnose", str(run), "--model", model, "--candidates", "nosuch"], ["--max-effects", "--seed"]),
        ("sim serve", ["sim", "serve", "--clock", "fast", "--world", files["missing"]], ["--seed"]),
    ]
    for cmd, base, opts in int_opts:
        for opt in opts:
            for kind, v in INT_BAD.items():
                if opt == "--seed" and kind in ("negative", "huge", "zero"):
                    continue  # any integer seeds (the base is refused anyway: listed nowhere)
                add(f"{cmd} {opt} {kind}", base + [opt, v], 5 if cmd == "sim serve" else HANG_S)

    # 2. Lists of names or P=V pairs.
    lists = {
        "--target-se": ["a=nan", "a=-1%", "a=abc", "nosuch=1%", "a=", "=1%", "a", "a=inf", "a=0"],
        "--cost": ["flip=nan", "flip=-1", "nosuch=1", "flip=abc", "flip", "flip=inf", "flip=1e9"],
    }
    for opt, values in lists.items():
        for v in values:
            add(f"plan {opt} {v}", ["plan", str(run), "--out", str(root / "plan"), "--target-se", "a=5%", opt, v])
            add(f"campaign --adaptive {opt} {v}", ["campaign", "--port", SIM, "--out", str(root / "campaign"),
                                                    "--adaptive", "--target-se", "a=5%", opt, v])
    for v in ["nosuch", "", "a,nosuch", "stribeck_friction.nosuch"]:
        add(f"fit --free {v!r}", ["fit", str(run), "--out", str(root / "m.toml"), "--free", v])
    for v in ["nosuch", "", "sweep,nosuch"]:
        add(f"fit --procedures {v!r}", ["fit", str(run), "--out", str(root / "m.toml"), "--procedures", v])
        add(f"diagnose --procedures {v!r}", ["diagnose", str(run), "--model", model, "--procedures", v])
    for v in ["nosuch_effect", "", "stribeck_friction,nosuch"]:
        add(f"diagnose --candidates {v!r}", ["diagnose", str(run), "--model", model, "--candidates", v])
    for v in ["nosuch", "fit,nosuch", ""]:
        add(f"campaign --analysis {v!r}", ["campaign", "--port", SIM, "--out", str(root / "campaign"), "--analysis", v])
    for v in ["1,1,1", "2,1,1,1", "nan,1,1,1", "a,b,c,d", "", "1,1,1,1,1", "0,1,1,1"]:
        mat = str(TFM / "square_fast.mat") if TFM.is_dir() else files["binary"]
        add(f"import tfm --signs {v!r}", ["import", "tfm", mat, "--out", new, "--signs", v])

    # 3. Input files x bad files (each option that reads a file).
    file_opts = [
        ("fit --robot", ["fit", str(run), "--out", str(root / "m.toml"), "--robot"]),
        ("validate-energy --model", ["validate-energy", str(erun), "--model"]),
        ("predict --model", ["predict", str(run), "--model"]),
        ("diagnose --model", ["diagnose", str(run), "--model"]),
        ("plan --model", ["plan", "--out", str(root / "plan"), "--target-se", "a=5%", "--model"]),
        ("simulate --robot", ["simulate", "--commands", cmds_csv, "--out", str(root / "sim.csv"), "--robot"]),
        ("simulate --commands", ["simulate", "--out", str(root / "sim.csv"), "--commands"]),
        ("sweep --robot", ["sweep", "--port", SIM, "--procedure", good_proc["sweep"], "--out", new, "--dry-run",
                           "--robot"]),
        ("sweep --wiring", ["sweep", "--port", SIM, "--procedure", good_proc["sweep"], "--out", new, "--wiring"]),
        ("forward --answers", ["forward", "--port", SIM, "--procedure", good_proc["forward"], "--out", new,
                               "--answers"]),
        ("commission --robot", ["commission", "--port", SIM, "--out", str(root / "w.toml"), "--robot"]),
        ("campaign --robot", ["campaign", "--port", SIM, "--out", str(root / "campaign"), "--robot"]),
        ("sim serve --world", ["sim", "serve", "--clock", "fast", "--world"]),
        ("import tfm FILE", ["import", "tfm", "--out", new]),
        ("import csv FILE", ["import", "csv", "--map", csv_map, "--out", new]),
        ("import csv --map", ["import", "csv", csv_log, "--out", new, "--map"]),
        ("import csv --robot", ["import", "csv", csv_log, "--map", csv_map, "--out", new, "--robot"]),
    ]
    for cmd in ("sweep", "forward", "lateral", "energy"):
        file_opts.append((f"{cmd} --procedure", [cmd, "--port", SIM, "--out", new, "--dry-run", "--procedure"]))
    for name, base in file_opts:
        for kind, path in files.items():
            add(f"{name} {kind}", base + [path], 5 if name.startswith("sim serve") else HANG_S)
    for kind in ("missing", "binary", "directory"):
        add(f"sim serve --firmware {kind}", ["sim", "serve", "--clock", "fast", "--firmware", files[kind]], 5)
    add("campaign --procedures a file", ["campaign", "--port", SIM, "--out", str(root / "campaign"),
                                         "--procedures", files["text"]])
    add("campaign --procedures missing", ["campaign", "--port", SIM, "--out", str(root / "campaign"),
                                          "--procedures", files["missing"]])
    add("plan --procedures a file", ["plan", str(run), "--out", str(root / "plan"), "--target-se", "a=5%",
                                     "--procedures", files["text"]])
    add("plan --procedures an empty folder", ["plan", str(run), "--out", str(root / "plan"), "--target-se", "a=5%",
                                              "--procedures", files["directory"]])

    # 4. Outputs pointed at a run's own files, an existing file where a folder goes, a folder where a file goes.
    out_opts = [
        ("fit --out", ["fit", str(run), "--out"], "file"),
        ("diagnose --out", ["diagnose", str(run), "--model", model, "--out"], "file"),
        ("simulate --out", ["simulate", "--commands", cmds_csv, "--out"], "file"),
        ("commission --out", ["commission", "--port", SIM, "--out"], "file"),
        ("fit --plots", ["fit", str(run), "--out", str(root / "m.toml"), "--plots"], "dir"),
        ("predict --plots", ["predict", str(run), "--model", model, "--plots"], "dir"),
        ("plan --out", ["plan", str(run), "--target-se", "a=5%", "--out"], "dir"),
        ("sweep --out", ["sweep", "--port", SIM, "--procedure", good_proc["sweep"], "--out"], "dir"),
        ("energy --out", ["energy", "--port", SIM, "--procedure", good_proc["energy"], "--out"], "dir"),
        ("import tfm --out", ["import", "tfm", str(TFM / "square_fast.mat"), "--out"], "dir"),
        ("campaign --out", ["campaign", "--port", SIM, "--out"], "dir"),
    ]
    for name, base, want in out_opts:
        if name.startswith("import") and not TFM.is_dir():
            continue  # needs a real 2019 log to refuse for the output alone
        targets = {"the run's run.json": str(run / "run.json"), "the run's samples.csv": str(run / "samples.csv"),
                   "a run directory": str(run), "empty": ""}
        targets["an existing file" if want == "dir" else "a directory"] = (
            files["text"] if want == "dir" else files["directory"])
        for kind, target in targets.items():
            add(f"{name} {kind}", base + [target])

    # 5. Runs: every damage x every command that reads runs (and --resume).
    readers = [
        ("fit", lambda r: ["fit", r, "--out", str(root / "m.toml")], "sweep"),
        ("validate-energy", lambda r: ["validate-energy", r, "--model", model], "energy"),
        ("predict", lambda r: ["predict", r, "--model", model], "sweep"),
        ("diagnose", lambda r: ["diagnose", r, "--model", model, "--procedures", "sweep"], "sweep"),
        ("plan", lambda r: ["plan", r, "--target-se", "a=5%", "--out", str(root / "plan")], "sweep"),
        ("sweep --resume", lambda r: ["sweep", "--port", SIM, "--out", new, "--resume", r], "sweep"),
    ]
    damaged: dict[tuple[str, str], str] = {}
    for damage, edit in RUN_DAMAGE.items():
        for which in ("sweep", "energy"):
            d = root / "bad" / which / damage.replace(" ", "_")
            shutil.copytree(runs[which], d)
            edit(d)
            damaged[(which, damage)] = str(d)
    for name, argv, which in readers:
        for damage in RUN_DAMAGE:
            if name == "sweep --resume" and damage in ("run.json status running", "run.json status aborted"):
                continue  # an interrupted run: resuming it is the point
            add(f"{name} {damage}", argv(damaged[(which, damage)]))
        add(f"{name} a binary file", argv(files["binary"]))
        add(f"{name} a missing run", argv(files["missing"]))
        add(f"{name} an empty folder", argv(files["directory"]))
        add(f"{name} the same run twice", argv(str(runs[which])) + [str(runs[which])])
        if name != "sweep --resume":
            add(f"{name} --skip-bad with nothing left" if name not in ("plan",) else f"{name} a cut run",
                argv(damaged[(which, "samples.csv cut")]) + (["--skip-bad"] if name != "plan" else []))
    add("fit a run of the wrong procedure", ["fit", str(erun), "--out", str(root / "m.toml"), "--procedures", "sweep"])
    add("validate-energy a sweep run", ["validate-energy", str(run), "--model", model])
    add("energy --resume a sweep run", ["energy", "--port", SIM, "--out", new, "--resume", str(run)])
    add("sweep --resume a complete run", ["sweep", "--port", SIM, "--out", new, "--resume", str(run)])

    # 6. Procedure files: unit keys x bad unit strings, counts, duty lists, whole-file faults.
    for cmd, path, unit, wrong in UNIT_KEYS:
        for kind, tpl in UNIT_BAD.items():
            if unit == "deg" and kind == "negative":
                continue
            p = write(f"proc/{cmd}-{'.'.join(map(str, path))}-{kind}.toml",
                      _edit_toml(PROCEDURES[cmd], path, tpl.format(u=unit, w=wrong)))
            add(f"{cmd} procedure {'.'.join(map(str, path))} {kind}",
                [cmd, "--port", SIM, "--out", new, "--dry-run", "--procedure", p])
    for cmd, path in COUNT_KEYS:
        for kind, v in COUNT_BAD.items():
            p = write(f"proc/{cmd}-count-{kind}.toml", _edit_toml(PROCEDURES[cmd], path, v))
            add(f"{cmd} procedure {'.'.join(path)} {kind}", [cmd, "--port", SIM, "--out", new, "--dry-run",
                                                             "--procedure", p])
    for cmd, path in (("sweep", ("sweep", "duties")), ("forward", ("runs", "duties"))):
        for kind, v in DUTY_BAD.items():
            p = write(f"proc/{cmd}-duties-{kind}.toml", _edit_toml(PROCEDURES[cmd], path, v))
            add(f"{cmd} procedure duties {kind}", [cmd, "--port", SIM, "--out", new, "--dry-run", "--procedure", p])
    for cmd, text in PROCEDURES.items():
        other = "forward" if cmd != "forward" else "sweep"
        variants = {
            "of another procedure": PROCEDURES[other],
            "with an unknown key": text + "\nnosuch_key = 1\n",
            "without a procedure name": "\n".join(ln for ln in text.splitlines() if not ln.startswith("procedure")),
            "with the telemetry table missing": text.split("[telemetry]")[0],
            "with a duplicate key": text + '\nprocedure = "x"\n',
        }
        for kind, t in variants.items():
            add(f"{cmd} procedure {kind}", [cmd, "--port", SIM, "--out", new, "--dry-run", "--procedure",
                                            write(f"proc/{cmd}-{kind.replace(' ', '_')}.toml", t)])
    tp = write("proc/energy-kind.toml", _edit_toml(PROCEDURES["energy"], ("trajectories", 0, "kind"), "zigzag"))
    add("energy procedure unknown trajectory kind", ["energy", "--port", SIM, "--out", new, "--dry-run", "--procedure", tp])

    # 7. Answers files (forward runs: step 0 is the one run).
    answers = {
        "distance computes": 'actions = "done"\n[distance]\n0 = "9**9**9 m"\n',
        "distance nan": 'actions = "done"\n[distance]\n0 = "nan m"\n',
        "distance huge": 'actions = "done"\n[distance]\n0 = "1e9 m"\n',
        "distance wrong dimension": 'actions = "done"\n[distance]\n0 = "1 kg"\n',
        "distance a word": 'actions = "done"\n[distance]\n0 = "far"\n',
        "distance missing": 'actions = "done"\n',
        "unknown step": 'actions = "done"\n[distance]\n0 = "0.3 m"\n7 = "1 m"\n',
        "actions not done": 'actions = "maybe"\n[distance]\n0 = "0.3 m"\n',
    }
    write("answers/good.toml", 'actions = "done"\n[distance]\n0 = "0.3 m"\n')
    for kind, text in answers.items():
        add(f"forward --answers {kind}", ["forward", "--port", SIM, "--procedure", good_proc["forward"], "--out", new,
                                          "--answers", write(f"answers/{kind.replace(' ', '_')}.toml", text)])

    # 8. Simulator URLs and world files (board info opens the port; sim serve reads the world).
    url_bad = {
        "overcurrent_limit": ["nan", "-1", "inf", "abc"], "payload": ["nan", "-1", "1e9", "abc"],
        "mode": ["sideways", ""], "wheel_mass": ["1,2", "nan,1,1,1", "-1,1,1,1"], "seed": ["abc", "1.5"],
        "drop": ["2", "-0.1", "nan"], "dt": ["0", "nan", "1"], "speed": ["0", "nan", "-1"], "clock": ["slow"],
        "wiring": ["1,1,2,3", "1,2,3", "5,1,2,3"], "reset_at": ["nan", "-1"], "effects.nosuch.k": ["1"],
        "effects.stribeck_friction.b_s": ["nan", "abc"], "effects.stribeck_friction.nosuch": ["1"],
        "nosuch_key": ["1"], "robot": [files["binary"], files["missing"]], "world": [files["binary"], files["directory"]],
        "protocol": ["nosuch"], "baudrate": ["0", "abc"],
    }
    for key, values in url_bad.items():
        for v in values:
            add(f"board info sim://?{key}={v}", ["board", "info", "--port", f"sim://?seed=1&{key}={v}"])
    worlds = {
        "unknown effect": '[effects.nosuch]\nk = 1\n',
        "effect parameter nan": '[effects.stribeck_friction]\nb_s = nan\nw_s = 0.5\n',
        "effect parameter unit computes": '[effects.stribeck_friction]\nb_s = "9**9**9 N*m*s"\n',
        "payload nan": "payload = nan\n", "payload negative": "payload = -1\n", "payload huge": "payload = 1e9\n",
        "payload computes": 'payload = "9**9**9 kg"\n', "mode unknown": 'mode = "sideways"\n',
        "wheel_mass three": "wheel_mass = [1, 1, 1]\n", "faults.drop above one": "[faults]\ndrop = 2\n",
        "unknown key": "nosuch = 1\n", "sensors nan": "[sensors]\ncurrent_noise = nan\n",
        "robot missing": 'robot = "nosuch.toml"\n',
    }
    for kind, text in worlds.items():
        add(f"sim serve --world {kind}", ["sim", "serve", "--clock", "fast", "--world",
                                          write(f"worlds/{kind.replace(' ', '_')}.toml", text)], 5)
    for item in ["nokey", "=1", "payload=nan", "nosuch=1", "mode=sideways", "effects.nosuch.k=1"]:
        add(f"sim serve --set {item}", ["sim", "serve", "--clock", "fast", "--set", item], 5)
    add("sim serve --status-file a directory", ["sim", "serve", "--clock", "fast", "--status-file",
                                                files["directory"]], 5)

    # 9. Ports.
    for port in ["nosuch://x", "/dev/nonexistent-omnibench", "", "sim://?seed=abc", files["text"]]:
        add(f"board info --port {port!r}", ["board", "info", "--port", port, "--timeout", "0.5"])
        add(f"sweep --port {port!r}", ["sweep", "--port", port, "--procedure", good_proc["sweep"], "--out", new])
    add("sweep without --port", ["sweep", "--procedure", good_proc["sweep"], "--out", new])
    add("energy --ammeter bad URL", ["energy", "--port", SIM, "--procedure", good_proc["energy"], "--out", new,
                                     "--ammeter", "nosuch://x"])
    add("commission --port bad URL", ["commission", "--port", "nosuch://x", "--out", str(root / "w.toml")])

    # 10. Every command: an unknown option, a missing required value, an unknown command.
    commands = ["simulate", "ports", "board info", "board monitor", "sim serve", "commission", "sweep", "forward",
                "lateral", "energy", "campaign", "import tfm", "fit", "validate-energy", "predict", "diagnose", "plan"]
    for c in commands:
        add(f"{c} --nosuch", c.split() + ["--nosuch"], 5 if c == "sim serve" else HANG_S)
    for c, opt in [("simulate", "--commands"), ("board info", "--port"), ("board monitor", "--port"),
                   ("commission", "--port"), ("fit", "--out"), ("validate-energy", "--model"), ("predict", "--model"),
                   ("diagnose", "--model"), ("plan", "--target-se"), ("sweep", "--procedure"), ("import tfm", "--signs")]:
        add(f"{c} {opt} without its value", c.split() + [str(run), opt] if c in ("fit", "validate-energy", "predict",
                                                                                  "diagnose") else c.split() + [opt])
    add("an unknown command", ["nosuch"])
    add("board with an unknown subcommand", ["board", "nosuch"])
    add("import with an unknown format", ["import", "nosuch", files["binary"]])
    out += one_robot_cases(root, runs, write)
    return out


#: A case whose name starts so combines runs (or a model and runs) of different robots, boards or
#: worlds: exit 0 on it is "mixed", not merely silent.
MIX = "mix: "


def one_robot_cases(root: Path, runs: dict[str, Path], write: Callable[[str, str], str]) -> list[Case]:
    """Runs of one robot only, no silent overwrite, resume only what is there: the mixes (another
    world, the real 2019 logs with a simulated run, a model of another encoder), a resume on
    another board, files the tool did not write, a resume of a folder holding no campaign.
    """
    out: list[Case] = []

    def add(name: str, argv: list[str]) -> None:
        out.append(Case(name, argv, HANG_S, "one robot"))

    run, erun = str(runs["sweep"]), str(runs["energy"])
    model = ROOT / "omnibench" / "model" / "omnibot.toml"
    other = root / "other"  # the same sweep in another simulated world (2 kg on the robot)
    if not other.exists():
        code, err = run_cli(["sweep", "--port", f"{SIM}&payload=2", "--procedure", str(PROC), "--out", str(other)], 120)
        assert code == 0, err
    (other_run,) = other.iterdir()
    m2048 = write("model_2048.toml", model.read_text().replace("counts_per_rev = 980", "counts_per_rev = 2048"))
    assert "2048" in Path(m2048).read_text()
    add(f"{MIX}fit runs of two simulated worlds", ["fit", run, str(other_run), "--out", str(root / "m.toml")])
    add(f"{MIX}predict runs of two simulated worlds", ["predict", run, str(other_run), "--model", str(model)])
    add(f"{MIX}diagnose runs of two simulated worlds", ["diagnose", run, str(other_run), "--model", str(model),
                                                       "--procedures", "sweep"])
    add(f"{MIX}predict with a model of another encoder", ["predict", run, "--model", m2048])
    add(f"{MIX}validate-energy with a model of another encoder", ["validate-energy", erun, "--model", m2048])
    add(f"{MIX}diagnose with a model of another encoder", ["diagnose", run, "--model", m2048, "--procedures", "sweep"])
    if TFM.is_dir():
        tfm = root / "tfm"
        if not tfm.exists():
            code, err = run_cli(["import", "tfm", str(TFM / "square_fast.mat"), "--out", str(tfm)], 120)
            assert code == 0, err
        (tfm_run,) = tfm.iterdir()
        add(f"{MIX}fit the 2019 logs with a simulated run", ["fit", str(tfm_run), erun, "--out", str(root / "m.toml")])
        add(f"{MIX}validate-energy the 2019 logs with a simulated run",
            ["validate-energy", str(tfm_run), erun, "--model", str(model)])
    aborted = root / "aborted" / runs["sweep"].name  # an interrupted run, to resume on another board
    if not aborted.exists():
        shutil.copytree(runs["sweep"], aborted)
        _set_json(aborted, status="aborted", reason="interrupted by the operator (Ctrl-C)")
    for port, what in [(f"{SIM}&board_id=2", "another board id"), (f"{SIM}&firmware_version=2.0.0", "other firmware"),
                       (f"{SIM}&payload=2", "another world")]:
        add(f"{MIX}sweep --resume on {what}", ["sweep", "--resume", str(aborted), "--port", port])
    hand = write("myrobot.toml", "# my Omnibot, measured by hand\n" + model.read_text())
    notes = write("notes.txt", "lab notes\n")
    add("fit --out a hand-written robot file", ["fit", run, "--out", hand])
    add("fit --out a text file", ["fit", run, "--out", notes])
    add("diagnose --out a hand-written robot file", ["diagnose", run, "--model", str(model), "--procedures", "sweep",
                                                     "--out", hand])
    add("campaign --resume --out a folder without a campaign", ["campaign", "--resume", "--port", SIM, "--out",
                                                                str(root / "campagin")])
    add("campaign --resume --out a folder of notes", ["campaign", "--resume", "--port", SIM, "--out",
                                                      str(Path(notes).parent / "answers")])
    add("sweep --port an unknown sim:// setting", ["sweep", "--port", "sim://?foo=1", "--procedure", str(PROC),
                                                   "--out", str(root / "new")])
    add("campain (a mistyped command)", ["campain"])
    return out


def classify(code: int | None, err: str, changed: bool, name: str = "", wrote_nan: bool = False) -> str:
    if changed:
        return "overwrite"
    if code is None:  # only a served simulator runs until stopped, and only on acceptable input
        return "handled" if name in ACCEPTABLE and name.startswith("sim serve") else "hang"
    if "internal error" in err or "Traceback" in err:
        return "internal"
    if code == 0:
        if name.startswith(MIX):
            return "mixed"
        return "handled" if name in ACCEPTABLE and not wrote_nan else "silent"
    lines = [x for x in err.strip().splitlines() if x.strip() and not x.startswith("skipping ")]  # --skip-bad
    return "clear" if len(lines) == 1 and lines[0].startswith("omnibench:") else "internal"


def _changed(before: dict, after: dict, refused: bool) -> bool:
    """A file that existed changed or vanished; or, when refused, anything new appeared."""
    if any(after.get(p) != v for p, v in before.items()):
        return True
    return refused and any(p not in before for p in after)


#: a NaN as JSON, CSV or TOML write it (a word of its own: not the "nan" in "provenance")
NAN_WORD = re.compile(r"(?<![A-Za-z])nan(?![A-Za-z])", re.IGNORECASE)


def _nan_written(before: dict, after: dict) -> bool:
    for p in after:
        if p not in before and os.path.isfile(p) and os.path.getsize(p) < 50_000_000:
            try:
                text = Path(p).read_text(errors="replace")
            except OSError:
                continue
            if NAN_WORD.search(text):
                return True
    return False


def _swap(arg: str, pairs: list[tuple[str, str]]) -> str:
    for a, b in pairs:
        arg = arg.replace(a, b)
    return arg


def run_all(root: Path | None = None, select: Callable[[int, Case], bool] | None = None,
            progress: Callable[[str], None] | None = None) -> tuple[dict[str, int], list[str]]:
    """Run the cases (all, or those `select` keeps); counts per outcome and the lines of those not clear."""
    own = root is None
    root = Path(tempfile.mkdtemp(prefix="omnibench-badinput-")) if own else root
    cwd = os.getcwd()
    try:
        work = root / "cwd"
        work.mkdir(parents=True, exist_ok=True)
        os.chdir(work)  # default outputs (runs/, model.toml, wiring.toml) land here, watched too
        runs = make_fixture(root)
        counts = {k: 0 for k in OUTCOMES}
        worst: list[str] = []
        all_cases = cases(root, runs)
        for case in controls(root, runs):
            before = _state(root)
            code, err = run_cli(case.argv, 120)
            if code != 0:
                worst.append(f"refused: {case.name}: exit {code}: {err.strip()[-200:]}")
            for p in sorted(set(_state(root)) - set(before), key=len, reverse=True):
                (shutil.rmtree if os.path.isdir(p) and not os.path.islink(p) else os.remove)(p)
        for i, case in enumerate(all_cases):
            if select is not None and not select(i, case):
                continue
            before = _state(root)
            code, err = run_cli(case.argv, case.timeout)
            after = _state(root)
            changed = _changed(before, after, refused=code != 0)
            outcome = classify(code, err, changed, case.name, code == 0 and _nan_written(before, after))
            counts[outcome] += 1
            if outcome not in ("clear", "handled"):
                last = err.strip().splitlines()[-1:] or [""]
                worst.append(f"{outcome}: {case.name}: exit {code}: {last[0][:200]}")
                if progress:
                    progress(worst[-1])
            if changed or code == 0:  # restore: the next case starts from the same tree
                for p in sorted(set(after) - set(before), key=len, reverse=True):
                    (shutil.rmtree if os.path.isdir(p) and not os.path.islink(p) else os.remove)(p)
                if any(after.get(p) != v for p, v in before.items()):
                    old = {k: str(v) for k, v in runs.items()}
                    shutil.rmtree(root / "runs", ignore_errors=True)
                    runs = make_fixture(root)
                    swap = [(old[k], str(runs[k])) for k in runs]
                    all_cases[i + 1:] = [Case(c.name, [_swap(a, swap) for a in c.argv], c.timeout, c.group)
                                         for c in all_cases[i + 1:]]
        return counts, worst
    finally:
        os.chdir(cwd)
        if own:
            shutil.rmtree(root, ignore_errors=True)
