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
"""

from __future__ import annotations

import argparse
import glob
import json
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
DEFAULT_DATA = next((p / "shared" / "data" / "omnibot-tfm" for p in HERE.parents
                     if (p / "shared" / "data" / "omnibot-tfm").is_dir()), Path("/work/shared/data/omnibot-tfm"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder of the 2019 .mat files")
    ap.add_argument("--json", default="", help="also write the results to this JSON file")
    args = ap.parse_args(argv)

    from omnibench.analysis.diagnosis import diagnose
    from omnibench.analysis.diagnosis.loro import heldout_runs, leave_one_firmware_out
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
        t0 = time.time()
        lofo = leave_one_firmware_out(d, obs, progress=lambda s: say(f"lofo: {s}"))
        for e in lofo.errors:
            e.run = name(e.run)
        lofo.sketch = {name(r): v for r, v in lofo.sketch.items()}
        lofo.trained_on = {name(r): [name(x) for x in v] for r, v in lofo.trained_on.items()}
        lofo.worse = {name(r): v for r, v in lofo.worse.items()}
        lofo.left_out = [name(r) for r in lofo.left_out]
        print()
        print(lofo.text())
        print(f"(leave-one-firmware-out: {time.time() - t0:.0f} s)")
        if args.json:
            Path(args.json).write_text(json.dumps({"diagnosis": d.to_json(), "leave_one_run_out": held.to_json(),
                                                   "leave_one_firmware_out": lofo.to_json()}, indent=2))
    return 0


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
