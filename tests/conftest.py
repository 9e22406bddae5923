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
    in sys.modules, where its dataclasses look their module up while it loads. Its folder is
    on the import path, as when it runs as a script (``sheets`` is imported so)."""
    if str(REPO / "benchmarks") not in sys.path:
        sys.path.append(str(REPO / "benchmarks"))
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


FILE_SECONDS = {
    "test_sim.py": 81,
    "test_report_plots.py": 52,
    "test_benchmark.py": 60,
    "test_kill.py": 30,
    "test_slam.py": 53,
    "test_api.py": 52,
    "test_stages.py": 50,
    "test_external_sweeps.py": 46,
    "test_package.py": 12,
    "test_example_trackers.py": 40,
    "test_kernels.py": 39,
    "test_figures.py": 38,
    "test_detectors.py": 13,  # the animal-recognition guards in the slow set, 2026-12-03
    "test_output.py": 33,
    "test_fuzz.py": 33,
    "test_gates.py": 30,
    "test_benchmarks.py": 30,
    "test_reuse.py": 29,
    "test_report.py": 26,
    "test_pytest_plugin.py": 26,
    "test_full_disk.py": 25,
    "test_slam_split.py": 10,  # the crowd pins in the slow set, 2026-12-03
    "test_report_hostile.py": 23,
    "test_compare.py": 23,
    "test_map_metrics.py": 22,
    "test_rows.py": 21,
    "test_dense_runs.py": 20,
    "test_tum_people.py": 18,
    "test_sweep.py": 18,
    "test_cli_conventions.py": 18,
    "test_report_geometry.py": 17,
    "test_tum_sensor.py": 15,
    "test_report_cache.py": 15,
    "test_trackers.py": 14,
    "test_keys.py": 14,
    "test_hostile_templates.py": 14,
    "test_rosbag.py": 12,
    "test_hostile_inputs.py": 12,
    "test_fidelity_benchmark.py": 12,
    "test_baseline.py": 11,
    "test_mapping_clock.py": 20,  # alone, 2026-12-03
    "test_local_mapping.py": 18,  # alone, 2026-12-03
    "test_cli.py": 9,
    "test_memo.py": 10,  # alone, 2026-12-03
}
"""Seconds each of the heaviest test files took (``make test``'s run of 2026-12-02, 2 workers,
from its JUnit XML); the rest took under 8 s each. Files run heaviest first, so that no
worker is left at the end with a long file while the other waits: pytest-xdist's own order
(most tests first) put test_kill.py, one test of 55 s, last."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Each file's tests stay together and in their order; the files go heaviest first."""
    items.sort(key=lambda item: -FILE_SECONDS.get(item.path.name, 0))


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
    names = ("DEPOTBENCH_CACHE", "DEPOTBENCH_CACHE_SEQUENCES", "DEPOTBENCH_WORKERS", *CACHE_VARIABLES)
    vocabulary = _users_vocabulary_folder()
    previous = {name: os.environ.pop(name, None) for name in names}
    os.environ["DEPOTBENCH_CACHE"] = str(tmp_path_factory.mktemp("caches"))
    os.environ["DEPOTBENCH_CACHE_SEQUENCES"] = "off"
    # A command's default --workers is one, run in the test's own process: the test workers
    # already fill the cores, and the 87 commands that take the default each spawned two
    # workers (1-2 s of imports apiece). Tests of the pool ask for theirs with --workers.
    os.environ["DEPOTBENCH_WORKERS"] = "1"
    if vocabulary is not None:
        os.environ["DEPOTBENCH_CACHE_VOCABULARY"] = str(vocabulary)
    yield
    for name, value in previous.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
