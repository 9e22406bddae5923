"""depotbench from Python: the command line's jobs as functions on typed values.

Each function takes what its command takes, typed (paths, numbers, the configuration
types of the parts), and returns a typed result instead of printing one:

- ``scenario`` / ``generate`` / ``generate_suite``: scenarios and the sequences they render;
- ``run``: one sequence through a detector and a tracker, as a ``RunRecord``;
- ``sweep``: a sweep spec's matrix into a resumable folder, as a ``SweepResult`` (its typed
  ``SweepSummary`` and ``Configuration``s, ``to_pandas()``);
- ``check``: a gate file's budgets, as a ``GateReport``;
- ``compare``: sets of runs against a base, as ``Comparisons`` (a ``SetComparison`` per set);
- ``report``: the self-contained HTML page of a run or a sweep;
- ``benchmark``: one tracker configuration scored on a frozen benchmark, as a
  ``BenchmarkResult`` (the papers' table, ``to_pandas()``, ``verify()``);
- ``evaluate``: ATE and RPE of an estimate against a reference trajectory.

Inputs are checked as the command line checks them (the same functions do it), and a bad
one raises ``depotbench.core.errors.InputError`` with the one line the command would print.
Nothing here prints except progress bars, which ``progress=False`` turns off.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

# The types of the signatures, imported so that typing.get_type_hints resolves every one
# (about 1 s: OpenCV, SciPy, pydantic). ``import depotbench`` does not load this module
# until a name of the API is first used; MuJoCo and ONNX Runtime load only when a function
# needs them.
from depotbench.core.camera import CameraOverride, Intrinsics
from depotbench.core.main_guard import require_main_guard
from depotbench.detectors.config import DetectorConfig
from depotbench.eval.gates.budgets import GateReport
from depotbench.eval.gates.compare import SetComparison
from depotbench.eval.metrics.evaluate import Comparison, ComparisonOptions
from depotbench.eval.metrics.record import RunRecord
from depotbench.eval.metrics.trajectory import Trajectory
from depotbench.eval.trackers.registry import TrackerConfig
from depotbench.results import (
    BenchmarkResult,
    Comparisons,
    Configuration,
    MissingExtra,
    SweepResult,
    SweepSummary,
)
from depotbench.sim.sequence import Sequence
from depotbench.sim.spec import ScenarioSpec

__all__ = [
    "BenchmarkResult",
    "CameraOverride",
    "Comparison",
    "ComparisonOptions",
    "Comparisons",
    "Configuration",
    "DetectorConfig",
    "GateReport",
    "Intrinsics",
    "MissingExtra",
    "RunRecord",
    "ScenarioSpec",
    "Sequence",
    "SetComparison",
    "Setting",
    "SweepResult",
    "SweepSummary",
    "TrackerConfig",
    "Trajectory",
    "benchmark",
    "check",
    "compare",
    "evaluate",
    "generate",
    "generate_suite",
    "report",
    "run",
    "scenario",
    "sweep",
]

Setting = int | float | str | bool
"""A threshold's or parameter's value (``settings={"max_flow_px": 2.5}``)."""


def scenario(spec: str | Path = "default", **changes: Any) -> ScenarioSpec:
    """A scenario as the simulator takes it: a library name (``depotbench scenarios``), a YAML
    file, or ``"default"``, with top-level fields changed (``seed=3, frames=40``), each checked
    against the schema's limits."""
    from depotbench.scenes.resolve import resolve

    return resolve(spec, changes, option="")


def generate(
    spec: ScenarioSpec | str | Path,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: bool = False,
    **changes: Any,
) -> Sequence:
    """Render a scenario (a ``scenario(...)`` or what ``scenario`` takes, with ``changes``) as
    a sequence folder at ``out``, written whole or not at all; the opened sequence."""
    import dataclasses

    from depotbench.sim.generate import generate as write_sequence

    if isinstance(spec, ScenarioSpec):  # a typed spec: its own checks (__post_init__) hold
        resolved, inputs = dataclasses.replace(spec, **changes), ()
    else:
        resolved = scenario(spec, **changes)
        inputs = (Path(spec),) if Path(spec).exists() else ()  # the output must not replace it
    folder = write_sequence(resolved, Path(out), overwrite=overwrite, progress=progress, inputs=inputs)
    return Sequence.open(folder)


def generate_suite(
    suite: str | Path, out: str | Path, *, workers: int = 1, overwrite: bool = False, progress: bool = False
) -> list[Sequence]:
    """Every variation of a suite file (``scenes/suites/``) rendered under ``out`` (up-to-date
    sequences are kept, held ones copied from the shared sequence store); the sequences in
    the suite's order."""
    from depotbench.scenes.generation import run_suite
    from depotbench.scenes.suite import load_suite

    require_main_guard("workers", workers)
    path, out = Path(suite), Path(out)
    index = run_suite(load_suite(path), path, out, workers, progress=progress, overwrite=overwrite)
    return [Sequence.open(out / entry["name"]) for entry in index["sequences"]]


def _detector(detector: DetectorConfig | str) -> DetectorConfig:
    from depotbench.core.errors import InputError
    from depotbench.detectors.config import DetectorConfigError, parse_detector

    if isinstance(detector, DetectorConfig):
        return detector
    try:
        return parse_detector(detector)
    except DetectorConfigError as exc:
        raise InputError(f"detector: {exc}") from None


def _tracker(tracker: TrackerConfig | str, parameters: Mapping[str, Setting]) -> TrackerConfig:
    from depotbench.core.errors import InputError
    from depotbench.eval.trackers.registry import check as check_tracker
    from depotbench.eval.trackers.registry import tracker_parameters, tracker_type

    if isinstance(tracker, str):
        kind = tracker_type(tracker)
        if parameters and not kind.parameters:
            raise InputError(f"parameters: tracker {kind.name} takes settings, not parameters")
        given = {name: str(value) for name, value in parameters.items()}
        tracker = TrackerConfig(kind.name, parameters=tracker_parameters(kind.name, given))
    elif parameters:
        raise InputError("parameters: give them in the TrackerConfig")
    check_tracker(tracker)
    return tracker


def _settings(settings: Mapping[str, Setting]) -> tuple[tuple[str, int | float | bool], ...]:
    """Threshold values checked against their fields; text (``"2.5"``) is parsed as ``--set`` parses it."""
    from depotbench.core.errors import InputError
    from depotbench.slam.config import ConfigError, parse_setting, setting_value

    try:
        return tuple(
            sorted(
                (name, parse_setting(name, value) if isinstance(value, str) else setting_value(name, value))
                for name, value in settings.items()
            )
        )
    except ConfigError as exc:
        raise InputError(f"settings: {exc}") from None


def _camera(camera: CameraOverride | Intrinsics | str | Path | None) -> CameraOverride | None:
    from depotbench.core.camera import CameraSource
    from depotbench.core.errors import InputError
    from depotbench.sim.camera import read_camera_file

    if camera is None or isinstance(camera, CameraOverride):
        return camera
    if isinstance(camera, Intrinsics):
        return CameraOverride.of(camera, CameraSource.GIVEN, "camera")
    if isinstance(camera, str | Path):
        return read_camera_file(Path(camera))
    raise InputError(
        f"camera: give a CameraOverride, an Intrinsics or a settings file, not {type(camera).__name__}"
    )


def run(
    sequence: Sequence | str | Path,
    out: str | Path | None = None,
    *,
    strategy: str = "none",
    detector: DetectorConfig | str | None = None,
    settings: Mapping[str, Setting] | None = None,
    tracker: TrackerConfig | str = "builtin",
    parameters: Mapping[str, Setting] | None = None,
    overwrite: bool = False,
    progress: bool = False,
    cache: bool = True,
    dense_map: bool = False,
    camera: CameraOverride | Intrinsics | str | Path | None = None,
) -> RunRecord:
    """Track a sequence with a rejection ``strategy``, boxes from ``detector`` (a
    ``DetectorConfig`` or its text, ``"onnx"``, ``"groundtruth+miss=0.3"``; None: the true
    boxes of a generated sequence, none on a real folder with ``strategy="none"``) and threshold
    ``settings``; ``tracker``: a registry name (``builtin``, ``orbslam3``) or a whole
    ``TrackerConfig`` (a ``cmd`` tracker needs its command). With ``out``, the run folder is
    written there (trajectory, frames, metrics, record: what ``depotbench report`` reads);
    without, nothing is written. ``cache``: reuse detections, features and flow from the
    stage cache (``DEPOTBENCH_CACHE``), as the command line does. ``dense_map``: also build
    the run's dense map (map.ply in ``out``) and score it: metrics.json's ``map``. ``camera``:
    a real TUM folder's camera, as ``--camera``/``--intrinsics`` give it: a ``CameraOverride``
    (``depotbench.core.camera``), a whole ``Intrinsics``, or an ORB-SLAM settings file's path;
    a ``Sequence`` opened with one keeps it. Without, a folder named like TUM's gets that
    sensor's calibration, else the ROS default, and a warning says which
    (``logging.getLogger("depotbench")``); metrics.json's ``camera`` records what was used."""
    from depotbench.eval.run.cache import StageCache
    from depotbench.eval.run.harness import RunJob, default_detector, run_job, slam_config

    # The options are checked before the sequence is opened: a misspelt strategy is named
    # as such, not hidden behind what the folder lacks.
    checked_settings = _settings(settings or {})
    checked_tracker = _tracker(tracker, parameters or {})
    slam_config(strategy, dict(checked_settings), checked_tracker.kind)
    root = sequence.root if isinstance(sequence, Sequence) else Path(sequence)
    if camera is None and isinstance(sequence, Sequence):
        camera = sequence.camera_given
    given = _camera(camera)
    job = RunJob(
        root,
        strategy,
        _detector(detector) if detector is not None else default_detector(root, strategy, given),
        checked_settings,
        checked_tracker,
        dense_map,
        given,
    )
    stages = StageCache.from_env() if cache else None
    finished = run_job(
        job, None if out is None else Path(out), progress=progress, overwrite=overwrite, cache=stages
    )
    return finished.record


def sweep(
    spec: str | Path,
    out: str | Path,
    *,
    workers: int = 1,
    progress: bool = False,
    dedupe: bool = True,
    backend: str = "local",
    address: str | None = None,
    retry_failed: bool = False,
) -> SweepResult:
    """A sweep spec's matrix run into the folder ``out`` (resumed where it holds rows;
    ``retry_failed``: failed ones run again): results.sqlite, results.csv, summary.json and
    plots, as ``depotbench sweep`` leaves them. ``workers`` > 1 from a script: its code under
    ``if __name__ == "__main__":`` (each spawned worker imports the script again)."""
    from depotbench.core.examples import Kind, find
    from depotbench.eval.metrics.figures import with_derived
    from depotbench.eval.sweep.execute import sweep_folder

    if backend == "local":
        require_main_guard("workers", workers)
    out = Path(out)
    outcome = sweep_folder(
        find(spec, Kind.SWEEP),  # a file, or a shipped spec's name ("smallest")
        out,
        workers,
        progress=progress,
        dedupe=dedupe,
        backend=backend,
        address=address,
        retry_failed=retry_failed,
    )
    summary = SweepSummary.of(outcome.summary)
    return SweepResult(
        out,
        outcome.records,
        with_derived(
            outcome.records, summary.baseline
        ),  # rho against the spec's baseline, as in summary.json
        summary,
        outcome.written,
        outcome.plots,
    )


def check(
    gates: str | Path,
    out: str | Path,
    *,
    baseline: str | Path | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    retry_failed: bool = False,
) -> GateReport:
    """A gate file's matrix run into ``out`` (resumed; ``retry_failed``: failed rows run
    again) and its budgets checked; ``baseline``: an earlier check's or sweep's folder, for
    ``vs_baseline`` budgets. The report's ``passed``
    and ``failures`` say what ``depotbench check`` would exit with and print."""
    from depotbench.core.examples import Kind, find
    from depotbench.eval.gates.check import check_folder, open_gates

    if backend == "local":
        require_main_guard("workers", workers)
    opened = open_gates(find(gates, Kind.GATES), None if baseline is None else Path(baseline))
    return check_folder(opened, Path(out), workers, backend, address, retry_failed)


def compare(base: str | Path, *others: str | Path) -> Comparisons:
    """Each folder of ``others`` (a sweep's or a check's) against ``base``, run by run paired by
    sequence: per figure the change, its 95 % interval and whether it is significant; a
    mapping of each folder to its ``SetComparison``, with ``to_pandas()``."""
    from depotbench.core.errors import InputError
    from depotbench.eval.gates.compare import compare_rows, load_rows

    if not others:
        raise InputError("compare needs two folders or more: the base, then what to compare with it")
    rows = load_rows(Path(base))
    return Comparisons(
        Path(base), {Path(other): compare_rows(rows, load_rows(Path(other))) for other in others}
    )


def report(source: str | Path, out: str | Path, workers: int = 1) -> Path:
    """The self-contained HTML page of a run folder or a sweep folder, written as
    ``out``/index.html (a folder of depotbench reports, or a new or empty one); its path.
    ``workers``: processes that track a sweep's featured runs again (from 300 frames in all)."""
    from depotbench.eval.report.write import report_folder

    require_main_guard("workers", workers)
    return report_folder(Path(source), Path(out), workers=workers).page


def benchmark(
    name: str | Path,
    out: str | Path,
    *,
    tracker: TrackerConfig | str = "builtin",
    strategy: str = "none",
    detector: DetectorConfig | str = "groundtruth",
    settings: Mapping[str, Setting] | None = None,
    parameters: Mapping[str, Setting] | None = None,
    repeats: int | None = None,
    deterministic: bool | None = None,
    fresh_seeds: int = 0,
    entropy: int | None = None,
    sequences: str | Path | None = None,
    workers: int = 1,
    progress: bool = False,
) -> BenchmarkResult:
    """One tracker configuration scored on a frozen benchmark (``tum-dyn-1``, ``depot-1``,
    ``smoke-1`` or a benchmark file), as ``depotbench benchmark run`` does: its sequences
    generated or reused under ``out/sequences`` and checked against its lock, each run
    ``repeats`` times where the tracker is not deterministic (ORB-SLAM3 always; a ``cmd``
    program when ``deterministic=False``), results.json written. ``fresh_seeds``: as many new
    seeds a scenario scored beside them (``entropy`` draws the same ones again).
    ``sequences``: a folder that keeps the sequences instead of ``out/sequences``, shared by
    the scores of several trackers (``--sequences``)."""
    from depotbench.core.errors import InputError
    from depotbench.eval.benchmark.runner import Plan, repeats_for, run_benchmark
    from depotbench.eval.benchmark.spec import load_benchmark
    from depotbench.eval.run.harness import STRATEGY_CHOICES, RunJob

    require_main_guard("workers", workers)
    if strategy not in STRATEGY_CHOICES:
        raise InputError(f"strategy: {strategy!r}; choose from {', '.join(STRATEGY_CHOICES)}")
    config = _tracker(tracker, parameters or {})
    if deterministic is None:
        deterministic = not config.type.external or config.type.command
    elif deterministic and config.kind == "orbslam3":
        raise InputError("deterministic: ORB-SLAM3's runs differ from one another; it is repeated")
    job = RunJob(Path("."), strategy, _detector(detector), _settings(settings or {}), config)
    plan = Plan(job, repeats_for(deterministic, repeats), deterministic)
    run_benchmark(
        load_benchmark(name),
        plan,
        Path(out),
        workers,
        progress,
        fresh_seeds=fresh_seeds,
        entropy=entropy,
        sequences_root=None if sequences is None else Path(sequences),
    )
    return BenchmarkResult.read(Path(out))


def evaluate(
    reference: Trajectory | str | Path,
    estimate: Trajectory | str | Path,
    options: ComparisonOptions | None = None,
) -> Comparison:
    """ATE and RPE of ``estimate`` against ``reference`` (TUM files or trajectories), associated
    by time and aligned as ``options`` say (SE(3) by default): what ``depotbench eval`` prints."""
    from depotbench.eval.metrics.evaluate import compare as compare_trajectories
    from depotbench.eval.metrics.trajectory import read_tum

    def opened(value: Trajectory | str | Path) -> Trajectory:
        return value if isinstance(value, Trajectory) else read_tum(value)

    return compare_trajectories(opened(reference), opened(estimate), options or ComparisonOptions())
