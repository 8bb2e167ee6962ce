"""Shared fixtures: the real Omnibot description and paths to the shared real data."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
TFM_DATA = SHARED / "data" / "omnibot-tfm"


@pytest.fixture(scope="session")
def omnibot():
    from omnibench.model import default_robot

    return default_robot()


@pytest.fixture(scope="session")
def tfm_data() -> Path:
    if not (TFM_DATA / "results_jacked.mat").exists():
        pytest.skip("shared/data/omnibot-tfm is not beside the checkout")
    return TFM_DATA


# ---------------------------------------------------------------------------------------------
# Scheduling under pytest-xdist (pyproject: `--dist loadgroup --no-loadscope-reorder`).
#
# A test is its own unit of work, so one file's dear tests (tests/analysis/test_diagnose.py) are
# shared by both workers, except that the tests of a file that uses a module-scoped fixture (a
# served simulator, imported runs) or a dear session one (a firmware build, a simulated campaign's
# fit) go to one worker together, so the fixture is made once. The units are handed out longest first (tests/durations.json, as
# measured: `--store-durations` rewrites it; a test it does not know counts 1 s), so that the
# workers do not end with one long test left on one of them. The order changes no assertion.

DURATIONS = Path(__file__).with_name("durations.json")


def pytest_xdist_auto_num_workers(config) -> int:
    """`-n auto`: one worker more than cores. Many tests wait (a served simulator's clock, a
    subprocess, simavr), so with one worker per core the cores idled ~15 % of the suite; on 2
    cores the suite took 11 min 50 s with 2 workers and 10 min 7 s with 3 (the same tests and
    machine, back to back). The kernel's numba threads are not limited: tests that compute
    alone at the end still use both cores."""
    return (os.cpu_count() or 1) + 1


def pytest_addoption(parser):
    parser.addoption("--store-durations", action="store_true", default=False,
                     help="write each test's measured time (setup + call + teardown) to tests/durations.json")


def _known_durations() -> dict[str, float]:
    try:
        return json.loads(DURATIONS.read_text())
    except (OSError, ValueError):
        return {}


def _plain(nodeid: str) -> str:
    """The node id without xdist's '@group' suffix."""
    return nodeid.rsplit("@", 1)[0] if nodeid.rfind("@") > nodeid.rfind("]") else nodeid


# session fixtures cheap enough to make on each worker (the others: a simulated campaign and its
# fit, firmware builds, keep their file on one worker, as --dist loadfile did)
CHEAP_SESSION_FIXTURES = {"omnibot", "robot", "truth", "tfm_data", "real_runs"}


def _shares_a_dear_fixture(item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return False
    for name, defs in info.name2fixturedefs.items():
        if not defs or not defs[-1].baseid:  # pytest's own (tmp_path_factory, ...)
            continue
        if defs[-1].scope in ("module", "package", "class"):
            return True
        if defs[-1].scope == "session" and name not in CHEAP_SESSION_FIXTURES:
            return True
    return False


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook reads the xdist_group marks
def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.get_closest_marker("xdist_group") is None and _shares_a_dear_fixture(item):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))
    known = _known_durations()

    def unit(item) -> str:
        mark = item.get_closest_marker("xdist_group")
        return item.nodeid if mark is None else str(mark.args[0] if mark.args else mark.kwargs.get("name"))

    cost: dict[str, float] = {}
    first: dict[str, int] = {}
    for i, item in enumerate(items):
        cost[unit(item)] = cost.get(unit(item), 0.0) + known.get(item.nodeid, 1.0)
        first.setdefault(unit(item), i)
    # longest unit first; a group's tests together, in their order; equals in collection order
    items.sort(key=lambda it: (-cost[unit(it)], first[unit(it)]))


class _DurationRecorder:
    def __init__(self) -> None:
        self.times: dict[str, float] = {}

    def pytest_runtest_logreport(self, report):
        key = _plain(report.nodeid)
        self.times[key] = self.times.get(key, 0.0) + report.duration

    def pytest_sessionfinish(self, session):
        merged = {**_known_durations(), **{k: round(v, 1) for k, v in self.times.items()}}
        DURATIONS.write_text(json.dumps(dict(sorted(merged.items())), indent=0) + "\n")


def pytest_configure(config):
    if not hasattr(config, "workerinput") and config.getoption("--store-durations"):
        config.pluginmanager.register(_DurationRecorder(), "omnibench-durations")
