"""Does a lateral pair whose wheels turn slowly move the wheel friction on other physics?

    nice .venv/bin/python benchmarks/slow_wheels.py [--draws 3]

A lateral run at 60 deg turns two wheels at 0.26 rad/s (4 kg on top), 26 x the ground wheel
sign's width. The campaign: the shipped sweep and forward files plus three lateral pairs
(30 deg 0 kg, 30 deg 4 kg, 90 deg 4 kg, 3 s), simulated by the independent physics
(omnibench/worlds/independent.py: its own integrator, a sign 10 x narrower), fitted without and
with a 60 deg 4 kg pair of 4.5 s. Printed per noise draw: (fitted - truth) / SE of each target.
With the algebraic wheel sign x / sqrt(x^2 + eps^2) the pair moved b by +3 to +5 SE (0.075 % of
dry friction missing at 26 eps); with tanh it should not move anything beyond the noise.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

LATERAL = """procedure = "lateral_runs"
description = "one heading both ways"
payloads = ["{payload} kg"]

[runs]
duration = "{duration} s"
repetitions = 1
both_ways = true
settle = "1 s"

[[directions]]
heading = "{heading} deg"
speed = "0.3 m/s"
"""
PAIRS = {"l30_0": (30, 0, 3), "l30_4": (30, 4, 3), "l90_4": (90, 4, 3), "l60_4": (60, 4, 4.5)}
TARGETS = ("a", "b", "c", "C_r", "a_r", "b_r", "c_r")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--draws", type=int, default=3)
    args = ap.parse_args(argv)

    from omnibench.analysis.fitting import fit
    from omnibench.analysis.observations import Observations
    from omnibench.analysis.simcampaign import simulated_observations
    from omnibench.model import default_robot

    robot = default_robot()
    truth = robot.replace(a=0.02, b=0.45, c=0.015, a_r=2.5, b_r=0.8, c_r=0.02, C_r=0.03)
    with tempfile.TemporaryDirectory() as tmp:
        files = {}
        for name, (heading, payload, duration) in PAIRS.items():
            files[name] = Path(tmp) / f"{name}.toml"
            files[name].write_text(LATERAL.format(heading=heading, payload=payload, duration=duration))

        def lateral(name: str, seed: int) -> Observations:
            return simulated_observations(truth, procedures=["lateral"], files={"lateral": files[name]}, seed=seed,
                                          run_prefix=name, generator="independent")

        print("(fitted - truth) / SE on the independent physics")
        for draw in range(args.draws):
            base = [simulated_observations(truth, procedures=["sweep", "forward"], seed=500 + draw,
                                           generator="independent")]
            base += [lateral(n, 600 + 10 * draw + k) for k, n in enumerate(("l30_0", "l30_4", "l90_4"))]
            extra = lateral("l60_4", 700 + draw)
            for label, obs in (("without 60 deg", Observations.concat(base)),
                               ("with 60 deg", Observations.concat(base + [extra]))):
                f = fit(robot, obs)
                print(f"draw {draw} {label:>15}: "
                      + ", ".join(f"{p} {(f.values[p] - getattr(truth, p)) / f.se[p]:+.1f}" for p in TARGETS), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
