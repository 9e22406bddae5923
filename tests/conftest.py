"""Shared fixtures: paths to the test data beside the checkout."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
TUM_TRAJECTORIES = SHARED / "data" / "tum-trajectories"


@pytest.fixture
def tum_trajectories() -> Path:
    if not TUM_TRAJECTORIES.is_dir():
        pytest.skip(f"{TUM_TRAJECTORIES} is not present (it sits beside the checkout in CI)")
    return TUM_TRAJECTORIES
