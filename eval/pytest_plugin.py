"""depotbench as a pytest plugin (registered on install): gates and runs as fixtures.

```python
@pytest.mark.depotbench_gates("gates/crowd.yaml")
def test_crowd_gates(depotbench_gates):
    ...  # the gate file ran before the body; the test failed naming each failed budget

def test_crowd(depotbench_run):
    run = depotbench_run("crowd", strategy="box_epipolar_flow", frames=60, seed=3,
                         budgets={"ate_rmse_m": {"max": 0.05}, "rejection_recall": {"min": 0.8}})
    assert run.rho_percent > 20  # a ScoredRun: its record and the derived figures

@pytest.mark.depotbench_budgets(ate_rmse_m={"max": 0.05})
def test_walking(depotbench_run):
    depotbench_run("walking_static", strategy="box_epipolar_flow")  # checked against the marker
```

Sequences are generated once per session (and the stage cache serves every run), copied
from the shared sequence store when it holds them, so a later session renders nothing;
``--depotbench-dir`` keeps them between sessions, and pytest-xdist workers may share it
(one of them makes a sequence or run while the others wait for it). A configuration that
cannot run (a strategy the tracker does not take, an unknown setting) is refused in one
line before anything is generated.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from depotbench.core.errors import InputError
from depotbench.core.output import OutputLock

if TYPE_CHECKING:
    from depotbench.eval.metrics.figures import ScoredRun
    from depotbench.eval.sweep.spec import SweepSpec
    from depotbench.sim.spec import ScenarioSpec


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
    group.addoption(
        "--depotbench-retry-failed",
        action="store_true",
        help="run failed rows kept in --depotbench-dir again instead of reusing them",
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "depotbench_gates(path): run this gate file; fail naming each failed budget"
    )
    config.addinivalue_line(
        "markers", "depotbench_budgets(**budgets): budgets every depotbench_run of the test must hold"
    )


def _bench_dir(config: pytest.Config) -> Path | None:
    """``--depotbench-dir`` as an absolute path, resolved once against the folder pytest
    started in: a sweep resolves a relative ``sequences:`` entry against its spec's folder
    (``runs/HASH/``, not the working directory), and a test may change directory."""
    chosen = config.getoption("--depotbench-dir")
    if not chosen:
        return None
    return (config.invocation_params.dir / Path(chosen).expanduser()).resolve()


@pytest.fixture(scope="session")
def depotbench_dir(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = _bench_dir(request.config)
    if path is None:
        return tmp_path_factory.mktemp("depotbench").resolve()
    path.mkdir(parents=True, exist_ok=True)
    return path


def _claim(target: Path) -> OutputLock:
    """An exclusive claim on ``target`` across processes, waiting for its holder: pytest-xdist
    workers sharing ``--depotbench-dir`` ask for the same sequence or run at once.

    It is ``.NAME.claim.lock``, not the target's own ``.NAME.lock``: the writer
    (``depotbench.core.output.StagedOutput``) takes that one without waiting, and a second ``flock``
    on it from this process would be refused."""
    target.parent.mkdir(parents=True, exist_ok=True)
    return OutputLock(target.with_name(f"{target.name}.claim"), wait=True)


def _beside_test(request: pytest.FixtureRequest, path: Path) -> Path:
    """A path a test names, relative to the test's file (as every path of a spec is to its
    file); one given relative to pytest's rootdir, as 0.3 resolved them, is still found."""
    path = path.expanduser()
    if path.is_absolute():
        return path
    beside = request.path.parent / path
    if beside.exists():
        return beside
    from_root = Path(request.config.rootpath) / path
    return from_root if from_root.exists() else beside


def _fail_on(report) -> None:
    if not report.passed:
        pytest.fail("depotbench budgets failed:\n" + "\n".join(report.failures), pytrace=False)


@pytest.fixture
def depotbench_gates(request: pytest.FixtureRequest, depotbench_dir: Path) -> Callable[..., Any]:
    """Call with a gate file to run and check it (``check=False`` returns the report
    without failing). A test marked ``depotbench_gates(path)`` runs that file first."""
    from depotbench.eval.gates.budgets import load_gates
    from depotbench.eval.gates.check import run_gates
    from depotbench.eval.sweep.engine import validate

    workers = request.config.getoption("--depotbench-workers")

    def run(path: str | Path, check: bool = True):
        path = _beside_test(request, Path(path))
        gates = load_gates(path)
        validate(gates.run, path)
        out = depotbench_dir / f"gates-{gates.gates}"
        with _claim(out):  # a suite's folder refuses a second writer: wait for it instead
            report = run_gates(gates, path, out, workers)
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


@dataclass(frozen=True)
class _Sequence:
    """The sequence a run asks for: the simulator's spec, its folder and its content key."""

    scenario: ScenarioSpec
    path: Path
    key: str


def _plan_sequence(scenario: str, frames: int | None, seed: int, root: Path, job: str) -> _Sequence:
    """Where ``scenario`` (a library name or a YAML file) with this seed and length lives
    under ``root``: named by a hash of the scenario, so no work is needed to know it. The
    seed and length are checked as a scenario file's would be (``frames=0`` is refused)."""
    from depotbench.scenes import library
    from depotbench.scenes.schema import Scenario, load_scenario, to_scenario, validate_model
    from depotbench.sim.spec import content_key

    path = Path(scenario)
    spec = load_scenario(path) if path.suffix in (".yaml", ".yml") else library.get(scenario)
    update: dict[str, Any] = {"seed": seed}
    if frames is not None:
        update |= {"frames": frames, "duration_s": None}
    spec = validate_model(Scenario, spec.model_dump() | update, job)
    name = hashlib.sha256(spec.model_dump_json().encode()).hexdigest()[:12]
    simulated = to_scenario(spec)
    return _Sequence(simulated, root / "sequences" / f"{spec.name}-{name}", content_key(simulated))


def _generate(sequence: _Sequence) -> None:
    """Generate the sequence unless it is complete and current (its marker holds this
    content key, as ``depotbench.scenes.generation`` decides); one process at a time. A sequence the
    shared store (``depotbench.scenes.store``) holds is copied from it, and one rendered is added to
    it: a second session, even with a fresh ``--depotbench-dir``, renders nothing."""
    from depotbench.scenes.generation import is_complete
    from depotbench.scenes.store import SequenceStore
    from depotbench.sim.generate import generate

    if is_complete(sequence.path, sequence.key):
        return
    with _claim(sequence.path):
        # Another process may have written it while this one waited for the claim.
        if is_complete(sequence.path, sequence.key):
            return
        store = SequenceStore.from_env()
        if store is not None and store.fetch(sequence.key, sequence.path):
            return
        generate(sequence.scenario, sequence.path, progress=False, overwrite=True)
        if store is not None:
            store.put(sequence.path, sequence.key)


def _check_configuration(spec: SweepSpec, spec_path: Path, job: str) -> None:
    """Refuse what cannot run as asked, before any generation or vocabulary build: the
    sweep's own checks of trackers and detectors, and every job it will run checked
    against the tracker (the sweep skips those an external tracker cannot run, and then
    no row comes back)."""
    from depotbench.eval.run.harness import slam_config
    from depotbench.eval.sweep.spec import detector_configs, tracker_configs, tracker_variants, variants

    try:
        trackers = tracker_configs(spec, str(spec_path))
        tracker_variants(spec, trackers, str(spec_path))
    except InputError as exc:
        raise InputError(f"{job}: {str(exc).removeprefix(str(spec_path) + ': ')}") from None
    detector_configs(spec, job)
    for variant in variants(spec):
        for tracker in trackers:
            try:
                slam_config(variant.strategy, dict(variant.settings), tracker.kind)
            except InputError as exc:
                raise InputError(f"{job}: {exc}") from None


def the_row(rows: list[ScoredRun], strategy: str, job: str) -> ScoredRun:
    """The run of ``strategy`` (for ``none``, the bare baseline) among a matrix's scored runs."""
    from depotbench.eval.metrics.figures import is_baseline

    found = [r for r in rows if r["strategy"] == strategy and (strategy != "none" or is_baseline(r))]
    if not found:
        raise InputError(
            f"{job}: the run matrix gave no row for strategy {strategy!r} "
            f"(rows for: {', '.join(sorted({r['strategy'] for r in rows})) or 'nothing'})"
        )
    return found[0]


@pytest.fixture
def depotbench_run(request: pytest.FixtureRequest, depotbench_dir: Path) -> Callable[..., ScoredRun]:
    """Call with a scenario (library name or file) and a configuration; returns the run as a
    ``ScoredRun``: its record (ATE, RPE, rejection precision/recall, ...) with rho, the
    lost fraction and the time ratio to the ``none`` run (``run.rho_percent`` or
    ``run["rho_percent"]``). ``budgets`` (and a ``depotbench_budgets`` marker) are checked.
    Everything is checked before any work: a configuration that cannot run is refused
    in one line, before a sequence is generated or a vocabulary built."""
    from depotbench.eval.gates.budgets import Check, GateFile, derived_rows, evaluate
    from depotbench.eval.sweep.execute import execute_sweep
    from depotbench.eval.sweep.spec import SweepSpec
    from depotbench.scenes.schema import validate_model

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
        tracker: str | dict[str, Any] = "builtin",
        settings: dict[str, float] | None = None,
        parameters: dict[str, float | str] | None = None,
        budgets: dict[str, dict[str, float]] | None = None,
    ) -> ScoredRun:
        """``tracker``: builtin, orbslam3, or an external tracker as a sweep spec gives one
        (a mapping: name, command, parameters, settings, timeout_s, env; paths relative to
        the test's file); ``parameters``: its parameter values for this run."""
        name = tracker if isinstance(tracker, str) else str(tracker.get("name"))
        job = f"depotbench_run({scenario!r}, strategy={strategy!r}, tracker={name!r})"
        settings, parameters = settings or {}, parameters or {}
        if parameters and isinstance(tracker, str):
            raise InputError(f"{job}: parameters are an external tracker's; give the tracker as a mapping")
        if Path(scenario).suffix in (".yaml", ".yml"):
            scenario = str(_beside_test(request, Path(scenario)))
        sequence = _plan_sequence(scenario, frames, seed, depotbench_dir, job)
        data = {
            "sweep": "pytest",
            "sequences": [str(sequence.path)],  # absolute: see _bench_dir
            "trackers": [tracker],
            "detectors": [detector],
            "strategies": sorted({"none", strategy}),
            "thresholds": {strategy: {k: {"grid": [v]} for k, v in settings.items()}} if settings else {},
            "parameters": {name: {k: {"grid": [v]} for k, v in parameters.items()}} if parameters else {},
        }
        spec = validate_model(SweepSpec, data, job)
        spec_path = request.path.parent / "depotbench_run.yaml"  # where a tracker's relative paths start
        _check_configuration(spec, spec_path, job)
        wanted = {**marked, **(budgets or {})}
        gates = None
        if wanted:
            check = {
                "name": f"{Path(scenario).stem}-{strategy}",
                "strategies": [strategy],
                "settings": settings,
                "parameters": parameters,
                "budgets": wanted,
            }
            gates = GateFile(gates="pytest", run=spec, checks=[validate_model(Check, check, job)])
        _generate(sequence)
        key = hashlib.sha256((spec.model_dump_json() + str(spec_path)).encode()).hexdigest()[:12]
        out = depotbench_dir / "runs" / key
        with _claim(out):  # two processes with one spec share its results database
            retry = request.config.getoption("--depotbench-retry-failed")
            outcome = execute_sweep(
                spec, spec_path, out, workers, progress=False, announce=False, retry_failed=retry
            )
        if gates is not None:
            _fail_on(evaluate(gates, outcome.records))
        return the_row(derived_rows(outcome.records, "none"), strategy, job)

    return run
