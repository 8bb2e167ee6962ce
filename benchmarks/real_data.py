"""The real 2019 logs: does the loop close, and does the physics earn its keep (issue 10)?

Imports every shipped file of shared/data/omnibot-tfm, runs `diagnose` on all of them from the
robot file (omnibench/model/omnibot.toml), then measures leave-one-run-out wheel-speed NRMSE
(each run predicted by models fitted to the other runs; the floor run by models fitted to
every run in the air) of:

- the declared model with the wheel inertia refitted (a, b from the sweep, I_w from the
  traces: the README's former best),
- the diagnosed model (the same refit, plus every parameter of every effect diagnose added),
- the per-wheel black boxes (first-order lag + Coulomb offset, without and with dead time).

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
        print(f"(leave-one-run-out: {time.time() - t0:.0f} s)")
        if args.json:
            Path(args.json).write_text(json.dumps({"diagnosis": d.to_json(), "leave_one_run_out": held.to_json()},
                                                  indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
