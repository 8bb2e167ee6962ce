"""Does the adaptive campaign's diagnostic floor tell a world with an undeclared effect from a clean one?

    nice .venv/bin/python benchmarks/design_floor.py --seeds 5                 # independent physics
    nice .venv/bin/python benchmarks/design_floor.py --seeds 5 --generator model

`campaign --adaptive` judges the declared model once, on the fit of its diagnostic floor (the lab's
sweep levels on the first wheel set, one level on the other, one forward pair;
docs/design.md): if the fit misses something (`FitResult.misses_something`), the rest of the
lab's own grid runs instead of a plan, so diagnose gets at least the fixed grid's data and its
detection figures cannot drop. If the floor does not flag an effect, the campaign plans on, and
diagnose gets only the planned data. This prints, for every world of benchmarks/diagnose.py whose
campaign uses the sweep, forward or lateral runs (library effects at their realistic size, the
independent physics' other forms, pairs, effects outside the library) and for clean worlds, how
many seeds the floor's fit flags, and on what.

The floor is written as procedure files (`design.files.write_procedures`) and simulated by
`simcampaign.simulated_observations` with the chosen generator; each seed draws new sensor noise.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

TABLE = {"upside_down_sweep": "sweep", "forward_runs": "forward", "lateral_runs": "lateral"}
GROUND_AND_SWEEP = {"sweep", "forward", "lateral"}
ENERGY: set[str] = set()  # worlds whose revealing campaign also has the energy runs


def _worlds(generator: str) -> list[tuple[str, dict]]:
    """(label, world effects) of diagnose's benchmark worlds that the floor's procedures can show
    (an effect whose campaign also has the energy runs is listed too: it may show only there, and
    both campaigns run the energy trajectories whole at the end)."""
    from omnibench.analysis.diagnosis.campaign import FORMS, OUT_OF_LIBRARY, PAIRS, REVEALING
    from omnibench.effects import EFFECTS

    def shows(spec) -> bool:
        return spec.step_response is None and bool(set(spec.procedures) & GROUND_AND_SWEEP)

    ENERGY.update(name for name, spec in REVEALING.items() if "energy" in spec.procedures)
    out = [("clean", {})]
    out += [(name, EFFECTS[name].world()) for name, spec in REVEALING.items() if shows(spec)]
    if generator == "independent":  # the other forms and the effects outside the library exist there only
        out += [(label, world) for label, (spec, world, _) in FORMS.items() if shows(spec)]
        out += [(label, world) for label, (spec, world) in OUT_OF_LIBRARY.items() if shows(spec)]
    out += [(label, world) for label, (spec, world) in PAIRS.items() if shows(spec)]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--generator", choices=("model", "independent"), default="independent")
    ap.add_argument("--only", default="", help="comma-separated world labels")
    args = ap.parse_args(argv)

    from omnibench.analysis.design.files import diagnostic_floor, space_from_files, write_procedures
    from omnibench.analysis.design.information import candidate_information
    from omnibench.analysis.design.planner import Unit, planning_names
    from omnibench.analysis.fitting import fit
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.simcampaign import simulated_observations
    from omnibench.campaign.run import procedure_files
    from omnibench.model import default_robot

    robot = default_robot()
    truth = robot.replace(a=0.02, b=0.45, c=0.015, a_r=2.5, b_r=0.8, c_r=0.02, C_r=0.03)
    files = procedure_files(None)
    space = space_from_files(robot, files)
    # what the campaign runs: the floor's levels the planner prices at some information (a level the
    # model predicts stuck, the lab's ±0.06, is not planned; docs/design.md)
    floor = [c for c in diagnostic_floor(robot, files, space) if c in space.candidates]
    usable = candidate_information(robot, floor, planning_names(robot)).usable
    floor = [c for c, ok in zip(floor, usable) if ok]
    only = set(filter(None, args.only.split(",")))
    worlds = [w for w in _worlds(args.generator) if not only or w[0] in only]
    print(f"worlds simulated by: {args.generator}; the floor: "
          + ", ".join(c.label for c in floor))
    missed = []
    with tempfile.TemporaryDirectory() as tmp:
        written = write_procedures([Unit(c, 1, i) for i, c in enumerate(floor)], files, Path(tmp), robot, seed=1)
        for label, world in worlds:
            flags, why = 0, {}
            for seed in range(args.seeds):
                obs = Observations.concat([
                    simulated_observations(truth, world_effects=world, procedures=[TABLE[p]], files={TABLE[p]: path},
                                           seed=1000 * seed + n + 17, run_prefix=f"floor-{n}", generator=args.generator)
                    for n, (p, path) in enumerate(written)])
                m = fit(robot, obs).misses_something()
                flags += bool(m)
                for reason in m:
                    key = reason.split(":")[0] if ":" in reason else reason.split(" ")[0]
                    why[key] = why.get(key, 0) + 1
            expect = "0" if label == "clean" else f"{args.seeds}"
            print(f"{label:<45} flagged {flags}/{args.seeds} (want {expect}/{args.seeds})"
                  + (" [also in the energy runs]" if label in ENERGY else "")
                  + (f"  on: {', '.join(f'{k} {v}' for k, v in why.items())}" if why else ""), flush=True)
            if (label == "clean") == (flags > 0) or (label != "clean" and flags < args.seeds):
                missed.append(label)
    print("every world told apart on every seed" if not missed else "not told apart on every seed: " + ", ".join(missed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
