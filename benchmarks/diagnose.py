"""Benchmark of `omnibench diagnose` on simulated campaigns, on either world generator.

Worlds (omnibench/analysis/diagnosis/campaign.py): every library effect at its realistic size
(omnibench/effects/library.py `example`) in the campaign that reveals it (`REVEALING`), the
alternative forms the independent physics has (`FORMS`), two effects at once (`PAIRS`),
effects outside the library (`OUT_OF_LIBRARY`) and clean worlds (`CLEAN`), each with a
different sensor-noise seed per run. The library includes the command-timing effects
(effects/timing.py: command_latency, serial_command_latency, per_wheel_latency, actuator_lag), revealed
by a square wave logged every 20 ± 5 ms; the wheel inertia is offered as a core-parameter
re-estimate wherever step responses are present (a false re-estimate on a clean world counts
as a false addition).

    --generator independent   physics written for testing only (omnibench/worlds/independent.py:
                              exact stick-slip, another integrator, other effect forms): the
                              figure that measures generalisation. The default.
    --generator model         the fit's own simulator (self-consistency)

Printed per world: right effect first, fitted size within 3 SE of the truth (over all runs;
n/a for a form whose size parameter the library's form does not share), no spurious second addition, the median held-out error ratio in the
procedure it shows in; pairs: both found; out-of-library: "unexplained" with nothing added;
clean: worlds with any addition.

    .venv/bin/python benchmarks/diagnose.py --seeds 10 --clean 20 --jobs 2
    .venv/bin/python benchmarks/diagnose.py --seeds 2 --only stribeck_friction,pair:battery+stribeck
    .venv/bin/python benchmarks/diagnose.py --generator model --seeds 3 --json results.json
    .venv/bin/python benchmarks/diagnose.py --from-json results.json     # figures of an interrupted run
    .venv/bin/python benchmarks/diagnose.py --seeds 5 --skip 5 --json more.json   # seeds 1005-1009
    .venv/bin/python benchmarks/diagnose.py --from-json results.json,more.json
    .venv/bin/python benchmarks/diagnose.py --seeds 1 --only driver_deadband --before main

--before REF also runs the same diagnoses with the omnibench of git ref REF (a temporary
detached worktree, this script, PYTHONPATH) and prints both, diagnosis by diagnosis: the
effects selected and the first effect's values +- SE, flagged where they differ (another
selection, or a value moved by more than its SE): a speed-up must give the same answers.

Jobs run seed-major (every world's first seed, then every world's second, ...), and --json is
rewritten after each diagnosis, so an interrupted run still gives every world the same seeds.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from at_ref import results_at  # benchmarks/at_ref.py (scripts run from this folder)
from at_ref import without_option as _without

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]

TABLE_OF = {"upside_down_sweep": "sweep", "forward_runs": "forward", "lateral_runs": "lateral",
            "energy_trajectories": "energy", "step_response": "step_response"}


def _worlds(generator: str) -> list[tuple[str, str, object, dict, tuple[str, ...], dict]]:
    """(kind, label, spec, world effects, expected effect names, true values {effect.param: v})."""
    from omnibench.analysis.diagnosis.campaign import CLEAN, FORMS, OUT_OF_LIBRARY, PAIRS, REVEALING
    from omnibench.effects import EFFECTS

    out = []
    for name, spec in REVEALING.items():
        eff = EFFECTS[name]
        out.append(("effect", name, spec, eff.world(), (name,), {f"{name}.{p}": eff.example[p] for p in eff.size_params}))
    if generator == "independent":
        for label, (spec, world, truth) in FORMS.items():
            out.append(("effect", label, spec, world, (label.split(":")[0],), truth))
    for label, (spec, world) in PAIRS.items():
        out.append(("pair", label, spec, world, tuple(world), {}))
    if generator == "independent":
        for label, (spec, world) in OUT_OF_LIBRARY.items():
            out.append(("outside", label, spec, world, (), {}))
    for k, spec in enumerate(CLEAN):
        out.append(("clean", f"clean {k}", spec, {}, (), {}))
    return out


def _one(job: tuple) -> dict:
    """Diagnose one seeded world; a small dict of what happened."""
    kind, label, spec, world, expected, truth, seed, generator = job
    from omnibench.analysis.diagnosis import diagnose
    from omnibench.analysis.diagnosis.campaign import campaign
    from omnibench.effects import EFFECTS
    from omnibench.model import default_robot

    robot = default_robot()
    t0 = time.time()
    d = diagnose(robot, campaign(robot, spec, world, seed=seed, generator=generator))
    names = [c.name for c in d.selected]
    covered = None
    fitted = {}
    if kind == "effect" and names and names[0] == expected[0]:
        c = d.selected[0]
        checked = [k for k in truth if k in c.values]
        covered = all(abs(c.values[k] - truth[k]) <= 3 * c.se[k] for k in checked) if checked else None
        fitted = {k: {"value": c.values[k], "se": c.se[k], "truth": truth.get(k)} for k in c.values}
    ratios = []
    for name in expected:
        if name in EFFECTS:
            ratios += [d.after[TABLE_OF[p]]["nrmse"] / d.before[TABLE_OF[p]]["nrmse"]
                       for p in EFFECTS[name].procedures if TABLE_OF[p] in d.before]
    return {"kind": kind, "label": label, "seed": seed, "selected": names, "covered": covered, "fitted": fitted, "ratios": ratios,
            "unexplained": len(d.unexplained), "seconds": time.time() - t0}


class _Serial:
    """ProcessPoolExecutor's map in this process (--jobs 1)."""

    def __enter__(self) -> "_Serial":
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def map(self, fn, items):
        return map(fn, items)


def summarise(results: list[dict], generator: str, seconds: float) -> dict:
    """Print the table of per-world figures from the diagnoses' results; the summary dict."""
    by: dict[str, list[dict]] = {}
    for r in results:
        by.setdefault(r["label"], []).append(r)
    print(f"generator: {generator}; {len(results)} diagnoses in {seconds:.0f} s")
    print(f"{'world':<40} {'right first':>11} {'in 3 SE':>8} {'no 2nd':>7} {'err ratio':>9}  picks")
    summary: dict = {"generator": generator, "worlds": {}}
    clean_n = clean_added = 0
    for label, rs in by.items():
        kind, n = rs[0]["kind"], len(rs)
        picks: dict[str, int] = {}
        for r in rs:
            key = "+".join(r["selected"]) or "-"
            picks[key] = picks.get(key, 0) + 1
        pick_s = ", ".join(f"{k} x{v}" for k, v in sorted(picks.items(), key=lambda kv: -kv[1]))
        ratios = [x for r in rs for x in r["ratios"]]
        med = statistics.median(ratios) if ratios else float("nan")
        row = {"kind": kind, "runs": n, "picks": picks, "median_error_ratio": med}
        if kind == "effect":
            want = label.split(":")[0].split(" ")[0]
            first = sum(bool(r["selected"]) and r["selected"][0] == want for r in rs)
            cover = sum(bool(r["covered"]) for r in rs)
            checked = sum(r["covered"] is not None for r in rs) or not first
            alone = sum(len(r["selected"]) <= 1 for r in rs)
            row.update(right_first=first, within_3se=cover if checked else None, no_second=alone)
            cover_s = f"{cover:>4}/{n:<3}" if checked else f"{'n/a':>8}"
            print(f"{label:<40} {first:>5}/{n:<5} {cover_s} {alone:>3}/{n:<3} {med:>9.3f}  {pick_s}")
        elif kind == "pair":
            want = set(label.split(":")[1].split("+")) if ":" in label else set()
            both = sum(want <= set(r["selected"]) for r in rs)
            row.update(both_found=both)
            print(f"{label:<40} both found {both:>3}/{n:<3} {'':>12} {med:>9.3f}  {pick_s}")
        elif kind == "outside":
            ok = sum((not r["selected"]) and r["unexplained"] > 0 for r in rs)
            row.update(unexplained_nothing_added=ok)
            print(f"{label:<40} unexplained, nothing added {ok:>3}/{n:<3}  {pick_s}")
        else:
            clean_n += n
            clean_added += sum(bool(r["selected"]) for r in rs)
            row.update(with_addition=sum(bool(r["selected"]) for r in rs))
        summary["worlds"][label] = row
    if clean_n:
        picks = {}
        for r in results:
            if r["kind"] == "clean":
                for c in r["selected"]:
                    picks[c] = picks.get(c, 0) + 1
        print(f"clean worlds: {clean_n - clean_added}/{clean_n} with no addition"
              f"{' (added: ' + ', '.join(f'{k} x{v}' for k, v in picks.items()) + ')' if picks else ''}")
        summary["clean"] = {"worlds": clean_n, "no_addition": clean_n - clean_added, "picks": picks}
    return summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10, help="simulated campaigns per world (default 10)")
    ap.add_argument("--clean", type=int, default=20, help="clean worlds in all (default 20)")
    ap.add_argument("--skip", type=int, default=0,
                    help="leave out the first SKIP seeds of each world (continue an earlier run on new seeds)")
    ap.add_argument("--generator", default="independent", choices=("independent", "model"))
    ap.add_argument("--only", default="", help="comma-separated world labels (as printed) to run")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--json", default="", help="also write the results to this JSON file")
    ap.add_argument("--before", default="", metavar="REF",
                    help="also run the same diagnoses with git ref REF's omnibench and print both side by side")
    ap.add_argument("--from-json", default="",
                    help="only print the figures of (possibly interrupted) runs' JSON files, comma-separated")
    args = ap.parse_args(argv)
    if args.from_json:
        runs = []
        for path in args.from_json.split(","):
            with open(path, encoding="utf-8") as fh:
                runs += json.load(fh)["runs"]
        summarise(runs, args.generator, sum(r["seconds"] for r in runs))
        return 0
    worlds = _worlds(args.generator)
    only = {s.strip() for s in args.only.split(",") if s.strip()}
    if only:
        unknown = only - {w[1] for w in worlds}
        if unknown:
            print(f"unknown world(s): {', '.join(sorted(unknown))}; known: {', '.join(w[1] for w in worlds)}",
                  file=sys.stderr)
            return 2
        worlds = [w for w in worlds if w[1] in only]
    jobs = []
    n_clean = sum(w[0] == "clean" for w in worlds)
    for w in worlds:
        if w[0] == "clean":
            k = int(w[1].split()[-1])
            seeds = [5000 + s for s in range(args.skip, args.skip + args.clean)
                     if s % max(n_clean, 1) == k % max(n_clean, 1)]
        else:
            seeds = [1000 + s for s in range(args.skip, args.skip + args.seeds)]
        jobs += [(k, (*w, seed, args.generator)) for k, seed in enumerate(seeds)]
    # seed-major: cut short, every world has had the same number of seeds
    jobs = [j for _, j in sorted(jobs, key=lambda kj: kj[0])]
    t0 = time.time()
    results = []
    with ProcessPoolExecutor(args.jobs) if args.jobs > 1 else _Serial() as ex:
        for r in ex.map(_one, jobs):
            results.append(r)
            print(f"  [{len(results)}/{len(jobs)} {time.time() - t0:.0f} s] {r['label']}: "
                  f"{'+'.join(r['selected']) or '-'}", file=sys.stderr, flush=True)
            if args.json:  # partial results survive an interrupted run
                with open(args.json, "w", encoding="utf-8") as fh:
                    json.dump({"runs": results}, fh)
    summary = summarise(results, args.generator, time.time() - t0)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"summary": summary, "runs": results}, fh, indent=2)
    if args.before:
        before = run_at_ref(args.before, [a for a in (argv if argv is not None else sys.argv[1:])])
        print(f"\n--- the same diagnoses with {args.before}'s omnibench ---")
        summarise(before, args.generator, sum(r["seconds"] for r in before))
        print()
        print(side_by_side(before, results, args.before))
    return 0


def run_at_ref(ref: str, argv: list[str]) -> list[dict]:
    """This script's results with git ref `ref`'s omnibench (the same arguments without --before
    and --json)."""
    return results_at(ref, HERE, _without(_without(argv, "--before"), "--json"))["runs"]


def side_by_side(before: list[dict], after: list[dict], ref: str) -> str:
    """Per diagnosis (world, seed): the effects selected and the first one's values +- SE before
    (git ref) and now, flagged DIFFERENT where the selection differs or a value moved by more
    than the larger of its two SEs; with each diagnosis' wall seconds."""
    old = {(r["label"], r.get("seed")): r for r in before}
    lines = [f"{'world':<34} {'seed':>5}  {ref + ' (before)':<44} {'this tree (after)':<44} verdict"]
    n_diff = 0
    for r in after:
        b = old.get((r["label"], r.get("seed")))
        if b is None:
            continue

        def show(x: dict) -> str:
            vals = ", ".join(f"{k.split('.')[-1]}={v['value']:.4g}±{v['se']:.2g}" for k, v in x["fitted"].items())
            return ("+".join(x["selected"]) or "-") + (f" ({vals})" if vals else "") + f" {x['seconds']:.0f}s"

        same = b["selected"] == r["selected"] and all(
            k in b["fitted"] and abs(v["value"] - b["fitted"][k]["value"]) <= max(v["se"], b["fitted"][k]["se"])
            for k, v in r["fitted"].items()) and set(b["fitted"]) == set(r["fitted"])
        n_diff += not same
        lines.append(f"{r['label']:<34} {r.get('seed', ''):>5}  {show(b):<44} {show(r):<44} "
                     f"{'same' if same else 'DIFFERENT'}")
    lines.append(f"{len(after) - n_diff} of {len(after)} diagnoses give the same answer as {ref}")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
