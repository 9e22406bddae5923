"""Shared fixtures: paths to the test data beside the checkout."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

pytest_plugins = ["pytester"]  # the depotbench pytest plugin is tested in a child session

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
TUM_TRAJECTORIES = SHARED / "data" / "tum-trajectories"


@pytest.fixture
def tum_trajectories() -> Path:
    if not TUM_TRAJECTORIES.is_dir():
        pytest.skip(f"{TUM_TRAJECTORIES} is not present (it sits beside the checkout in CI)")
    return TUM_TRAJECTORIES


@pytest.fixture(autouse=True, scope="session")
def _private_stage_cache(tmp_path_factory: pytest.TempPathFactory):
    """Tests never read or fill the user's stage cache (~/.cache/depotbench/stages)."""
    previous = os.environ.get("DEPOTBENCH_CACHE_DIR")
    os.environ["DEPOTBENCH_CACHE_DIR"] = str(tmp_path_factory.mktemp("stage-cache"))
    yield
    if previous is None:
        os.environ.pop("DEPOTBENCH_CACHE_DIR", None)
    else:
        os.environ["DEPOTBENCH_CACHE_DIR"] = previous


@pytest.fixture(autouse=True, scope="session")
def _no_sequence_store():
    """Tests never read or fill the user's sequence store (~/.cache/depotbench/sequences),
    and determinism tests render what they compare; tests of the store set their own."""
    previous = os.environ.get("DEPOTBENCH_SEQUENCE_STORE")
    os.environ["DEPOTBENCH_SEQUENCE_STORE"] = "off"
    yield
    if previous is None:
        os.environ.pop("DEPOTBENCH_SEQUENCE_STORE", None)
    else:
        os.environ["DEPOTBENCH_SEQUENCE_STORE"] = previous
