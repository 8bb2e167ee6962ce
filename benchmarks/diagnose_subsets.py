"""`omnibench diagnose` on every subset of the five 2019 logs: what each costs and what it finds.

Imports every .mat file of shared/data/omnibot-tfm into a temporary folder (one run folder per
log, `omnibench.runs.tfm.import_tfm`), then runs the README's command

    omnibench diagnose --model omnibench/model/omnibot.toml RUN... --json

on every subset of the chosen sizes, each as its own process (NUMBA_NUM_THREADS=--threads, 1 by
default: the CPU figure that does not depend on other work on the machine). Printed per subset:
the logs, the process's CPU (user + system) and wall seconds, the effects selected with their
values +- SE, and the held-out error per procedure before -> after (RMS held-out residual / RMS
measured, as diagnose prints it); then the largest CPU time of any subset. A subset whose
process runs out of --cpu-limit seconds of CPU is stopped (SIGXCPU) and printed "over the CPU
limit": the figure is then at least the limit.

    .venv/bin/python benchmarks/diagnose_subsets.py                        # sizes 1..5, 31 subsets
    .venv/bin/python benchmarks/diagnose_subsets.py --sizes 1,2,3,5 --jobs 2
    .venv/bin/python benchmarks/diagnose_subsets.py --only results_jacked,square_fast,square_small
    .venv/bin/python benchmarks/diagnose_subsets.py --sizes 3 --json out.json --before main

--before REF also runs the same subsets with git ref REF's omnibench (a temporary detached
worktree, this script, PYTHONPATH; benchmarks/at_ref.py) and prints both, subset by subset.
"""

from __future__ import annotations

import argparse
import glob
import itertools
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from at_ref import results_at  # benchmarks/at_ref.py (scripts run from this folder)
from at_ref import without_option as _without

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]
DEFAULT_DATA = next((p / "shared" / "data" / "omnibot-tfm" for p in HERE.parents
                     if (p / "shared" / "data" / "omnibot-tfm").is_dir()), Path("/work/shared/data/omnibot-tfm"))
MODEL = ROOT / "omnibench" / "model" / "omnibot.toml"
#: the aim: diagnose on any subset of the five logs within this much CPU
AIM_CPU = 180.0


def import_logs(data: Path, out: Path) -> dict[str, Path]:
    """Every .mat file of `data` imported into its own folder under `out`: {log name: run folder}."""
    from omnibench.runs.tfm import import_tfm

    runs = {}
    for f in sorted(glob.glob(str(data / "*.mat"))):
        name = Path(f).stem
        runs[name] = Path(import_tfm(f, out / name))
    return runs


def diagnose_once(runs: list[Path], *, threads: int, cpu_limit: float) -> dict[str, Any]:
    """One `omnibench diagnose ... --json` process on `runs`: its CPU and wall seconds, exit
    code and JSON (None when it did not finish)."""
    # this checkout's omnibench, or the one PYTHONPATH names (another ref's, with --before)
    env = {**os.environ, "NUMBA_NUM_THREADS": str(threads), "PYTHONPATH": os.environ.get("PYTHONPATH") or str(ROOT)}
    cmd = [sys.executable, "-m", "omnibench", "diagnose", "--model", str(MODEL), *map(str, runs), "--json"]

    def limit() -> None:  # in the child: SIGXCPU at the limit (the process is stopped, not left to run)
        if cpu_limit > 0:
            resource.setrlimit(resource.RLIMIT_CPU, (int(cpu_limit), int(cpu_limit) + 5))

    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, env=env, cwd=str(ROOT), preexec_fn=limit)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.monotonic() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        text, errors = out.read(), err.read()
    result = None
    if proc.returncode == 0:
        try:
            result = json.loads(text)
        except json.JSONDecodeError:
            result = None
    return {"cpu": usage.ru_utime + usage.ru_stime, "wall": wall, "returncode": proc.returncode,
            "over_limit": proc.returncode == -signal.SIGXCPU,
            "json": result, "stderr_tail": errors.strip().splitlines()[-3:]}


def summary_of(res: dict[str, Any]) -> dict[str, Any]:
    """What is printed of one diagnosis: the effects selected (values +- SE) and the held-out
    error per procedure before and after."""
    j = res.get("json")
    if not j:
        return {"selected": None, "heldout": None}
    selected = [{"effect": s["effect"], "parameters": {k: (v["value"], v["se"]) for k, v in s["parameters"].items()}}
                for s in j["selected"]]
    heldout = {p: (j["before"][p]["nrmse"], j["after"].get(p, {}).get("nrmse")) for p in j["before"]}
    return {"selected": selected, "heldout": heldout}


def show_selected(selected: list[dict[str, Any]] | None) -> str:
    if selected is None:
        return "(no result)"
    if not selected:
        return "nothing added"
    return "; ".join(s["effect"] + " (" + ", ".join(f"{k.split('.')[-1]} = {v:.4g} ± {se:.2g}"
                                                     for k, (v, se) in s["parameters"].items()) + ")"
                     for s in selected)


def show_heldout(heldout: dict[str, tuple[float, float | None]] | None) -> str:
    if not heldout:
        return ""
    return ", ".join(f"{p} {100 * a:.2f} % -> " + (f"{100 * b:.2f} %" if b is not None else "?")
                     for p, (a, b) in heldout.items())


def print_rows(rows: list[dict[str, Any]]) -> None:
    for r in rows:
        state = "" if r["returncode"] == 0 else (
            "  OVER THE CPU LIMIT" if r["over_limit"] else f"  exit {r['returncode']}: {' / '.join(r['stderr_tail'])}")
        print(f"{' + '.join(r['logs'])}")
        print(f"    CPU {r['cpu']:7.1f} s   wall {r['wall']:7.1f} s{state}")
        print(f"    selected: {show_selected(r['selected'])}")
        if r["heldout"]:
            print(f"    held-out: {show_heldout(r['heldout'])}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder of the 2019 .mat files")
    ap.add_argument("--sizes", default="1,2,3,4,5", help="subset sizes, comma-separated (default 1,2,3,4,5)")
    ap.add_argument("--only", default="", help="one subset: log names (file stems), comma-separated")
    ap.add_argument("--jobs", type=int, default=1, help="diagnoses at once (default 1)")
    ap.add_argument("--threads", type=int, default=1, help="NUMBA_NUM_THREADS of each diagnosis (default 1)")
    ap.add_argument("--cpu-limit", type=float, default=900.0,
                    help="stop a diagnosis after this many CPU seconds (default 900; 0: no limit)")
    ap.add_argument("--json", default="", help="also write the results to this JSON file")
    ap.add_argument("--before", default="", metavar="REF",
                    help="also run the same subsets with git ref REF's omnibench and print both")
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        runs = import_logs(args.data, Path(tmp))
        if not runs:
            print(f"{args.data}: no .mat files", file=sys.stderr)
            return 2
        names = list(runs)
        if args.only:
            want = [s.strip() for s in args.only.split(",") if s.strip()]
            unknown = [w for w in want if w not in runs]
            if unknown:
                print(f"unknown log(s): {', '.join(unknown)}; known: {', '.join(names)}", file=sys.stderr)
                return 2
            subsets = [tuple(want)]
        else:
            sizes = sorted({int(s) for s in args.sizes.split(",") if s.strip()})
            subsets = [c for k in sizes if 1 <= k <= len(names) for c in itertools.combinations(names, k)]
        print(f"{len(subsets)} subsets of {len(names)} logs ({', '.join(names)}); "
              f"{args.jobs} at a time, NUMBA_NUM_THREADS={args.threads}", file=sys.stderr)
        t0 = time.monotonic()

        def one(sub: tuple[str, ...]) -> dict[str, Any]:
            res = diagnose_once([runs[n] for n in sub], threads=args.threads, cpu_limit=args.cpu_limit)
            row = {"logs": list(sub), **{k: res[k] for k in ("cpu", "wall", "returncode", "over_limit", "stderr_tail")},
                   **summary_of(res)}
            # as each one ends (the table on stdout comes at the end)
            print(f"  [{time.monotonic() - t0:.0f} s] {' + '.join(sub)}: {row['cpu']:.1f} s CPU; "
                  f"{show_selected(row['selected'])}; {show_heldout(row['heldout'])}", file=sys.stderr, flush=True)
            return row

        # the largest subsets (the dearest) first, so that --jobs does not end with one left running
        order = sorted(range(len(subsets)), key=lambda k: -len(subsets[k]))
        with ThreadPoolExecutor(max(args.jobs, 1)) as ex:
            done = dict(zip(order, ex.map(one, [subsets[k] for k in order])))
        rows = [done[k] for k in range(len(subsets))]
    print_rows(rows)
    worst = max(rows, key=lambda r: r["cpu"])
    ok = all(r["returncode"] == 0 for r in rows)
    print(f"\nmaximum CPU time: {worst['cpu']:.1f} s ({' + '.join(worst['logs'])})"
          f"{'' if worst['returncode'] == 0 else ', did not finish'}; aim {AIM_CPU:.0f} s: "
          f"{'met' if ok and worst['cpu'] <= AIM_CPU else 'NOT met'}")
    print(f"total: {sum(r['cpu'] for r in rows):.0f} s CPU, {time.monotonic() - t0:.0f} s wall")
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows}, indent=2))
    if args.before:
        argv_ = [a for a in (argv if argv is not None else sys.argv[1:])]
        before = results_at(args.before, HERE, _without(_without(argv_, "--before"), "--json"))["rows"]
        print(f"\n--- the same subsets with {args.before}'s omnibench ---")
        print_rows(before)
        print()
        print(side_by_side(before, rows, args.before))
    return 0


def side_by_side(before: list[dict[str, Any]], after: list[dict[str, Any]], ref: str) -> str:
    """Per subset: CPU before (ref) and now, and whether the selection and held-out errors agree."""
    old = {tuple(r["logs"]): r for r in before}
    lines = [f"{'subset':<60} {'CPU ' + ref:>14} {'CPU now':>10}  answer"]
    for r in after:
        b = old.get(tuple(r["logs"]))
        if b is None:
            continue
        same = b["selected"] == r["selected"] and b["heldout"] == r["heldout"]
        verdict = "same" if same else ("before did not finish" if b["returncode"] != 0 else "DIFFERENT")
        lines.append(f"{' + '.join(r['logs'])[:60]:<60} {b['cpu']:>13.1f}{'+' if b['over_limit'] else ' '} "
                     f"{r['cpu']:>9.1f}   {verdict}")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
