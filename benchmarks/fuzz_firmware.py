"""Fuzzing benchmark of the firmware's protocol core (firmware/fuzz/fuzz_core.c, docs/firmware.md).

Builds the libFuzzer harness (`make -C firmware fuzz`: clang, AddressSanitizer and
UndefinedBehaviorSanitizer) into a temporary folder, seeds it from the protocol vectors and runs
it for --runs inputs (or --seconds). The harness aborts on a sanitizer finding or a broken
invariant (a duty that moves without a valid SET_DUTIES, STOP, fault or watchdog; a valid frame
not acknowledged once; a board frame with a bad CRC; wheels still driven after the watchdog
timeout). Printed: inputs executed, exec/s, crashes, sanitizer findings, invariant violations,
corpus size, coverage (libFuzzer's edges `cov` and features `ft`).

    nice .venv/bin/python benchmarks/fuzz_firmware.py --runs 3000000 [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    """Build, fuzz, print the figures; exit 1 on any crash."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=3_000_000, help="inputs to execute (default 3000000)")
    ap.add_argument("--seconds", type=int, default=0, help="stop after this many seconds instead (0: --runs)")
    ap.add_argument("--seed", type=int, default=1, help="libFuzzer's random seed")
    ap.add_argument("--json", type=Path, help="write the figures here too")
    args = ap.parse_args(argv)

    from omnibench.sim.firmware.build import make, missing_tools

    miss = missing_tools("fuzz")
    if miss:
        print(f"fuzz_firmware: tools missing: {', '.join(miss)}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="omnibench-fuzz-") as tmp:
        folder = make("fuzz", Path(tmp)) / "fuzz"
        corpus = Path(tmp) / "corpus"
        corpus.mkdir()
        limit = [f"-max_total_time={args.seconds}"] if args.seconds else [f"-runs={args.runs}"]
        cmd = [str(folder / "fuzz_core"), *limit, f"-seed={args.seed}", "-print_final_stats=1",
               f"-artifact_prefix={tmp}/", str(corpus), str(folder / "seeds")]
        t0 = time.monotonic()
        r = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.monotonic() - t0
        log = r.stderr
        crashes = len(list(Path(tmp).glob("crash-*"))) + len(list(Path(tmp).glob("leak-*")))
        stat = {k: int(v) for k, v in re.findall(r"^stat::(\w+):\s+(\d+)", log, re.M)}
        last = [m for m in re.finditer(r"cov: (\d+) ft: (\d+) corp: (\d+)/", log)]
        figures = {
            "inputs": stat.get("number_of_executed_units", 0),
            "exec_per_s": stat.get("average_exec_per_sec", 0),
            "wall_s": round(wall, 1),
            "crashes": crashes,
            "sanitizer_findings": len(re.findall(r"ERROR: (AddressSanitizer|LeakSanitizer)|runtime error:", log)),
            "invariant_violations": log.count("invariant broken"),
            "corpus": len(list(corpus.iterdir())),
            "edges": int(last[-1].group(1)) if last else 0,
            "features": int(last[-1].group(2)) if last else 0,
            "exit": r.returncode,
        }
    print(f"protocol-core fuzzing (libFuzzer, ASan + UBSan): {figures['inputs']} inputs in {figures['wall_s']} s "
          f"({figures['exec_per_s']} exec/s)")
    print(f"  crashes {figures['crashes']}, sanitizer findings {figures['sanitizer_findings']}, "
          f"invariant violations {figures['invariant_violations']}")
    print(f"  corpus {figures['corpus']} inputs, coverage {figures['edges']} edges, {figures['features']} features")
    if r.returncode != 0:
        print(log[-3000:], file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1) + "\n")
    return 0 if r.returncode == 0 and crashes == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
