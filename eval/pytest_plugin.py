"""depotbench as a pytest plugin (registered on install): gates and runs as fixtures.

```python
@pytest.mark.depotbench_gates("gates/crowd.yaml")
def test_crowd_gates(depotbench_gates):
    ...  # the gate file ran before the body; the test failed naming each failed budget

def test_crowd(depotbench_run):
    run = depotbench_run("crowd", strategy="box_epipolar_flow", frames=60, seed=3,
                         budgets={"ate_rmse_m": {"max": 0.05}, "rejection_recall": {"min": 0.8}})
    assert run["rho_percent"] > 20

@pytest.mark.depotbench_budgets(ate_rmse_m={"max": 0.05})
def test_walking(depotbench_run):
    depotbench_run("walking_static", strategy="box_epipolar_flow")  # checked against the marker
```

Sequences are generated once per session (and the stage cache serves every run);
``--depotbench-dir`` keeps them between sessions.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("depotbench")
    group.addoption(
        "--depotbench-dir",
        default=None,
        help="where depotbench fixtures keep generated sequences and run matrices (default: a temp dir)",
    )
    group.addoption(
        "--depotbench-workers",
        type=int,
        default=max(1, os.cpu_count() or 1),
        help="worker processes for depotbench fixtures",
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "depotbench_gates(path): run this gate file; fail naming each failed budget"
    )
    config.addinivalue_line(
        "markers", "depotbench_budgets(**budgets): budgets every depotbench_run of the test must hold"
    )


@pytest.fixture(scope="session")
def depotbench_dir(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    chosen = request.config.getoption("--depotbench-dir")
    if chosen:
        path = Path(chosen)
        path.mkdir(parents=True, exist_ok=True)
        return path
    return tmp_path_factory.mktemp("depotbench")


def _fail_on(report) -> None:
    if not report.passed:
        pytest.fail("depotbench budgets failed:\n" + "\n".join(report.failures), pytrace=False)


@pytest.fixture
def depotbench_gates(request: pytest.FixtureRequest, depotbench_dir: Path) -> Callable[..., Any]:
    """Call with a gate file to run and check it (``check=False`` returns the report
    without failing). A test marked ``depotbench_gates(path)`` runs that file first."""
    from eval.cli_gates import run_gates
    from eval.gates import load_gates
    from eval.sweep import validate

    workers = request.config.getoption("--depotbench-workers")

    def run(path: str | Path, check: bool = True):
        path = Path(path)
        if not path.is_absolute():
            path = Path(request.config.rootpath) / path
        gates = load_gates(path)
        validate(gates.run, path)
        report = run_gates(gates, path, depotbench_dir / f"gates-{gates.gates}", workers)
        if check:
            _fail_on(report)
        return report

    return run


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_call(item: pytest.Item) -> None:
    """A test marked ``depotbench_gates(path)`` runs the gate file first, in its call phase
    (so a failed budget is a test failure, not a setup error); ``depotbench_gates.report``
    holds the report."""
    marker = item.get_closest_marker("depotbench_gates")
    if marker is None:
        return
    if len(marker.args) != 1:
        raise pytest.UsageError(f"{item.nodeid}: depotbench_gates takes one gate file path")
    runner = getattr(item, "funcargs", {}).get("depotbench_gates")
    if runner is None:
        raise pytest.UsageError(
            f"{item.nodeid}: a depotbench_gates-marked test must take the depotbench_gates fixture"
        )
    runner.report = runner(marker.args[0])


def _sequence(scenario: str, frames: int | None, seed: int, root: Path) -> Path:
    from scenes import library
    from scenes.schema import load_scenario, to_scenario
    from sim.generate import generate

    path = Path(scenario)
    spec = load_scenario(path) if path.suffix in (".yaml", ".yml") else library.get(scenario)
    update: dict[str, Any] = {"seed": seed}
    if frames is not None:
        update |= {"frames": frames, "duration_s": None}
    spec = spec.model_copy(update=update)
    name = hashlib.sha256(spec.model_dump_json().encode()).hexdigest()[:12]
    out = root / "sequences" / f"{spec.name}-{name}"
    if not (out / "meta.json").is_file():
        generate(to_scenario(spec), out, progress=False)
    return out


@pytest.fixture
def depotbench_run(request: pytest.FixtureRequest, depotbench_dir: Path) -> Callable[..., dict[str, Any]]:
    """Call with a scenario (library name or file) and a configuration; returns the run's
    row (ATE, RPE, rho, rejection precision/recall, lost fraction, time ratio to the
    ``none`` run). ``budgets`` (and a ``depotbench_budgets`` marker) are checked."""
    from eval.gates import Check, GateFile, derived_rows, evaluate
    from eval.sweep_run import execute_sweep
    from eval.sweep_spec import SweepSpec

    workers = request.config.getoption("--depotbench-workers")
    marker = request.node.get_closest_marker("depotbench_budgets")
    marked = dict(marker.kwargs) if marker is not None else {}

    def run(
        scenario: str,
        *,
        strategy: str = "box_epipolar_flow",
        frames: int | None = None,
        seed: int = 0,
        detector: str = "groundtruth",
        tracker: str = "builtin",
        settings: dict[str, float] | None = None,
        budgets: dict[str, dict[str, float]] | None = None,
    ) -> dict[str, Any]:
        sequence = _sequence(scenario, frames, seed, depotbench_dir)
        settings = settings or {}
        spec = SweepSpec(
            sweep="pytest",
            sequences=[str(sequence)],
            trackers=[tracker],
            detectors=[detector],
            strategies=sorted({"none", strategy}),
            thresholds={strategy: {k: {"grid": [v]} for k, v in settings.items()}} if settings else {},
        )
        out = depotbench_dir / "runs" / hashlib.sha256(spec.model_dump_json().encode()).hexdigest()[:12]
        out.mkdir(parents=True, exist_ok=True)
        outcome = execute_sweep(spec, out / "spec.yaml", out, workers, progress=False, announce=False)
        wanted = {**marked, **(budgets or {})}
        if wanted:
            check = Check(
                name=f"{Path(scenario).stem}-{strategy}",
                strategies=[strategy],
                settings=settings,
                budgets=wanted,
            )
            _fail_on(evaluate(GateFile(gates="pytest", run=spec, checks=[check]), outcome.rows))
        rows = [
            r
            for r in derived_rows(outcome.rows, "none")
            if r["strategy"] == strategy and (strategy != "none" or r["settings"] == "{}")
        ]
        return rows[0]

    return run
