"""The suite's scheduling (tests/conftest.py): the tests that share a module-scoped fixture go
to one worker together, so the fixture (a served simulator, a simulated campaign) is made once."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def shared() -> object:
    return object()


def test_a_test_sharing_a_module_fixture_goes_to_the_worker_of_its_file(request, shared) -> None:
    """xdist sends a test to its group's worker by the '@group' suffix of its node id; pytest
    9.2 with pytest-xdist 3.8 drops the suffix silently (pytest-dev/pytest-xdist#1386), and every
    worker then builds such a fixture again (pyproject pins pytest < 9.2)."""
    if not hasattr(request.config, "workerinput"):
        pytest.skip("the grouping exists only under pytest-xdist (the suite's `-n auto`; this run is -n 0)")
    assert request.node.nodeid.endswith("@tests/test_scheduling.py"), (
        f"{request.node.nodeid}: the xdist group is lost; each worker rebuilds module fixtures")
