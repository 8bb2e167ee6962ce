"""Benchmark of the planner's sensitivities: the CPU time of `candidate_information` over the
default design space (the shipped procedure files' candidates) at the robot file's values, the
cost every adaptive replan pays at a new fit.

    NUMBA_NUM_THREADS=1 nice .venv/bin/python benchmarks/design_sensitivity.py [--merged]

--merged also runs the old path (one simulation group per timed procedure, simulated to its
latest end) and checks that the Jacobians agree bit for bit. Measured on the 2-core machine,
NUMBA_NUM_THREADS=1, process time: 95 candidates, 172.5 s merged, 8.1 s split by end time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--merged", action="store_true", help="also time the merged groups (slow) and compare")
    args = ap.parse_args()
    import omnibench.analysis.design.information as information
    from omnibench.analysis.design.files import space_from_files
    from omnibench.analysis.design.planner import planning_names
    from omnibench.analysis.least_squares import param_scale
    from omnibench.campaign.run import procedure_files
    from omnibench.model import default_robot

    robot = default_robot()
    cands = space_from_files(robot, procedure_files(None)).candidates
    names = planning_names(robot)
    scale = np.array([param_scale(robot, p) for p in names])
    information.candidate_information(robot, cands[:1], names)  # load the kernel outside the timing
    t = time.process_time()
    split = information._simulate_sensitivity(robot, cands, names, scale, True)
    print(f"{len(cands)} candidates, {split.J.shape[0]} rows: {time.process_time() - t:.2f} CPU s (split by end time)")
    if args.merged:
        keep = information.split_by_end
        information.split_by_end = lambda pred: pred  # type: ignore[assignment]
        try:
            t = time.process_time()
            merged = information._simulate_sensitivity(robot, cands, names, scale, True)
            print(f"merged groups: {time.process_time() - t:.2f} CPU s; Jacobian bit for bit the same: "
                  f"{np.array_equal(split.J, merged.J) and np.array_equal(split.cand_of, merged.cand_of)}")
        finally:
            information.split_by_end = keep


if __name__ == "__main__":
    main()
