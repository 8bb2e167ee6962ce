"""How close the noise-known plan is to the best the design space allows.

    nice .venv/bin/python benchmarks/design_bound.py --seeds 1 --restarts 60

For each seed: the fixed grid is simulated and fitted (its values and each group's chi^2/dof are
then known), the planner plans the whole campaign at once with the diagnostic floor (the
"noise known in advance" figure of benchmarks/design.py), and two checks say whether a cheaper
design exists:

- the lateral part by enumeration: with the plan's sweep and forward steps fixed, every set of
  two lateral pairs and every set of three (each candidate once) is tried; printed: the best
  two-pair set (largest SE / target), the best three-pair set of the shortest duration, and the
  cheapest three-pair set that meets every target;
- the whole plan by random restarts: the planner again with the floor plus 1-3 random lateral
  pairs (half of the restarts also a random forward pair) required; printed: the cheapest plan
  that meets the targets, against the plan's own cost;
- with --floorless N: what the diagnostic floor costs. N restarts without it, each requiring 2-5
  random sweep levels, 0-1 forward pair and 0-3 lateral pairs (the planner alone, from nothing
  required, does badly: its greedy needs a start); printed: the least robot time found.

The targets are benchmarks/design.py's (the median relative SE of the fixed grid over 5 seeds).
"""

from __future__ import annotations

import argparse
import itertools
import math
import random
import sys

TARGETS = {"a": 0.00181, "b": 0.000615, "c": 0.00284, "C_r": 0.00764, "a_r": 0.00422, "b_r": 0.00422,
           "c_r": 0.00788}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--restarts", type=int, default=60)
    ap.add_argument("--robot-second", type=float, default=3.0, help="cost of a robot second (s)")
    ap.add_argument("--floorless", type=int, default=0, help="restarts without the diagnostic floor (0: skip)")
    args = ap.parse_args(argv)

    import numpy as np

    from omnibench.analysis.design.files import diagnostic_floor, space_from_files
    from omnibench.analysis.design.information import candidate_information, prior_information
    from omnibench.analysis.design.planner import MARGIN, plan, planning_names, target_se
    from omnibench.analysis.design.space import Costs
    from omnibench.analysis.fitting import fit
    from omnibench.analysis.least_squares import param_value
    from omnibench.analysis.simcampaign import simulated_observations
    from omnibench.campaign.run import procedure_files
    from omnibench.model import default_robot

    robot = default_robot()
    truth = robot.replace(a=0.02, b=0.45, c=0.015, a_r=2.5, b_r=0.8, c_r=0.02, C_r=0.03)
    files = procedure_files(None)
    space = space_from_files(robot, files)
    floor = diagnostic_floor(robot, files, space)
    costs = Costs(robot_second=args.robot_second)
    targets = {p: (v, True) for p, v in TARGETS.items()}
    cands = space.candidates
    for seed in range(args.seeds):
        obs = simulated_observations(truth, seed=7000 + seed, procedures=["sweep", "forward", "lateral"])
        ff = fit(robot, obs)
        names = planning_names(ff.robot)
        info = candidate_information(ff.robot, cands, names, group_s2=ff.group_s2, group_dof=ff.group_dof)
        d = plan(ff.robot, None, targets, space, costs, required=floor, info=info)
        lat_s = sum(u.candidate.robot_seconds * u.reps for u in d.units if u.candidate.procedure == "lateral")
        print(f"seed {seed}: noise-known plan {d.robot_seconds:.1f} s (lateral {lat_s:.1f} s), cost {d.cost:.0f} s, "
              f"targets met: {all(d.met.values())}", flush=True)
        # ---- the lateral part by enumeration, the rest of the plan fixed
        tabs = target_se(targets, {p: param_value(ff.robot, p) for p in names})
        tidx = np.array([names.index(p) for p in TARGETS])
        t = np.array([MARGIN * tabs[p] / info.scale[names.index(p)] for p in TARGETS])
        base = prior_information(None, names, info.scale)
        for u in d.units:
            if u.candidate.procedure != "lateral":
                base = base + u.reps * info.info[cands.index(u.candidate)]
        lat = [k for k, c in enumerate(cands) if c.procedure == "lateral" and info.usable[k]]

        def worst(combo: tuple[int, ...]) -> float:
            try:
                V = np.linalg.inv(base + sum(info.info[k] for k in combo))
            except np.linalg.LinAlgError:
                return float("inf")
            v = np.diag(V)[tidx]
            return float(np.max(np.sqrt(np.maximum(v, 0)) / t) * MARGIN) if np.all(v > 0) else float("inf")

        two = min(itertools.combinations(lat, 2), key=worst)
        short = [k for k in lat if cands[k].duration == min(cands[j].duration for j in lat)]
        three_short = min(itertools.combinations(short, 3), key=worst)
        meets = [(sum(cands[k].robot_seconds for k in c), worst(c), c) for c in itertools.combinations(lat, 3)]
        meets = [m for m in meets if m[1] <= MARGIN + 1e-9]
        print(f"  {len(lat)} lateral candidates; best two pairs: SE / target up to {worst(two):.3g}; best three "
              f"{cands[short[0]].duration:g} s pairs: {worst(three_short):.2f}; cheapest three pairs that meet every "
              f"target: " + (f"{min(meets)[0]:.1f} s" if meets else "none"), flush=True)
        # ---- the whole plan by random restarts
        rng = random.Random(seed)
        fwd = [c for c in cands if c.procedure == "forward"]
        lat_c = [cands[k] for k in lat]
        best = d.cost
        for _ in range(args.restarts):
            add = rng.sample(lat_c, rng.choice([1, 2, 3])) + (rng.sample(fwd, 1) if rng.random() < 0.5 else [])
            dd = plan(ff.robot, None, targets, space, costs, required=floor + add, info=info)
            if all(dd.met.values()) and dd.cost < best - 1e-6:
                best = dd.cost
                print(f"  restart cheaper: {dd.robot_seconds:.1f} s, cost {dd.cost:.0f} s", flush=True)
        print(f"  {args.restarts} random restarts: cheapest cost {best:.0f} s against the plan's {d.cost:.0f} s", flush=True)
        if args.floorless:
            sweep = [cands[k] for k, c in enumerate(cands) if c.procedure == "sweep" and info.usable[k]]
            least = math.inf
            for _ in range(args.floorless):
                req = rng.sample(sweep, rng.randint(2, 5)) + rng.sample(fwd, rng.randint(0, 1)) + rng.sample(
                    lat_c, rng.randint(0, 3))
                dd = plan(ff.robot, None, targets, space, costs, required=req, info=info)
                if all(dd.met.values()):
                    least = min(least, dd.robot_seconds)
            print(f"  without the diagnostic floor ({args.floorless} restarts): least robot time {least:.1f} s against "
                  f"{d.robot_seconds:.1f} s with it", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
