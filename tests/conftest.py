"""Shared fixtures: the real Omnibot description and paths to the shared real data."""

from __future__ import annotations

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
