"""Benchmark of `omnibench diagnose` on simulated campaigns (issue 6).

For every effect of the library: the world carries it at its realistic size
(omnibench/effects/library.py `example`) in the campaign that reveals it
(omnibench/analysis/diagnosis/campaign.py `REVEALING`), with a different sensor-noise seed
each time. Printed per effect: detection rate (selected first), how often the fitted value
is within 3 SE of the truth, the median held-out error ratio after/before, and wrong
first picks. Then the false-addition rate on clean worlds (no undeclared effect), over the
`CLEAN` campaigns. The library includes the command-timing effects (effects/timing.py:
command_latency, serial_command_latency, per_wheel_latency, actuator_lag), revealed by a square
wave logged every 20 ± 5 ms; the wheel inertia is offered as a core-parameter re-estimate wherever step
responses are present (a false re-estimate on a clean world counts as a false addition).

    .venv/bin/python benchmarks/diagnose.py                 # 20 seeds per effect, 20 clean worlds
    .venv/bin/python benchmarks/diagnose.py --seeds 5 --effects stribeck_friction,driver_deadband
    .venv/bin/python benchmarks/diagnose.py --json results.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

TABLE_OF = {"upside_down_sweep": "sweep", "forward_runs": "forward", "lateral_runs": "lateral",
            "energy_trajectories": "energy", "step_response": "step_response"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20, help="simulated campaigns per effect (default 20)")
    ap.add_argument("--clean", type=int, default=20, help="clean worlds (default 20)")
    ap.add_argument("--effects", default="", help="comma-separated subset of the library")
    ap.add_argument("--json", default="", help="also write the results to this JSON file")
    args = ap.parse_args(argv)

    from omnibench.analysis.diagnosis import diagnose
    from omnibench.analysis.diagnosis.campaign import CLEAN, REVEALING, campaign
    from omnibench.effects import EFFECTS
    from omnibench.model import default_robot

    robot = default_robot()
    names = [n.strip() for n in args.effects.split(",") if n.strip()] or list(EFFECTS)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        print(f"unknown effect(s): {', '.join(unknown)}; known: {', '.join(EFFECTS)}", file=sys.stderr)
        return 2
    results: dict = {"effects": {}, "clean": {}}
    print(f"{'effect':<20} {'detected':>9} {'in 3 SE':>8} {'err after/before':>17} {'s/run':>6}  wrong first picks")
    for name in names:
        eff, spec = EFFECTS[name], REVEALING[name]
        det = cover = 0
        ratios, wrong = [], {}
        t0 = time.time()
        for seed in range(args.seeds):
            d = diagnose(robot, campaign(robot, spec, eff.world(), seed=1000 + seed))
            first = d.selected[0].name if d.selected else None
            if first == name:
                det += 1
                c = d.selected[0]
                cover += all(abs(c.values[f"{name}.{p}"] - eff.example[p]) <= 3 * c.se[f"{name}.{p}"] for p in eff.fit)
            else:
                wrong[str(first)] = wrong.get(str(first), 0) + 1
            procs = [TABLE_OF[p] for p in eff.procedures if TABLE_OF[p] in d.before]
            for p in procs:
                ratios.append(d.after[p]["nrmse"] / d.before[p]["nrmse"])
        dt = (time.time() - t0) / max(args.seeds, 1)
        med = statistics.median(ratios) if ratios else float("nan")
        results["effects"][name] = {"seeds": args.seeds, "detected": det, "within_3se": cover,
                                    "median_error_ratio": med, "wrong_first": wrong}
        wrong_s = ", ".join(f"{k} x{v}" for k, v in wrong.items()) or "-"
        print(f"{name:<20} {det:>4}/{args.seeds:<4} {cover:>4}/{det:<3} {med:>17.3f} {dt:>6.1f}  {wrong_s}", flush=True)
    added = 0
    worlds_with = 0
    picks: dict[str, int] = {}
    for seed in range(args.clean):
        spec = CLEAN[seed % len(CLEAN)]
        d = diagnose(robot, campaign(robot, spec, {}, seed=5000 + seed))
        added += len(d.selected)
        worlds_with += bool(d.selected)
        for c in d.selected:
            picks[c.name] = picks.get(c.name, 0) + 1
    results["clean"] = {"worlds": args.clean, "worlds_with_addition": worlds_with, "additions": added, "picks": picks}
    rate = worlds_with / max(args.clean, 1)
    print(f"clean worlds: {worlds_with}/{args.clean} with a false addition ({100 * rate:.0f} %), "
          f"{added} addition(s){': ' + ', '.join(f'{k} x{v}' for k, v in picks.items()) if picks else ''}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(results, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
