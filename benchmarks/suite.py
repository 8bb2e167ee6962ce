"""Where the test suite's time goes (issue 34: the suite stays under 10 min on 2 cores).

Runs the README's test command (`python -m pytest -q`: every core, pytest-xdist) with this file
loaded as a pytest plugin that records each test's CPU: the worker process's user + system time
(its numba threads and the children it waited for included) over the test's setup, call and
teardown, so a module's shared fixture counts on its first test. Prints the suite's wall, its
CPU, how busy the cores were, then the dearest tests and files by CPU. The suite is CPU-bound
(3 workers on 2 cores), so its wall follows its CPU: that is what to cut.

    .venv/bin/python benchmarks/suite.py                  # the whole suite
    .venv/bin/python benchmarks/suite.py --top 40 -- tests/analysis   # pytest arguments after --

Measured on 2026-11-29 (2 cores, at ea4c86d): 713 tests, 11:17 wall, 1195 s of CPU (88 % of both
cores); tests/analysis/test_diagnose.py 319 s of it, and there the Stribeck candidate's twelve
fits (two forms, six starts each) 113 of its 210 s of diagnosis (90 s once a start behind the best
one stops re-weighting: engine._behind); the kernel is 52-76 % of a profiled test's CPU.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
_OUT = "OMNIBENCH_SUITE_CPU_DIR"
_times: dict[str, tuple[float, float]] = {}


def _cpu() -> float:
    own, waited = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + waited.ru_utime + waited.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """(CPU s, wall s) of one test: setup, call and teardown."""
    c0, w0 = _cpu(), time.monotonic()
    yield
    _times[item.nodeid] = (_cpu() - c0, time.monotonic() - w0)


def pytest_sessionfinish(session):
    folder = os.environ.get(_OUT)
    if folder:
        name = os.environ.get("PYTEST_XDIST_WORKER", "main")
        Path(folder, f"{name}.json").write_text(json.dumps(_times))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--top", type=int, default=25, help="how many tests and files to list")
    ap.add_argument("pytest_args", nargs="*", help="passed to pytest (after --)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        env = {**os.environ, _OUT: folder,
               "PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).parent), os.environ.get("PYTHONPATH")]))}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.monotonic()
        rc = subprocess.call([sys.executable, "-m", "pytest", "-q", "-p", "suite", *args.pytest_args],
                             cwd=REPO, env=env)
        wall = time.monotonic() - w0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        times: dict[str, tuple[float, float]] = {}
        for f in Path(folder).glob("*.json"):
            times.update(json.loads(f.read_text()))
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    cores = os.cpu_count() or 1
    print(f"\nsuite: {len(times)} tests, {wall / 60:.0f}:{wall % 60:04.1f} wall, {cpu:.0f} s of CPU "
          f"({100 * cpu / (wall * cores):.0f} % of {cores} cores); the tests themselves {sum(c for c, _ in times.values()):.0f} s")
    print(f"\n{'CPU s':>7} {'wall s':>7}  dearest tests")
    for node, (c, w) in sorted(times.items(), key=lambda kv: -kv[1][0])[:args.top]:
        print(f"{c:7.1f} {w:7.1f}  {node.rsplit('@', 1)[0]}")
    files: collections.Counter[str] = collections.Counter()
    for node, (c, _) in times.items():
        files[node.split("::")[0]] += c
    print(f"\n{'CPU s':>7}  dearest files")
    for name, c in files.most_common(args.top):
        print(f"{c:7.1f}  {name}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
