"""The real 2019 logs: does the loop close, and does the physics earn its keep (issue 10)?

Imports every shipped file of shared/data/omnibot-tfm, runs `diagnose` on all of them from the
robot file (omnibench/model/omnibot.toml), then measures leave-one-run-out wheel-speed NRMSE
(each run predicted by models fitted to the other runs; the floor run by models fitted to
every run in the air) of:

- the declared model with the wheel inertia refitted (a, b from the sweep, I_w from the
  traces: the README's former best),
- the diagnosed model (the same refit, plus every parameter of every effect diagnose added),
- the per-wheel black boxes (first-order lag + Coulomb offset, without and with dead time);

then leave-one-firmware-out (issue 36): every stage refitted on the logs of one 2019 sketch
predicts the logs of the other (square.ino: sweep, square_fast, square_small; ardu.ino.ino:
inputs.mat), each run replayed with its own firmware's timing; the floor run (no sketch
documented) is in no fold. It also prints the firmware timing each run was predicted with.

    .venv/bin/python benchmarks/real_data.py                  # ~10 min on 2 busy cores
    .venv/bin/python benchmarks/real_data.py --data DIR --json out.json
    .venv/bin/python benchmarks/real_data.py --before main   # also main's results, side by side

--before REF runs this script with git ref REF's omnibench too (a temporary detached worktree
on PYTHONPATH) and prints the two diagnoses (effects added, values +- SE) and leave-one-run-out
tables side by side: a speed-up must give the same answers.
"""

from __future__ import annotations

import argparse
import glob
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from at_ref import results_at  # benchmarks/at_ref.py (scripts run from this folder)

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]
DEFAULT_DATA = next((p / "shared" / "data" / "omnibot-tfm" for p in HERE.parents
                     if (p / "shared" / "data" / "omnibot-tfm").is_dir()), Path("/work/shared/data/omnibot-tfm"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder of the 2019 .mat files")
    ap.add_argument("--json", default="", help="also write the results to this JSON file")
    ap.add_argument("--before", default="", metavar="REF",
                    help="also run with git ref REF's omnibench and print both results side by side")
    args = ap.parse_args(argv)

    from omnibench.analysis.diagnosis import diagnose, loro
    from omnibench.analysis.diagnosis.loro import heldout_runs
    from omnibench.analysis.observations import Observations
    from omnibench.model import default_robot
    from omnibench.runs.tfm import import_tfm

    files = sorted(glob.glob(str(args.data / "*.mat")))
    if not files:
        print(f"{args.data}: no .mat files", file=sys.stderr)
        return 2
    say = lambda s: print(s, file=sys.stderr)  # noqa: E731
    robot = default_robot()
    with tempfile.TemporaryDirectory() as tmp:
        for f in files:
            import_tfm(f, tmp)
        obs = Observations.from_runs([tmp], robot)
        names = {rid: Path(obs.runs[rid].get("path", rid)).name for rid in obs.run_ids}
        sources = {}
        for rid in obs.run_ids:
            meta = json.loads((Path(obs.runs[rid]["path"]) / "run.json").read_text())
            sources[rid] = Path(meta["source_file"]).name
        t0 = time.time()
        d = diagnose(robot, obs, progress=lambda s: say(f"diagnose: {s}"))
        t_diag = time.time() - t0
        print(d.text())
        print(f"(diagnose: {t_diag:.0f} s)\n")
        t0 = time.time()
        held = heldout_runs(d, obs, progress=lambda s: say(f"loro: {s}"))
        name = lambda rid: sources.get(rid, names.get(rid, rid))  # noqa: E731
        for e in held.errors:
            e.run = name(e.run)
        for t in held.tradeoffs:
            t["worse"] = {name(r): v for r, v in t["worse"].items()}
            t["better"] = {name(r): v for r, v in t["better"].items()}
        held.timing = {name(r): v for r, v in held.timing.items()}
        print(held.text())
        print(f"(leave-one-run-out: {time.time() - t0:.0f} s)\n")
        print(timing_table(obs, name, held))
        lofo_json = None
        if hasattr(loro, "leave_one_firmware_out"):  # since 04deae5: --before an older ref runs without it
            t0 = time.time()
            lofo = loro.leave_one_firmware_out(d, obs, progress=lambda s: say(f"lofo: {s}"))
            for e in lofo.errors:
                e.run = name(e.run)
            lofo.sketch = {name(r): v for r, v in lofo.sketch.items()}
            lofo.trained_on = {name(r): [name(x) for x in v] for r, v in lofo.trained_on.items()}
            lofo.worse = {name(r): v for r, v in lofo.worse.items()}
            lofo.left_out = [name(r) for r in lofo.left_out]
            print()
            print(lofo.text())
            print(f"(leave-one-firmware-out: {time.time() - t0:.0f} s)")
            lofo_json = lofo.to_json()
        else:
            print("(this omnibench has no leave-one-firmware-out)")
        now = {"diagnosis": d.to_json(), "leave_one_run_out": held.to_json(),
               "leave_one_firmware_out": lofo_json, "seconds": {"diagnose": t_diag}}
        if args.json:
            Path(args.json).write_text(json.dumps(now, indent=2))
    if args.before:
        print()
        print(side_by_side(before_results(args.before, args.data), now, args.before))
    return 0


def before_results(ref: str, data: Path) -> dict[str, Any]:
    """This script's JSON results with git ref `ref`'s omnibench."""
    return results_at(ref, HERE, ["--data", str(data)])


def side_by_side(before: dict[str, Any], after: dict[str, Any], ref: str) -> str:
    """The effects added (values +- SE) and the leave-one-run-out NRMSE, before (ref) and now."""
    def added(res: dict[str, Any]) -> list[str]:
        return [f"{s['effect']}: " + ", ".join(f"{k.split('.')[-1]} = {v['value']:.4g} ± {v['se']:.2g}"
                                               for k, v in s["parameters"].items())
                for s in res["diagnosis"]["selected"]]

    lines = [f"{'':<44} {ref + ' (before)':<44} this tree (after)"]
    a0, a1 = added(before), added(after)
    for k in range(max(len(a0), len(a1))):
        lines.append(f"{'added' if k == 0 else '':<44} {(a0[k] if k < len(a0) else '-'):<44} "
                     f"{a1[k] if k < len(a1) else '-'}")
    secs = before.get("seconds", {}).get("diagnose")
    lines.append(f"{'diagnose, wall s':<44} {(f'{secs:.0f}' if secs else '?'):<44} {after['seconds']['diagnose']:.0f}")
    runs0 = {r["run"]: r for r in before["leave_one_run_out"]["runs"]}
    lines.append("leave-one-run-out NRMSE, % (stages: " + ", ".join(after["leave_one_run_out"]["stages"]) + ")")
    for r in after["leave_one_run_out"]["runs"]:
        b = runs0.get(r["run"], {}).get("nrmse", {})
        fmt = lambda d: " ".join(f"{100 * v:.2f}" for v in d.values())  # noqa: E731
        lines.append(f"  {r['run'][:42]:<42} {fmt(b):<44} {fmt(r['nrmse'])}")
    return "\n".join(lines)


def timing_table(obs, name, held) -> str:
    """The firmware timing each run was predicted with: its sketch's send order and command
    offset, or for a run of unknown firmware the sketch each stage's profiling chose."""
    lines = ["Firmware timing used per run:"]
    for rid in obs.run_ids:
        info = obs.runs[rid]
        order = "".join("FL FR RL RR".split()[w - 1][0] + "FL FR RL RR".split()[w - 1][1] + " "
                        for w in info.get("command_order") or (1, 2, 3, 4)).strip()
        off = 1000 * float(info.get("command_offset", 0.0) or 0.0)
        if info.get("sketch", "unknown") == "unknown":
            chosen = held.timing.get(name(rid), {})
            lines.append(f"  {name(rid)}: firmware unknown, profiled over the documented sketches: "
                         + ", ".join(f"{label} -> {sk}" for label, (sk, _) in chosen.items()))
        else:
            lines.append(f"  {name(rid)}: {info['sketch']} (send order {order}, commands {off:+.1f} ms from the "
                         "time stamp, 4.17 ms per packet)")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
