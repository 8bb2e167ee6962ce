"""Reliability figures of issue 12 (printed; copy them into the README's benchmark table).

    python benchmarks/reliability.py [--sweeps 20] [--frames 200000] [--quick]

1. stale samples: real-time sweeps on `omnibench sim serve` with host stalls of 0-2 s
   injected around every command; steps whose window holds another step's samples or whose
   steady speed is off the clean run's.
2. frame integrity: accepted corrupt frames per 1e9 at 1 % byte errors, measured by fuzzing
   (directly at 32 bits; at 8 bits to check the 2^-w model) and computed.
3. byte-error rate a sweep survives (sim://, fast clock), with the steady-speed deviation.
4. watchdog stop time for a hung host (real-time pty, runner hung mid-hold).
5. bad input: clear / silent / internal / hang / overwrite (tests/reliability/badinput.py).
6. corrupted run files: every field of run.json and steps.jsonl x wrong type, NaN, inf, huge,
   negative, missing, path trick, over fit, validate-energy, predict, diagnose, resume and
   campaign (tests/reliability/runmatrix.py): clear / correct / unclear / silent / internal /
   escape / hang per command.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from reliability.test_stale_samples import check_sweep, run_sweep  # noqa: E402
from simserver import HostStalls, spawn_server  # noqa: E402

from omnibench.link.codec import Codec  # noqa: E402
from omnibench.link.fuzz import fuzz_frames, predicted_rate, spec_with_width  # noqa: E402
from omnibench.runs import read_run  # noqa: E402


def stale(tmp: Path, sweeps: int) -> None:
    srv = spawn_server(tmp, "--clock", "realtime", "--seed", "12")
    bad_steps = steps = rejected = 0
    try:
        clean = run_sweep("sim://?seed=12", tmp / "clean")
        for k in range(sweeps):
            with HostStalls(max_s=2.0, seed=100 + k) as st:
                run_dir = run_sweep(srv.path, tmp / f"stall{k}")
            bad, rej = check_sweep(run_dir, clean)
            n = len(read_run(run_dir).steps)
            bad_steps += len(bad)
            steps += n
            rejected += rej
            print(f"  sweep {k + 1}: {n} steps, stalls up to {max(st.stalls):.2f} s, {rej} queued samples "
                  f"left out, steps with another step's data: {bad or 'none'}", flush=True)
    finally:
        srv.stop()
    print(f"stale samples: {bad_steps} of {steps} steps took another step's samples over {sweeps} real-time "
          f"sweeps with 0-2 s host stalls ({rejected} queued samples correctly left out)")


def integrity(frames: int) -> None:
    p = 0.01
    r8 = fuzz_frames(frames // 4, p, width=8, seed=1)
    w8 = Codec(spec_with_width(8)).wire_size("TELEMETRY")
    ratio = r8.rate / predicted_rate(w8, p, 8)
    r32 = fuzz_frames(frames, p, seed=2)
    w32 = Codec().wire_size("TELEMETRY")
    model = predicted_rate(w32, p, 32)
    print(f"frame integrity at 1 % byte errors, TELEMETRY {w32} bytes on the wire:")
    print(f"  CRC-8 check of the model: {r8.accepted_bad} corrupt accepted of {r8.frames} frames = "
          f"{r8.rate:.2e}/frame, model bound {predicted_rate(w8, p, 8):.2e} (measured/model {ratio:.2f})")
    print(f"  CRC-32 measured: {r32.accepted_bad} corrupt accepted of {r32.frames} frames "
          f"({r32.corrupted} corrupted, {r32.accepted_good} intact accepted)")
    print(f"  CRC-32 computed: {model * 1e9:.3f} accepted corrupt frames per 1e9 frames (bound), "
          f"{model * ratio * 1e9:.3f} with the measured CRC-8 ratio")


def byte_errors(tmp: Path, rates: list[float]) -> None:
    """The default sweep (32 steps, 0.3 s averages) over sim:// with corrupted bytes both ways."""
    from omnibench.bench.session import run_command

    def sweep(url: str, out: Path):
        res = run_command("upside_down_sweep", port=url, procedure_file=None, robot_file=None, out=out,
                          echo=lambda line: None, progress=False)
        return read_run(res["run"])

    clean = sweep("sim://?seed=5", tmp / "clean")
    other = sweep("sim://?seed=6", tmp / "clean6")
    fast = clean.steps["w1"].abs() >= 1.0

    def deviation(run) -> tuple[float, float]:
        rel = max(float(((run.steps[f"w{j}"] - clean.steps[f"w{j}"]).abs() / clean.steps[f"w{j}"].abs())[fast].max())
                  for j in range(1, 5))
        ab = max(float((run.steps[f"w{j}"] - clean.steps[f"w{j}"]).abs().max()) for j in range(1, 5))
        return rel, ab

    r, a = deviation(other)
    print(f"  clean link, another seed (the noise floor): {r:.2%} on steps >= 1 rad/s, {a:.3f} rad/s on any step")
    best = 0.0
    for rate in rates:
        try:
            run = sweep(f"sim://?seed=5&corrupt={rate}", tmp / f"c{rate}")
        except Exception as exc:  # noqa: BLE001 - a benchmark reports the failure and goes on
            print(f"  {rate:.1%} corrupted bytes: sweep failed: {exc}")
            continue
        r, a = deviation(run)
        link = run.metadata["link"]
        print(f"  {rate:.1%} corrupted bytes: complete; {link['lost']} frames lost, {link['retries']} retries; "
              f"steady speeds vs the clean run: {r:.2%} on steps >= 1 rad/s, {a:.3f} rad/s on any step")
        best = rate
    print(f"highest byte-error rate a sweep survives (of {', '.join(f'{r:.0%}' for r in rates)}): {best:.0%}")


def hung_host(tmp: Path) -> None:
    import json

    import omnibench.bench.runner as runner_mod
    from omnibench.bench.session import run_command

    srv = spawn_server(tmp, "--clock", "realtime", "--seed", "7")
    released = threading.Event()
    hung_at: list[float] = []
    stopped_at: list[float] = []
    real = runner_mod.steady_state

    def hanging(t, phi, **kw):
        if not hung_at:
            hung_at.append(time.time())
            released.wait(30)
        return real(t, phi, **kw)

    def watch():
        while not hung_at:
            time.sleep(0.001)
        while not released.is_set():
            st = srv.status()
            if st["faults"]:
                stopped_at.append(st["wall_time"])
                break
            time.sleep(0.002)
        released.set()

    runner_mod.steady_state = hanging
    threading.Thread(target=watch, daemon=True).start()
    try:
        run_command("upside_down_sweep", port=srv.path, procedure_file=HERE.parent / "tests" / "reliability" /
                    "procedures" / "hung_sweep.toml", robot_file=None, out=tmp / "hung", echo=lambda line: None,
                    progress=False)
    except Exception:  # noqa: BLE001 - expected: the watchdog fault ends the run
        pass
    finally:
        runner_mod.steady_state = real
        released.set()
        srv.stop()
    (run_dir,) = (tmp / "hung").iterdir()
    meta = json.loads((run_dir / "run.json").read_text())
    wd = [e for e in meta["link"]["events"] if e[1] == "WATCHDOG"]
    print(f"hung host (watchdog 0.5 s, telemetry 240 Hz = 4.2 ms): motors stopped "
          f"{stopped_at[0] - hung_at[0]:.3f} s (host clock) after the runner hung; board reports "
          f"{wd[0][2] if wd else '?'} ms of host silence")


def bad_input() -> None:
    try:
        from reliability.badinput import run_all
    except ImportError:
        print("bad input: suite not available")
        return
    t0 = time.process_time()
    counts, worst = run_all()
    print(f"bad input: cases {sum(counts.values())}, " + ", ".join(f"{k} {v}" for k, v in counts.items())
          + f" ({time.process_time() - t0:.0f} s CPU)")
    for line in worst:
        print(f"  {line}")


def run_files(accepted_every: int = 1) -> None:
    from reliability.runmatrix import damages, run_matrix, total

    t0 = time.process_time()
    keep: set[str] = set()
    if accepted_every > 1:
        tmp = Path(tempfile.mkdtemp(prefix="omnibench-runmatrix-names-"))
        try:
            from reliability.badinput import make_fixture

            names = [d.name for d, _ in damages(make_fixture(tmp))]
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        keep = set(names[::accepted_every])
        print(f"  (cases the reader accepts run for every {accepted_every}th damage only: whole analyses)")
    counts, worst = run_matrix(progress=lambda line: print(f"  {line}", flush=True),
                               run_accepted=(lambda dmg: dmg.name in keep) if keep else (lambda dmg: True))
    for cmd, per in counts.items():
        print(f"  {cmd}: cases {sum(per.values())}, " + ", ".join(f"{k} {v}" for k, v in per.items()))
    t = total(counts)
    print(f"corrupted run files: cases {sum(t.values())}, " + ", ".join(f"{k} {v}" for k, v in t.items())
          + f" ({time.process_time() - t0:.0f} s CPU)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sweeps", type=int, default=20)
    ap.add_argument("--frames", type=int, default=200_000)
    ap.add_argument("--quick", action="store_true", help="2 sweeps, 20000 frames, accepted run files every 4th")
    ap.add_argument("--accepted-every", type=int, default=1,
                    help="run-file matrix: run the cases the reader accepts (whole analyses) for every Nth damage")
    ap.add_argument("--only", choices=["stale", "integrity", "errors", "hung", "bad", "runs"], default=None)
    a = ap.parse_args()
    if a.quick:
        a.sweeps, a.frames, a.accepted_every = 2, 20_000, max(a.accepted_every, 4)
    tmp = Path(tempfile.mkdtemp(prefix="omnibench-reliability-"))
    try:
        if a.only in (None, "integrity"):
            integrity(a.frames)
        if a.only in (None, "errors"):
            byte_errors(tmp, [0.01, 0.02, 0.03, 0.05])
        if a.only in (None, "hung"):
            hung_host(tmp)
        if a.only in (None, "bad"):
            bad_input()
        if a.only in (None, "runs"):
            run_files(a.accepted_every)
        if a.only in (None, "stale"):
            stale(tmp, a.sweeps)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
