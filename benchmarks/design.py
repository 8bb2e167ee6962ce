"""Benchmark of the experiment design (issue 15): the adaptive campaign against the paper's
fixed grid on simulated worlds.

    nice .venv/bin/python benchmarks/design.py [--seeds 5] [--effect driver_deadband] [--no-effect-world]
    nice .venv/bin/python benchmarks/design.py --seeds 5 --no-effect-world --rounds   # each round: what ran, SE / target, SE / planned
    nice .venv/bin/python benchmarks/design.py --seeds 5 --no-effect-world --prior    # from the robot's previous campaign
    nice .venv/bin/python benchmarks/design.py --seeds 10 --no-effect-world --generator independent  # other physics
    nice .venv/bin/python benchmarks/design.py --seeds 10 --only 2,7 --no-effect-world --rounds  # two seeds, same targets

Per seed: the fixed grid (the shipped sweep, forward and lateral procedure files) is simulated
and fitted; the targets are the median over seeds of the fixed grid's own relative SEs on
a, b, c, a_r, b_r, c_r, C_r ("the same target SEs"). The adaptive loop (omnibench.campaign.adaptive,
the same code `campaign --adaptive` runs) then plans, simulates the planned procedure files
(`simcampaign.simulated_observations` with those files: the model, or with `--generator independent`
the physics written for testing only, with the simulated board's sensor noise),
fits and re-plans until the targets are met. Both are priced with the same cost model: robot
seconds of the steps (sweep holds at min_hold + max(window, average)), operator actions (flips, wheel swaps,
payload changes, tape measurements) including the return to the rest state.

Printed: per seed and world, robot time and operator actions of both, whether the targets were
met, the coverage of the adaptive campaign's final 95 % intervals (clean worlds: truth inside);
the medians and the ratios adaptive / fixed; on the world with an undeclared effect, whether
diagnose names it first from the adaptive data and from the fixed grid's data.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

TARGETS = ("a", "b", "c", "C_r", "a_r", "b_r", "c_r")
TABLE = {"upside_down_sweep": "sweep", "forward_runs": "forward", "lateral_runs": "lateral"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--effect", default="driver_deadband", help="undeclared effect of the second world")
    ap.add_argument("--no-effect-world", action="store_true", help="clean worlds only")
    ap.add_argument("--robot-second", type=float, default=3.0, help="cost of a robot second (s)")
    ap.add_argument("--diagnose", action="store_true", help="also run diagnose on the effect worlds (slow)")
    ap.add_argument("--prior", action="store_true",
                    help="start each adaptive campaign from the robot's previous one: that seed's fixed-grid fit "
                         "(its values and noise; `campaign --adaptive --prior-runs`)")
    ap.add_argument("--generator", choices=("model", "independent"), default="model",
                    help="who simulates the worlds: the fit's own simulator, or the physics written for testing "
                         "only (omnibench/worlds/independent.py: exact stick-slip, another integrator)")
    ap.add_argument("--only", default="",
                    help="run the adaptive campaign on these seeds alone (e.g. 2,7,8); the targets stay the medians "
                         "over all --seeds fixed grids")
    ap.add_argument("--rounds", action="store_true",
                    help="also print each adaptive round: what ran, robot s, SE / target after it")
    args = ap.parse_args(argv)

    import numpy as np

    from omnibench.analysis.design.files import fixed_grid_units, space_from_files
    from omnibench.analysis.design.space import Costs, sequence_actions
    from omnibench.analysis.fitting import fit
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.simcampaign import simulated_observations
    from omnibench.campaign.adaptive import adaptive_loop
    from omnibench.campaign.run import procedure_files
    from omnibench.effects import EFFECTS
    from omnibench.model import default_robot

    robot = default_robot()
    truth = robot.replace(a=0.02, b=0.45, c=0.015, a_r=2.5, b_r=0.8, c_r=0.02, C_r=0.03)
    files = procedure_files(None)
    space = space_from_files(robot, files)
    fixed = fixed_grid_units(robot, files)
    fixed_s = sum(u.reps * u.candidate.robot_seconds for u in fixed) + 2 * space.sweep_rest * len(
        {u.candidate.world for u in fixed if u.candidate.procedure == "sweep"})
    fixed_a = sum(sequence_actions([u.candidate.world for u in fixed for _ in range(u.reps)],
                                   sum(u.reps * u.candidate.measurements for u in fixed)).values())
    costs = Costs(robot_second=args.robot_second)
    seeds = list(range(args.seeds))
    worlds = [("clean", {})] + ([] if args.no_effect_world else [(args.effect, EFFECTS[args.effect].world())])

    # ---- the fixed grid and its SEs (the targets)
    fixed_fits: dict[tuple[str, int], object] = {}
    fixed_obs: dict[tuple[str, int], object] = {}
    for wname, weff in worlds:
        for seed in seeds:
            obs = simulated_observations(truth, world_effects=weff, seed=7000 + seed,
                                         procedures=["sweep", "forward", "lateral"], generator=args.generator)
            fixed_obs[(wname, seed)] = obs
            fixed_fits[(wname, seed)] = fit(robot, obs)
    rel = {p: statistics.median(fixed_fits[("clean", s)].se[p] / abs(fixed_fits[("clean", s)].values[p])
                                for s in seeds) for p in TARGETS}
    targets = {p: (rel[p], True) for p in TARGETS}
    print(f"worlds simulated by: {args.generator}")
    print(f"fixed grid: {fixed_s:.0f} s of robot time, {fixed_a} operator actions (cost model of docs/design.md)")
    print("targets (median relative SE of the fixed grid over the clean seeds): "
          + ", ".join(f"{p}={100 * v:.3g}%" for p, v in rel.items()))
    print(f"\n{'world':<16} {'seed':>4} {'robot s':>8} {'actions':>8} {'met':>4} {'rounds':>6} {'cover':>6} "
          f"{'host s':>7}  fixed: met")
    rows = []
    adaptive_seeds = [int(x) for x in args.only.split(",")] if args.only else seeds
    for wname, weff in worlds:
        for seed in adaptive_seeds:
            t0 = time.time()

            def execute(written, r, _seed=seed, _weff=weff):
                out = []
                for n, (proc, path) in enumerate(written):
                    t = TABLE[proc]
                    out.append(simulated_observations(truth, world_effects=_weff, procedures=[t], files={t: path},
                                                      seed=100000 * (_seed + 1) + 100 * r + n, run_prefix=f"r{r}-{n}",
                                                      generator=args.generator))
                return Observations.concat(out)

            with tempfile.TemporaryDirectory() as tmp:
                res = adaptive_loop(robot, targets, files, execute, Path(tmp), costs=costs, space=space,
                                    budget_seconds=4 * fixed_s, budget_actions=2 * fixed_a,
                                    prior=fixed_fits[(wname, seed)] if args.prior else None)
            f = res.fit
            cover = [f.ci95[p][0] <= getattr(truth, p) <= f.ci95[p][1] for p in TARGETS
                     if f is not None and math.isfinite(f.se.get(p, math.nan))]
            ff = fixed_fits[(wname, seed)]
            fixed_met = all(ff.se[p] <= rel[p] * abs(ff.values[p]) for p in TARGETS)
            row = {"world": wname, "seed": seed, "s": res.robot_seconds, "a": res.operator_actions, "met": res.met,
                   "rounds": len(res.rounds), "cover": cover, "host": time.time() - t0, "fixed_met": fixed_met,
                   "obs": res.obs}
            rows.append(row)
            print(f"{wname:<16} {seed:>4} {row['s']:>8.1f} {row['a']:>8} {str(res.met)[0]:>4} {row['rounds']:>6} "
                  f"{sum(cover):>3}/{len(cover):<2} {row['host']:>7.0f}  {fixed_met}", flush=True)
            if not res.met:
                print(f"    stopped: {res.stop_reason}", flush=True)
            if f is not None and not weff:  # where an interval misses: (fitted - truth) / SE, adaptive and fixed
                z = lambda fit: ", ".join(f"{p} {(fit.values[p] - getattr(truth, p)) / fit.se[p]:+.1f}"  # noqa: E731
                                          for p in TARGETS if math.isfinite(fit.se.get(p, math.nan)))
                print(f"    (fitted - truth) / SE: adaptive {z(f)}; fixed grid {z(ff)}", flush=True)
            if args.rounds:
                for rd in res.rounds:
                    tgt = {p: rel[p] * abs(f.values[p]) for p in TARGETS if f is not None}
                    hit = {p: rd.se[p] / tgt[p] for p in tgt if rd.se.get(p)}
                    vs_plan = {p: rd.se[p] / rd.block_expected_se[p] for p in hit if rd.block_expected_se.get(p)}
                    print(f"    round {rd.index}: {rd.robot_seconds:.0f} s, {sum(rd.actions.values())} actions; "
                          f"ran {', '.join(rd.ran)}", flush=True)
                    print("      fitted SE / target: " + ", ".join(f"{p} {v:.2f}" for p, v in hit.items())
                          + ("; fitted / planned SE: " + ", ".join(f"{p} {v:.2f}" for p, v in vs_plan.items())
                             if vs_plan else ""), flush=True)
    print()
    for wname, _ in worlds:
        rs = [r for r in rows if r["world"] == wname]
        med_s = statistics.median(r["s"] for r in rs)
        med_a = statistics.median(r["a"] for r in rs)
        cov = [c for r in rs for c in r["cover"]]
        print(f"{wname}: median robot time {med_s:.1f} s vs fixed {fixed_s:.1f} s (ratio adaptive/fixed "
              f"{med_s / fixed_s:.3f}); median operator actions {med_a:.0f} vs {fixed_a} (ratio {med_a / fixed_a:.2f}); "
              f"targets met {sum(r['met'] for r in rs)}/{len(rs)} (fixed grid itself: "
              f"{sum(r['fixed_met'] for r in rs)}/{len(rs)}); 95 % interval coverage {100 * np.mean(cov):.0f} % "
              f"({sum(cov)}/{len(cov)})" + (" [model lacks the world's effect: coverage not expected]"
                                            if wname != "clean" else ""))
    # ---- the same planner with the noise known in advance (each clean seed's fixed-grid fit: its values and
    # chi^2/dof per group), planning the whole campaign at once with the diagnostic floor: what the
    # adaptive loop would reach if it did not have to learn the noise first
    from omnibench.analysis.design.files import diagnostic_floor
    from omnibench.analysis.design.information import candidate_information
    from omnibench.analysis.design.planner import plan, planning_names

    floor = diagnostic_floor(robot, files, space)
    known = []
    for seed in seeds:
        ff = fixed_fits[("clean", seed)]
        info = candidate_information(ff.robot, space.candidates, planning_names(ff.robot), group_s2=ff.group_s2,
                                    group_dof=ff.group_dof)
        d = plan(ff.robot, None, targets, space, costs, required=floor, info=info)
        known.append((d.robot_seconds, d.operator_actions, all(d.met.values())))
    ks, ka = statistics.median(k[0] for k in known), statistics.median(k[1] for k in known)
    print(f"noise known in advance (one plan, no pilot): median robot time {ks:.0f} s (ratio {ks / fixed_s:.2f}), "
          f"operator actions {ka:.0f} (ratio {ka / fixed_a:.2f}); predicted to meet the targets in "
          f"{sum(k[2] for k in known)}/{len(known)}")
    if args.diagnose and not args.no_effect_world:
        from omnibench.analysis.diagnosis import diagnose

        det_a = det_f = 0
        n = 0
        false_a = false_f = n_clean = 0
        for r in rows:
            da = diagnose(robot, r["obs"])
            df = diagnose(robot, fixed_obs[(r["world"], r["seed"])])
            named = [", ".join(c.name for c in d.selected) or "nothing" for d in (da, df)]
            print(f"  {r['world']} seed {r['seed']}: diagnose adds {named[0]} from the adaptive data, "
                  f"{named[1]} from the fixed grid's", flush=True)
            if r["world"] == "clean":  # a false addition: an effect named on a world without one
                n_clean += 1
                false_a += bool(da.selected)
                false_f += bool(df.selected)
                continue
            n += 1
            det_a += bool(da.selected) and da.selected[0].name == args.effect
            det_f += bool(df.selected) and df.selected[0].name == args.effect
        print(f"diagnose names {args.effect} first: adaptive data {det_a}/{n}, fixed grid data {det_f}/{n}")
        print(f"diagnose adds an effect on a clean world: adaptive data {false_a}/{n_clean}, "
              f"fixed grid data {false_f}/{n_clean}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
