"""What a user waits for: the README's own commands on their own run folders, CPU and wall each,
and where the time goes (issue 34).

Runs in a temporary folder (or --work DIR, kept), each as its own `omnibench` process:

    campaign        omnibench campaign --port sim:// --out campaign          (clean simulated robot)
    fit             omnibench fit campaign/runs --out model.toml               (the campaign's run folders)
    validate-energy omnibench validate-energy --model model.toml campaign/runs
    diagnose        omnibench diagnose --model model.toml campaign/runs
    deadband        omnibench campaign --port "sim://?effects.driver_deadband.u_0=0.04" --out campaign-deadband
    loro            omnibench import tfm <2019 logs> --out runs/tfm; omnibench diagnose --model omnibot.toml runs/tfm --loro
    independent     omnibench campaign --port "sim://?plant=independent" --out campaign-independent

CPU is the child process's user + system time (one thread when NUMBA_NUM_THREADS=1, which
--threads 1 sets: the figure that does not depend on other work on the machine); wall is what
the operator waits. With --profile each command runs under cProfile and the time is split by
stage (cumulative CPU time of the functions that do each part; the stages nest, e.g. Jacobians
are part of settle passes, so the rows do not add up):

    simulations      simulator.simulate_batch (every model prediction)
    Jacobians        the finite-difference Jacobians of the fits (least_squares'
                     WeightedResiduals.jacobian, engine.fit_model's jac and its final Jacobian)
    fitting.fit      the user's fit (`omnibench fit`; diagnose's declared model when its file
                     is not the fit of these runs)
    model fits       engine.fit_model (its settle passes: weighted fits until the scales settle)
    screening        engine.screen (first-order score of every candidate)
    candidate fits   engine.fit_candidate / fit_candidates (full refits of the promising ones)
    CV folds         engine.heldout_residuals
    robust SEs       robust_se.cluster_se, encoder_se.encoder_se
    structure        diagnosis structure tests

Measured (issue 34, one thread, CPU; fit and diagnose on main's clean-campaign runs, 2-core
machine under load): main 4ba8eb8 -> the engine branch: fit 23.6 s -> 14.7 s, diagnose
51.4 s -> 26.9 s (under the profiler: simulations 52.8 -> 27.5 s, screening 29.5 -> 14.0 s,
the declared model's fit 24.0 -> 14.0 s), the deadband example 15:05 -> 6:53 (same finding).

Issue 34, `omnibench fit`'s start-up (branch fitwall, main 71bceb7 -> fitwall; same model file, diff
of the date line only). Parts measured in one process, before and after, machine at load 7-10:
pint import + registry 0.28 s -> not imported; generating the kernel's source to find its file
0.14-0.18 s -> 0.004 s; 25 empty Observations() tables 0.32 -> 0.01 s; step_samples of all 66
steps 0.10 -> 0.02 s. End to end (--only fit --threads 1, alternated with main, load 3-7, so +-1 s
of noise): CPU main 11.4 / 10.8 / 11.9 s, fitwall 9.3 / 11.0 / 8.6 s; all cores, load ~3.3:
main 12.4 / 11.5 s CPU, 14.3 / 11.7 s wall, fitwall 11.5 / 10.7 s CPU, 14.5 / 10.9 s wall. The
5 s wall target of a quiet machine is not shown: the kernel (~3-4 s CPU) and numpy/pandas/
numba/scipy imports and numba's cache load (~2 s) remain.

Issue 34, `omnibench fit` on a clean campaign's runs, next round (branch h2, main cb17615 -> h2; merged without its run hand-over, below; the
model file the same, diff of the date line only). Where its time goes, one thread, CPU, load 4-5:
imports of numpy, pandas, numba, scipy.optimize ~1.3 s; numba loading the cached kernel 0.4-0.6 s
(mostly numba's own registries: its BLAS check imports scipy.linalg, which scipy.optimize needs
anyway); reading the runs 0.6 s; the fit 4.4 s, of which the kernel 3.3-4.1 s (90 calls, 273
simulations of a group under a parameter set: sweep 142, forward 55, lateral 76); the per-wheel
fits 0.5-0.6 s. Checked and left: every kernel call of the fit has two lane groups or more, so
every prediction, a single parameter set too, already runs on both cores (the fit's 90 calls
replayed lane group by lane group: 4.41 s of work, a 2-thread makespan of 2.27 s, 2.20 ideal); the
Jacobian for the SEs and the reweighted pass's start come from the caches (no simulation); the
sweep warm start's own Predictor re-simulates the identifiability Jacobian's sweep part (~0.03 s).
Changed on h2: a run read by runs.check handed to the analysis' read of it (check + from_runs
0.76-0.80 -> 0.57-0.64 s CPU; NOT merged: a process-wide cache of parsed runs keyed by file
signatures is too much machinery for ~0.2 s); a group's parameter sets simulated trajectory-major, so a lane
group holds one trajectory under several sets (same adaptive sub-steps): the fit's 90 kernel calls
replayed 3.46 -> 3.27 s CPU twice, every number bit for bit; OMP_WAIT_POLICY=passive unless set
(libgomp's workers spun ~6 ms after each parallel region, CPU taken from the fit's own thread on a
busy machine; a 60-call microbenchmark at load 6: CPU 0.84 -> 0.45 s, wall 1.26 -> 0.85 s). End to
end, alternating main and h2 on the same runs (the machine busy with other work throughout):
one thread, load 6.0-8.6: main CPU 10.53 / 10.99 / 11.54 / 9.61 / 10.06 / 9.97 s, h2 11.09 /
10.03 / 11.23 / 10.27 / 10.57 / 8.42 s (the ~0.35 s saved is below this load's noise); all cores,
load 7.4-8.8: main CPU 12.45 / 11.01 / 10.54 / 10.37 / 11.90 s, wall 18.09 / 15.92 / 15.28 /
15.20 / 17.51 s; h2 CPU 9.14 / 10.18 / 8.80 / 11.13 / 9.98 s, wall 13.53 / 14.89 / 12.77 / 16.20 /
14.29 s (medians: wall 15.9 -> 14.3 s). In one process per run (fitting.fit and fit_per_wheel
called directly, one thread, three alternations, load 4.7-6): reading the runs 0.85 / 0.67 / 0.47
-> 0.55 / 0.45 / 0.36 s, the kernel's 90 calls 4.10 / 4.05 / 3.81 -> 3.92 / 3.43 / 3.66 s, fit and
per-wheel fits 4.83 / 4.85 / 4.56 -> 4.72 / 4.18 / 4.42 s. diagnose on these runs with the fitted
model: --json output and --out model identical to main's. The 5 s wall target of a quiet machine is still not shown
(no quiet machine this round): about 1.7 s of imports and numba start-up, 0.6 s of reading, ~1.4 s
of the fits' own Python and ~1.7 s of kernel on two cores remain.

Issue 34, where the deadband diagnose's time goes (branch h1, on main cb17615's code: the
README's deadband campaign at seed 8 with `--analysis none`, then `omnibench fit` and diagnose on its
runs; one thread under cProfile, load 5-8, ~1.5x the unprofiled quiet figures): 697 s CPU,
simulations 687 s, Jacobians 441 s, candidate fits 557 s, screening 57 s. By fit: the declared
model 60 s (136 simulations); driver_deadband "shifted" 315 s (688 simulations: settle passes 1-4
end at max_nfev=15 with 10-14 Jacobians each, creeping from the screen's u_0 = 0.021 to 0.040 along
the valley of u_0 with the Coulomb term and R_a); its "cut" form 34 s (one pass); the three
candidates found not significant (actuator_lag, per_wheel_latency, serial_command_latency; LR 0.0,
1.9, 0.2) 19 + 106 + 83 s; the polish 19 s. Tried on h1 and not merged: candidate fits at relative
tolerance 1e-5 (669 s, same report, but it moves candidates' evidence for 4 %); giving up a losing
start or form from its linearised promise (unsound: at the deadband's start the linear model's
optimum, deviance 2826-4601, is worse than the start's 1391, while the fit reaches 446); scanning
u_0 at 0.5-3x the screen's estimate (picks 0.010 for 0.04); max_nfev 45 per pass (the first pass
alone 39 Jacobians, 220 s, still at its limit) or 8 (stops at u_0 0.021, deviance 1223). The
deadband target needs a solver for that valley (e.g. u_0 profiled out), not fewer passes.

Issue 34, the deadband's candidate fit from a data start (branch dz, on main c3571e8, same runs as
above: seed 8, `--analysis none`, `omnibench fit`, then fit_candidate from the declared fit; one
thread, CPU, machine loaded 4-6 by other work). Why it crept: the declared fit had taken up the dead
zone's offset in R_a (3.51 ohm for 1.85) and, since the ground runs log no current, in the ground
terms through R_a x torque (a_r, b_r, C_r about half their values); from the screen's u_0 0.021 the
fit had to walk u_0 up and R_a down together. The sweep's voltage balance
V (u - u_0 sign u) = k_e omega + R_a i is linear in k_e, R_a, u_0: one solve over its steady states
with current gives 0.04005, 1.840, 1.605 (true 0.04, 1.846, 1.604). The start takes those, scales
the ground terms by the R_a ratio, takes one Gauss-Newton step for a, b, c, c_r, and is kept only
if its deviance beats the screen's start (4129 screen, 2883 data, 2329 after the step; 444 at the
optimum); its first settle pass weighs the groups by the start's own scales. The "shifted" fit:
315.6 s, 658 simulations, 6 passes (1-4 at max_nfev) -> 98.9 s, 172 simulations, 4 passes of 6/5/4/3
evaluations, all converged; u_0 0.040042 +- 0.000062 -> 0.040039 +- 0.000062, deviance 444.156 ->
444.162. Not kept: x_scale='jac' (the same costs and evaluation counts pass by pass); a linearised
profile of u_0 over the declared fit's Jacobian (its minimum at 0.010: the Jacobian at R_a 3.51
moves the ground terms by half what R_a 1.85 needs). End to end, `omnibench diagnose --candidates
driver_deadband` on those runs (one thread, load 4-6, not alternated): main 500.7 s CPU, dz 249.3 s;
u_0 0.0400391 +- 0.0000623 both, LR 972.7 -> 974.0, held-out errors the same to 4 digits (sweep
6.47 -> 0.222 %, energy 7.24 -> 0.173 %); the full default diagnose was not re-measured.
`benchmarks/diagnose.py --seeds 2 --clean 3` on driver_deadband, its cut form, stribeck_friction,
the deadband + quadratic drag pair and the clean worlds, `--before main` at 04a4e32 (before the
start's own scales): 11 of 11 the same answer; dz's final code alone: the same selections and
values (u_0 0.03014 +- 0.00011, 0.02988 +- 0.00012; cut 0.08046 +- 0.0036, 0.07836 +- 0.0030;
clean 3/3 nothing added). Wall seconds there are too noisy at this load to compare.

Issue 34, subnormal doubles (main 52bf8a3 -> c9b72a4; one thread, CPU): a speed decaying to rest
passes through subnormal doubles, ~100x slower on x86; the kernel now runs each lane group with
FTZ/DAZ set (omnibench/model/fpu.py). The clean campaign's four energy runs under one parameter
set 1.20 -> 0.25 s; the fixed-count kernel's cost had jumped 3x between 7 and 8 sub-steps. End to
end: campaign 1:28 -> 0:45.3, diagnose 58 -> 23.4 s, the deadband example 5:37 -> 2:44.7, fit
9.1 -> 8.9 s (its ground runs had few subnormals), `diagnose --loro` 10:05 -> 9:51.8 (upside down,
exact stick: none), independent 2:19 -> 2:18.0. Same model file; benchmarks/diagnose.py --before
52bf8a3 --seeds 1 --clean 2: 29 of 29 the same; benchmarks/real_data.py --before 52bf8a3: the
same effects, values, SEs and leave-one-run-out table.
Issue 34, settling passes and pairs (main e3e3883 -> b4d374a; one thread, CPU, the other core busy
with a test run): engine.fit_model's passes that only settle the weights step on the last exact
pass's Jacobian (one simulation per step, not a stencil), and an exact pass ends every fit; a
pair's fit starts from its lead effect's own fit. The deadband example 2:44.7 -> 2:19.5 (its
driver_deadband candidate alone, `diagnose --candidates driver_deadband`: 102.7 -> 80.6 s; the
shifted form 110 simulations, 30 s; the cut form, 601 AIC behind, 178 simulations, 38 s: its first
pass, at its evaluation limit, is most of it), `diagnose --loro` 9:51.8 -> 8:12.1. Same answers:
benchmarks/diagnose.py --before e3e3883 --seeds 1 --clean 2: 29 of 29 the same;
benchmarks/real_data.py --before e3e3883: the same effects (tau_a 0.01903 -> 0.01902 +- 0.00043,
tau 0.002548 -> 0.002552 +- 0.00072, tau_packet 0.003917 +- 6.4e-05 both) and the same
leave-one-run-out table digit for digit. Tried and dropped: stopping a later form's settle passes
once it cannot beat the best form so far (engine.hopeless against the best form's LR): the cut
form's one check, after its first pass (LR 362 + 2 x 362 of the 487 that half the winner's 974
needs), does not stop it, and its later passes are the cheap ones now.
Issue 34, fits that cannot matter (main ceaf918 -> 141f9ef): no pair fit for a partner whose
first-order LR holds only outside its physical range (engine.Screen.in_range) or that one of the
pair nests; no candidate fit for such a candidate (it keeps its place among the round's fits);
candidate fits stop at a deviance gain of 0.1 or a step of 1e-4 of the scales
(engine.CANDIDATE_DEVIANCE_TOL). The 2019 logs' diagnose (without --loro) simulated 2902 -> 1301
parameter sets (counted as scipy's evaluations plus p + 1 per Jacobian; the tolerances alone, on
the fits both made: 2515 -> 2039). One thread, CPU, quiet: `diagnose --loro` 8:13.8 -> 4:02.3,
the deadband example 2:28.0 -> 2:15.3 (same finding, u_0 0.040039 +- 0.000062). Both cores, quiet:
campaign 40.2 s wall, fit 6.9 s, the deadband example 1:37.6, `diagnose --loro` 3:23.6, the
independent-physics campaign 1:49.8. Same answers: benchmarks/diagnose.py --before ceaf918 --seeds
1 --clean 2: 29 of 29 the same; benchmarks/real_data.py --before ceaf918: the same effects and
values (tau_a 0.01902 +- 0.00043, tau 0.002552 +- 0.00072, tau_packet 0.003917 +- 6.4e-05) and the
same leave-one-run-out table digit for digit. `fit` (helper branch, observations and residual
structure vectorised): reading the runs 0.55-0.65 -> 0.39-0.41 s of CPU; the rest is imports
(~1.5-2 s) and the kernel (~4.5 s of CPU).

    .venv/bin/python benchmarks/commands.py                       # all, one thread
    .venv/bin/python benchmarks/commands.py --only campaign,fit,diagnose --profile
    .venv/bin/python benchmarks/commands.py --threads 0           # all cores (numba's default)
"""

from __future__ import annotations

import argparse
import glob
import os
import pstats
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]
DEFAULT_DATA = next((p / "shared" / "data" / "omnibot-tfm" for p in HERE.parents
                     if (p / "shared" / "data" / "omnibot-tfm").is_dir()), Path("/work/shared/data/omnibot-tfm"))

#: stage -> (module path fragment, function name) pairs whose cumulative time is the stage's
STAGES: dict[str, list[tuple[str, str]]] = {
    "simulations": [("model/simulator.py", "simulate_batch")],
    "Jacobians": [("analysis/least_squares.py", "jacobian"), ("diagnosis/engine.py", "jac"),
                  ("diagnosis/engine.py", "_final_jacobian")],
    "fitting.fit": [("analysis/fitting.py", "fit")],
    "model fits": [("diagnosis/engine.py", "fit_model")],
    "screening": [("diagnosis/engine.py", "screen")],
    "candidate fits": [("diagnosis/engine.py", "fit_candidate"), ("diagnosis/engine.py", "fit_candidates")],
    "CV folds": [("diagnosis/engine.py", "heldout_residuals")],
    "robust SEs": [("diagnosis/robust_se.py", "cluster_se"), ("diagnosis/encoder_se.py", "encoder_se")],
    "structure": [("diagnosis/core.py", "_structure_of")],
    "reading runs": [("analysis/observations.py", "from_runs")],
}


def commands(work: Path, data: Path, only: set[str]) -> list[tuple[str, list[list[str]]]]:
    """(name, argument lists run one after another) of every command asked for."""
    toml = str(ROOT / "omnibench" / "model" / "omnibot.toml")
    mats = sorted(glob.glob(str(data / "*.mat")))
    out = [
        ("campaign", [["campaign", "--port", "sim://", "--out", "campaign"]]),
        ("fit", [["fit", "campaign/runs", "--out", "model.toml"]]),
        ("validate-energy", [["validate-energy", "--model", "model.toml", "campaign/runs"]]),
        ("diagnose", [["diagnose", "--model", "model.toml", "campaign/runs", "--out", "model_diagnosed.toml"]]),
        ("deadband", [["campaign", "--port", "sim://?effects.driver_deadband.u_0=0.04", "--out", "campaign-deadband"]]),
        ("loro", [["import", "tfm", *mats, "--out", "runs/tfm"],
                  ["diagnose", "--model", toml, "runs/tfm", "--loro"]]),
        ("independent", [["campaign", "--port", "sim://?plant=independent", "--out", "campaign-independent"]]),
    ]
    return [(n, a) for n, a in out if not only or n in only]


#: run the command line under cProfile timed by this process's CPU (not wall: other work on the
#: machine does not count); argv: profile file, then the command's arguments
_PROFILED = """
import cProfile, sys, time
from omnibench.cli import main
out, sys.argv = sys.argv[1], ["omnibench"] + sys.argv[2:]
pr = cProfile.Profile(time.process_time)
pr.enable()
try:
    main()
except SystemExit as exc:
    code = exc.code
else:
    code = 0
finally:
    pr.disable()
    pr.dump_stats(out)
sys.exit(code)
"""


def stage_profile(prof: Path) -> dict[str, float]:
    """Cumulative seconds per stage (STAGES) in a cProfile dump."""
    st = pstats.Stats(str(prof))
    out = {k: 0.0 for k in STAGES}
    for (path, _line, func), (_cc, _nc, _tt, ct, _callers) in st.stats.items():  # type: ignore[attr-defined]
        for stage, keys in STAGES.items():
            if any(path.endswith(frag) and func == name for frag, name in keys):
                out[stage] += ct
    return out


def run(name: str, argvs: list[list[str]], work: Path, env: dict[str, str], profile: bool,
        log: Path) -> tuple[float, float, int, dict[str, float]]:
    """(CPU s, wall s, exit code, stage profile) of one command (all its argument lists)."""
    exe = str(Path(sys.executable).parent / "omnibench")
    cpu = wall = 0.0
    code = 0
    stages: dict[str, float] = {}
    for k, argv in enumerate(argvs):
        prof = work / f"{name}-{k}.prof"
        cmd = ([sys.executable, "-c", _PROFILED, str(prof), *argv] if profile else [exe, *argv])
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.monotonic()
        with open(log, "a") as fh:
            fh.write(f"\n$ omnibench {' '.join(argv)}\n")
            fh.flush()
            p = subprocess.run(cmd, cwd=work, env=env, stdout=fh, stderr=subprocess.STDOUT)
        wall += time.monotonic() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu += (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        code = code or p.returncode
        if profile and prof.is_file():
            for s, v in stage_profile(prof).items():
                stages[s] = stages.get(s, 0.0) + v
    return cpu, wall, code, stages


def _mmss(s: float) -> str:
    return f"{int(s // 60)}:{s % 60:04.1f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default="", help="comma list of: campaign, fit, validate-energy, diagnose, "
                                               "deadband, loro, independent (fit/validate-energy/diagnose "
                                               "need the campaign's runs: run campaign first or keep --work)")
    ap.add_argument("--threads", type=int, default=1, help="NUMBA_NUM_THREADS (0: numba's default, all cores)")
    ap.add_argument("--profile", action="store_true", help="run under cProfile and print the time by stage")
    ap.add_argument("--work", type=Path, default=None, help="work folder (kept; default: a temporary one)")
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder of the 2019 .mat files")
    args = ap.parse_args(argv)
    only = {s.strip() for s in args.only.split(",") if s.strip()}
    known = {n for n, _ in commands(Path("."), args.data, set())}
    if only - known:
        print(f"--only: unknown {', '.join(sorted(only - known))}; choose from {', '.join(sorted(known))}",
              file=sys.stderr)
        return 2
    tmp = None
    if args.work is None:
        tmp = tempfile.mkdtemp(prefix="omnibench-commands-")
        work = Path(tmp)
    else:
        work = args.work
        work.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.pop("NUMBA_NUM_THREADS", None)
    if args.threads > 0:
        env["NUMBA_NUM_THREADS"] = str(args.threads)
    log = work / "commands.log"
    print(f"work folder {work} (output in {log}); NUMBA_NUM_THREADS={env.get('NUMBA_NUM_THREADS', 'all')}, "
          f"{os.cpu_count()} cores")
    # compile the kernel first: its one-off cost is not the commands'
    subprocess.run([sys.executable, "-c", "from omnibench.model.kernel import load_kernel; load_kernel()"],
                   env=env, check=True)
    rows = []
    try:
        for name, argvs in commands(work, args.data, only):
            cpu, wall, code, stages = run(name, argvs, work, env, args.profile, log)
            rows.append((name, cpu, wall, code, stages))
            print(f"{name:<16} CPU {_mmss(cpu):>8}  wall {_mmss(wall):>8}  exit {code}", flush=True)
            if stages:
                print("    " + ", ".join(f"{k} {v:.1f} s" for k, v in stages.items() if v > 0.05), flush=True)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return 1 if any(r[3] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
