"""Fixtures of the analysis tests: simulated campaigns (seeded) and the real 2019 runs imported."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path("/work/shared/data/omnibot-tfm")
_here = Path(__file__).resolve()
for parent in _here.parents:
    if (parent / "shared" / "data" / "omnibot-tfm").is_dir():
        DATA = parent / "shared" / "data" / "omnibot-tfm"
        break


@pytest.fixture(scope="session")
def robot():
    from omnibench.model import default_robot

    return default_robot()


@pytest.fixture(scope="session")
def truth(robot):
    """The world's true coefficients: deliberately away from the robot file's placeholders."""
    return robot.replace(a=0.02, b=0.45, c=0.015, a_r=2.5, b_r=0.8, c_r=0.02, C_r=0.03)


@pytest.fixture(scope="session")
def campaign(truth):
    """A whole simulated campaign (sweep with currents, forward, lateral, energy)."""
    from omnibench.analysis.simcampaign import simulated_observations

    return simulated_observations(truth, seed=11)


@pytest.fixture(scope="session")
def campaign_fit(robot, campaign):
    from omnibench.analysis.fitting import fit

    return fit(robot, campaign)


@pytest.fixture(scope="session")
def real_runs(tmp_path_factory):
    """The three 2019 logs imported as run directories (skipped without the shared data)."""
    if not (DATA / "results_jacked.mat").exists():
        pytest.skip("shared/data/omnibot-tfm is not available")
    from omnibench.runs.tfm import import_tfm

    out = tmp_path_factory.mktemp("tfm")
    return {name: import_tfm(DATA / f"{name}.mat", out) for name in ("results_jacked", "square_fast", "square_small")}
