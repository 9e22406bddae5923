"""Shared fixtures: paths to the test data beside the checkout."""

from __future__ import annotations

import functools
import importlib.util
import os
import sys
from pathlib import Path
from types import ModuleType

import pytest

pytest_plugins = ["pytester"]  # the depotbench pytest plugin is tested in a child session

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
TUM_TRAJECTORIES = SHARED / "data" / "tum-trajectories"


@functools.cache
def benchmark_module(name: str) -> ModuleType:
    """benchmarks/NAME.py as a module, loaded once (benchmarks/ is not a package); registered
    in sys.modules, where its dataclasses look their module up while it loads."""
    spec = importlib.util.spec_from_file_location(f"{name}_benchmark", REPO / "benchmarks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def tum_trajectories() -> Path:
    if not TUM_TRAJECTORIES.is_dir():
        pytest.skip(f"{TUM_TRAJECTORIES} is not present (it sits beside the checkout in CI)")
    return TUM_TRAJECTORIES


CACHE_VARIABLES = (
    "DEPOTBENCH_CACHE_STAGES",
    "DEPOTBENCH_CACHE_VOCABULARY",
    "DEPOTBENCH_CACHE_STAGES_MAX_BYTES",
    "DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES",
    "DEPOTBENCH_CACHE_DIR",  # retired names: refused wherever set, so not taken from a shell
    "DEPOTBENCH_CACHE_MAX_BYTES",
    "DEPOTBENCH_SEQUENCE_STORE",
    "DEPOTBENCH_SEQUENCE_STORE_MAX_BYTES",
)


def _users_vocabulary_folder() -> Path | None:
    """The user's ORB vocabulary cache, which tests share: the default vocabulary takes
    minutes to build, and each test process (4 under xdist) would build its own in a private
    root. It is built from fixed scenes and a fixed seed, so sharing it changes no result;
    None (a private one) when the user's caches are off or misconfigured."""
    from depotbench.core.cache_home import cache_folder
    from depotbench.core.errors import InputError

    try:
        return cache_folder("vocabulary")
    except InputError:
        return None


@pytest.fixture(autouse=True, scope="session")
def _private_caches(tmp_path_factory: pytest.TempPathFactory):
    """Tests never read or fill the user's caches (~/.cache/depotbench), the vocabulary
    aside: the session has a cache root of its own, whatever the shell sets. The sequence
    store is off there, since determinism tests render what they compare; tests of the store
    set their own."""
    names = ("DEPOTBENCH_CACHE", "DEPOTBENCH_CACHE_SEQUENCES", *CACHE_VARIABLES)
    vocabulary = _users_vocabulary_folder()
    previous = {name: os.environ.pop(name, None) for name in names}
    os.environ["DEPOTBENCH_CACHE"] = str(tmp_path_factory.mktemp("caches"))
    os.environ["DEPOTBENCH_CACHE_SEQUENCES"] = "off"
    if vocabulary is not None:
        os.environ["DEPOTBENCH_CACHE_VOCABULARY"] = str(vocabulary)
    yield
    for name, value in previous.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
