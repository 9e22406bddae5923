"""Run a sequence through a detector and a tracker, and leave machine-readable results.

``run_sequence`` is a pure function of (sequence, tracker, detector, strategy,
settings) for the built-in tracker; it writes ``trajectory.txt`` (TUM),
``frames.csv`` (per frame: state and tracking time), ``diagnostics.npz`` (the
built-in tracker's per-keypoint facts) and ``metrics.json`` into a staged folder
swapped into place when complete.

Trackers: the built-in pipeline takes every rejection strategy; ORB-SLAM3 and
external commands take no boxes, so they run with ``none`` or ``mask`` (dynamic
boxes blanked in RGB and depth before the frames reach them).
"""

from __future__ import annotations

import functools
import logging
import re
import shlex
import shutil
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from depotbench.core.camera import CameraOverride, Intrinsics, camera_json
from depotbench.core.errors import InputError
from depotbench.core.files import dumps_json, file_digest
from depotbench.core.logs import timed
from depotbench.core.output import OutputKind, StagedOutput
from depotbench.core.path_text import path_text
from depotbench.core.version import code_version
from depotbench.detectors.config import DetectorConfig, DetectorKind
from depotbench.eval.metrics.evaluate import Comparison, ComparisonOptions, compare
from depotbench.eval.metrics.record import RECORD_VERSION, RunIdentity, RunRecord
from depotbench.eval.metrics.trajectory import Trajectory, write_tum
from depotbench.eval.run.cache import StageCache, content_hash
from depotbench.eval.run.dense import RunMap, run_map
from depotbench.eval.run.detections import SequenceDetections, detect_sequence, sequence_fingerprint
from depotbench.eval.run.stages import FrameStages, features_key, sequence_stages
from depotbench.eval.trackers.base import TrackerError, TrackerRun
from depotbench.eval.trackers.builtin import BuiltinTracker, camera_of
from depotbench.eval.trackers.evidence import write_evidence
from depotbench.eval.trackers.frames import FrameSource, MaskSettings
from depotbench.eval.trackers.registry import BUILTIN, TrackerConfig, tracker_type
from depotbench.eval.trackers.registry import build as build_tracker
from depotbench.sim.sequence import Sequence
from depotbench.slam import kernels
from depotbench.slam.config import ConfigError, Setting, SlamConfig, TrackingConfig, check_pyramid
from depotbench.slam.dense_map import write_ply
from depotbench.slam.rejection import STRATEGIES
from depotbench.slam.types import REJECTION_CODES, FrameResult, Rejection, TrackingState

MASK = "mask"
STRATEGY_CHOICES = (*STRATEGIES, MASK)
EXTERNAL_STRATEGIES = ("none", MASK)
FLOW_STRATEGIES = ("prior_flow", "box_epipolar_flow")
MASK_SETTINGS = ("box_dilation_px", "min_confidence")
"""The only settings that apply to external trackers: they shape the mask."""
log = logging.getLogger("depotbench.camera")
LOG = logging.getLogger(__name__)


def maps_itself(tracker: TrackerConfig) -> bool:
    """Whether a run of ``tracker`` has a map to score: the built-in tracker builds one from its
    keyframes, ORB-SLAM3 gives its map points, a command program may write one at ``{map}``."""
    return tracker.type.maps or (tracker.type.command and "{map}" in (tracker.command or ""))


def slam_config(strategy: str, settings: Mapping[str, Setting], tracker: str = BUILTIN) -> SlamConfig:
    """The strategy and its settings (typed: ``--set`` text is parsed where it comes in),
    checked against what the tracker (a registry name) can use."""
    if strategy not in STRATEGY_CHOICES:
        raise InputError(f"unknown strategy {strategy!r}; choose one of {', '.join(STRATEGY_CHOICES)}")
    if not tracker_type(tracker).per_keypoint:
        if strategy not in EXTERNAL_STRATEGIES:
            raise InputError(
                f"--strategy {strategy} needs the built-in tracker (it decides per keypoint); "
                f"--slam {tracker} takes {' or '.join(EXTERNAL_STRATEGIES)}"
            )
        extra = sorted(set(settings) - set(MASK_SETTINGS))
        if extra:
            raise InputError(f"--set {extra[0]}: --slam {tracker} takes only {', '.join(MASK_SETTINGS)}")
    try:
        return SlamConfig(strategy="none" if strategy == MASK else strategy).with_settings(settings)
    except ConfigError as exc:
        raise InputError(f"--set: {exc}") from None


@dataclass(frozen=True)
class RunJob:
    """One run: a sequence through a detector and a tracker with a strategy and settings.

    Everything here is parsed and typed; the CLI, the demo, sweeps and benchmarks
    build these, and ``track`` / ``run_sequence`` execute them.
    """

    sequence: Path
    strategy: str
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    settings: tuple[tuple[str, Setting], ...] = ()
    """Threshold overrides by name (``--set``), typed, sorted."""
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    dense_map: bool = False
    """Also build the run's dense map from its keyframes and score it (``eval/run/dense.py``)."""
    camera: CameraOverride | None = None
    """The camera of a real TUM folder (``--camera``, ``--intrinsics``), replacing the guess its
    name gives (``Sequence.open``); every tracker reads it from the opened sequence."""


@dataclass(frozen=True)
class Tracked:
    """What ``track`` returns: the metrics and the run they came from."""

    metrics: dict[str, Any]
    run: TrackerRun
    header: str
    map: RunMap | None = None
    decisions: tuple[list[np.ndarray], list[np.ndarray]] | None = None
    """``frame_decisions`` of the run, labelled once for its metrics, frames.csv and diagnostics."""


def prepare(job: RunJob, sequence: Sequence | None = None) -> tuple[Sequence, SlamConfig]:
    """Open and check everything before any work: the sequence (unless given, already
    open), settings, detector use."""
    config = slam_config(job.strategy, dict(job.settings), job.tracker.kind)
    per_keypoint = job.tracker.type.per_keypoint
    if sequence is None or sequence.root != Path(job.sequence) or sequence.camera_given != job.camera:
        sequence = Sequence.open(job.sequence, camera=job.camera)
    if sequence.camera_warning is not None:
        _warn_once(sequence.camera_warning)
    if job.strategy == MASK and job.detector.kind is DetectorKind.NONE:
        raise InputError("--strategy mask needs boxes: give a detector (not --detector none)")
    if job.dense_map and not maps_itself(job.tracker):
        raise InputError(
            f"--map needs a tracker with a map: the built-in one, ORB-SLAM3, or a --command that "
            f"writes {{map}}; --slam {job.tracker.kind} gives none"
        )
    if per_keypoint:  # the bench's own front end: its pyramid must fit the image
        camera = camera_of(sequence)
        try:
            check_pyramid(config.tracking, camera.width, camera.height)
        except ConfigError as exc:
            raise InputError(f"--set: {exc}") from None
    return sequence, config


BOXLESS_STRATEGIES = ("none",)
"""The strategies that decide nothing from boxes: on a real folder they need no detector."""


def default_detector(
    sequence_dir: Path, strategy: str, camera: CameraOverride | None = None
) -> DetectorConfig:
    """The detector of a run that names none: the true boxes of a generated sequence. A real
    TUM folder has no ground truth to draw boxes from, so there a strategy that uses no boxes
    runs with no detector, and one that does is refused in one line naming what to give."""
    sequence = Sequence.open(sequence_dir, camera=camera)
    if sequence.is_generated:
        return DetectorConfig()
    if strategy in BOXLESS_STRATEGIES:
        return DetectorConfig(DetectorKind.NONE)
    raise InputError(
        f"{sequence.root}: --strategy {strategy} needs boxes, and a real folder has no ground truth "
        "to draw them from: give --detector onnx (the shipped YOLOX-nano) or onnx:PATH"
    )


@functools.cache
def _warn_once(message: str) -> None:
    """A guessed camera is said once per folder and process: a sweep prepares each of its
    jobs, and 40 jobs on one folder would print the same line 40 times."""
    log.warning(message)


def _execute(
    job: RunJob, sequence: Sequence, config: SlamConfig, cache: StageCache | None, progress: bool
) -> Tracked:
    mask = MaskSettings(config.rejection.box_dilation_px, config.rejection.min_confidence)
    what = f"{sequence.root.name} {job.tracker.label} {job.strategy}"
    with timed(LOG, f"{what}: detections ({job.detector.label})"):
        detections = detect_sequence(sequence, job.detector, cache, progress)
    boxes = detections.per_frame if detections is not None else None
    frames = FrameSource(sequence, boxes, mask if job.strategy == MASK else None)
    stages = None
    if uses_stages(job) and cache is not None:
        with timed(LOG, f"{what}: features and flow"):
            stages = stages_for(sequence, config, cache, progress)
    with timed(LOG, f"{what}: tracking {len(sequence)} frames"):
        run = build_tracker(job.tracker, config, progress, stages).run(frames, progress)
    with timed(LOG, f"{what}: metrics"):
        return _tracked(job, sequence, frames, run, config, detections)


def _tracked(
    job: RunJob,
    sequence: Sequence,
    frames: FrameSource,
    run: TrackerRun,
    config: SlamConfig,
    detections: SequenceDetections | None,
) -> Tracked:
    """A finished run's metrics, with its dense map and the map's scores where the job asks."""
    truth = _against_truth(sequence, run)
    decisions = frame_decisions(sequence, run)
    metrics = _metrics(
        sequence, run, config, job.strategy, job.detector, detections, job.tracker, truth, decisions
    )
    dense = run_map(frames, run, config, job.strategy) if job.dense_map else None
    if dense is not None:
        metrics["map"] = dense.figures()
    return Tracked(metrics, run, _header(job), dense, decisions)


def uses_stages(job: RunJob) -> bool:
    """Whether the run can take cached features and flow (the built-in tracker, not ``mask``)."""
    return job.tracker.type.per_keypoint and job.strategy != MASK


def stages_for(
    sequence: Sequence, config: SlamConfig, cache: StageCache | None, progress: bool = False
) -> list[FrameStages]:
    """The features (and, for flow strategies, the flow) of every frame; they do not depend
    on rejection thresholds, so the cache computes them once."""
    need_flow = config.strategy in FLOW_STRATEGIES
    return sequence_stages(sequence, config.tracking, config.rejection, need_flow, cache, progress)


def track(job: RunJob, cache: StageCache | None = None, progress: bool = False) -> Tracked:
    """Run a job and return its metrics, writing nothing (sweeps keep rows, not folders)."""
    sequence, config = prepare(job)
    return _execute(job, sequence, config, cache, progress)


def branch_root(job: RunJob, features: str, config: SlamConfig) -> str:
    """What jobs must share to be tracked as one branching run (``track_tree``): the
    sequence and tracking settings (``features``, ``stages.features_key``), detector (with
    faults), strategy and flow stage; they may differ in rejection thresholds only."""
    flow = (config.rejection.lk_window_px, config.rejection.lk_levels)
    return content_hash(
        features,
        job.detector.key(),
        job.detector.faults.to_dict(),
        job.strategy,
        flow,
    )


def track_tree(jobs: list[RunJob], paths: list[tuple[str, ...]], cache: StageCache) -> list[Tracked]:
    """Track jobs of one ``branch_root`` together: once while they keep the same keypoints
    (``paths``: per job and frame, ``depotbench.eval.run.stages.decision_path``), forked where they part.
    Each result equals the job's own ``track``, timings aside."""
    sequence = Sequence.open(jobs[0].sequence, camera=jobs[0].camera)
    prepared = [prepare(job, sequence) for job in jobs]
    first = prepared[0][1]
    features: dict[TrackingConfig, str] = {}
    for _, config in prepared:  # a fingerprint stats every frame file: once per tracking setting
        if config.tracking not in features:
            features[config.tracking] = features_key(sequence, config.tracking)
    roots = {
        branch_root(job, features[config.tracking], config)
        for job, (_, config) in zip(jobs, prepared, strict=True)
    }
    same_sequence = all(seq is sequence for seq, _ in prepared)
    if not same_sequence or len(roots) != 1 or not all(uses_stages(job) for job in jobs):
        raise ValueError("track_tree takes built-in jobs that differ in rejection thresholds only")
    configs = [config for _, config in prepared]
    detections = detect_sequence(sequence, jobs[0].detector, cache)
    frames = FrameSource(sequence, detections.per_frame if detections is not None else None)
    runs = BuiltinTracker(first, stages_for(sequence, first, cache)).run_tree(frames, configs, paths)
    return [
        _tracked(job, sequence, frames, run, config, detections)
        for job, config, run in zip(jobs, configs, runs, strict=True)
    ]


def _header(job: RunJob) -> str:
    return f"depotbench {job.tracker.kind}, strategy {job.strategy}, detector {job.detector.label}"


def tracker_identity(tracker: TrackerConfig) -> tuple[tuple[str, Any], ...]:
    """What of an external tracker shapes its results: the command template, the bytes of
    the program it starts, of every other file its command names (``command_files``: an
    interpreter's script, a config file) and of the vocabulary it is given (a rebuilt
    program, an edited script or another vocabulary is a new run, not a row to resume). A
    sweep computes it once per tracker: ORB-SLAM's own vocabulary is 145 MB. The built-in's
    program is depotbench itself: its ``code_version``, so that a folder swept by two
    releases (or two states of a checkout) holds two versions of it, kept apart as any
    program's, not one set whose rows a baseline would mix."""
    identity: dict[str, Any] = {"kind": tracker.kind}
    if not tracker.type.external:
        return tuple((identity | {"version": code_version()}).items())
    identity |= {
        "name": tracker.label,
        "timeout_s": tracker.timeout_s,
        "parameters": tracker.parameters,
        "env": tracker.env,
    }
    if tracker.settings_template is not None:
        identity["settings_template_sha256"] = file_digest(
            tracker.settings_template, "settings template"
        ).hex()
    if tracker.command:
        identity["command"] = tracker.command
        program = _program_path(tracker.command)
        identity["program_sha256"] = file_digest(program, "program").hex() if program else None
        named = command_files(tracker.command, tracker.label)
        if named:  # a command naming no file keeps the identity (and the keys) it had
            identity["command_files_sha256"] = tuple(
                (word, file_digest(path, "file the command names").hex()) for word, path in named
            )
    if tracker.vocabulary is not None:
        identity["vocabulary"] = str(tracker.vocabulary.resolve())
        identity["vocabulary_sha256"] = file_digest(tracker.vocabulary, "vocabulary").hex()
    return tuple(sorted(identity.items()))


FINGERPRINT_CHARS = 12
"""A tracker fingerprint's length in hex digits: 48 bits, so two program versions of one
tracker collide with odds of about 1 in 10^14."""


def tracker_fingerprint(identity: tuple[tuple[str, Any], ...]) -> str:
    """A short content hash of ``tracker_identity`` but its parameters: every row carries it,
    so that rows of two versions of one program (one tracker label) are told apart and never
    paired or averaged together. Parameters are left out: a sweep over them runs one program,
    and each value is a configuration of its own (the row's ``parameters``)."""
    version = [(name, value) for name, value in identity if name != "parameters"]
    return content_hash("tracker", version)[:FINGERPRINT_CHARS]


def _program_path(command: str) -> Path | None:
    """The file a command template starts (None when it cannot be found: the run says so)."""
    try:
        words = shlex.split(command)
    except ValueError:
        return None
    found = shutil.which(words[0]) if words else None
    return Path(found) if found else None


COMMAND_FILES_MAX_BYTES = 4 << 30
"""What the files a command names (its program aside) may total: each sweep hashes them once
per tracker, and 4 GiB take about 3 s at SHA-256's 1.5 GB/s; a command naming more (a data
set as an argument) is refused rather than keyed by anything weaker than content."""


def command_files(command: str, label: str = "command") -> list[tuple[str, Path]]:
    """The regular files a command template names after its program word, as (word, path):
    a word, or the value after the first ``=`` of an ``--option=value`` word, that names an
    existing regular file from the folder the bench was started in (as the program word is
    found). A word with a placeholder is the job's own input, keyed apart; a directory is
    keyed by its name only (the command text), never by its content."""
    try:
        words = shlex.split(command)
    except ValueError:
        return []
    found: dict[str, Path] = {}
    for word in words[1:]:
        for candidate in (word, word.partition("=")[2] if word.startswith("-") else ""):
            if not candidate or "{" in candidate or candidate in found:
                continue
            path = Path(candidate) if Path(candidate).is_absolute() else Path.cwd() / candidate
            try:
                if path.is_file():
                    found[candidate] = path
            except OSError:  # a name too long, a loop of links: not a file the key can cover
                continue
    total = sum(path.stat().st_size for path in found.values())
    if total > COMMAND_FILES_MAX_BYTES:
        raise InputError(
            f"tracker {label}: the files its command names total {total} bytes, over the "
            f"{COMMAND_FILES_MAX_BYTES} a row key hashes; name a large input's folder instead "
            "(a folder is keyed by its name)"
        )
    return sorted(found.items())


def job_key(
    fingerprint: str,
    tracker: tuple[tuple[str, Any], ...],
    detector: DetectorConfig,
    strategy: str,
    settings,
    dense_map: bool = False,
    camera: Intrinsics | None = None,
) -> str:
    """A run's identity: its inputs' content (the sequence fingerprint), the tracker (with
    its program and vocabulary), detector with faults, strategy, settings, the bench's
    code (``code_version``), and the camera where one was given for a real folder (the same folder with
    another calibration is another run; without one the key is what it was)."""
    return content_hash(
        RECORD_VERSION,
        code_version(),
        fingerprint,
        tracker,
        detector.key(),
        detector.faults.to_dict(),
        strategy,
        list(settings),
        *(["dense_map"] if dense_map else []),  # a run with its map is another run's record
        *([("camera", repr(camera))] if camera is not None else []),
    )


def family_of(sequence: Sequence) -> str:
    """A sequence's scenario name (a suite variation's number dropped), or its folder's name."""
    scenario = (sequence.meta or {}).get("scenario") or {}
    name = scenario.get("name") if isinstance(scenario, dict) else None
    return re.sub(r"-\d{4}$", "", str(name)) if name else sequence.root.name


def seed_of(sequence: Sequence) -> int | None:
    """A generated sequence's scenario seed (None for a real TUM folder)."""
    seed = (sequence.meta or {}).get("seed")
    return seed if isinstance(seed, int) and not isinstance(seed, bool) else None


def identity_of(
    job: RunJob,
    key: str,
    family: str,
    stored: str,
    fingerprint: str,
    seed: int | None,
    knobs: dict[str, Any] | None = None,
    tracker_fingerprint: str | None = None,
) -> RunIdentity:
    """What a row records of a job besides its results (``tracker_fingerprint``: of the
    job's ``tracker_identity``, computed once per tracker by the caller)."""
    return RunIdentity(
        key=key,
        family=family,
        sequence=stored,
        fingerprint=fingerprint,
        tracker=job.tracker.label,
        detector=job.detector.label,
        strategy=job.strategy,
        settings=job.settings,
        parameters=job.tracker.parameters,
        detector_config=job.detector.to_dict(),
        seed=seed,
        knobs=knobs or {},
        tracker_fingerprint=tracker_fingerprint,
    )


def record_of(job: RunJob, sequence: Sequence, metrics: dict[str, Any]) -> RunRecord:
    """The typed row of a single run (what a sweep stores for it)."""
    return RunRecord.of_run(run_identity(job, sequence), metrics, code_version())


def run_identity(job: RunJob, sequence: Sequence) -> RunIdentity:
    """What the row of a single run records of it besides its results."""
    fingerprint = sequence_fingerprint(sequence)
    camera = sequence.intrinsics if job.camera is not None else None
    tracker = tracker_identity(job.tracker)
    key = job_key(
        fingerprint,
        tracker,
        job.detector,
        job.strategy,
        job.settings,
        job.dense_map,
        camera,
    )
    stored = path_text(sequence.root.resolve())
    family, seed = family_of(sequence), seed_of(sequence)
    return identity_of(job, key, family, stored, fingerprint, seed, None, tracker_fingerprint(tracker))


def run_sequence(
    sequence_dir: Path,
    out_dir: Path,
    strategy: str,
    detector: DetectorConfig | None = None,
    settings: Mapping[str, Setting] | None = None,
    progress: bool = True,
    overwrite: bool = False,
    tracker: TrackerConfig | None = None,
    cache: StageCache | None = None,
    dense_map: bool = False,
    camera: CameraOverride | None = None,
) -> dict[str, Any]:
    """Track a sequence; return (and write) its metrics (``dense_map``: and its map, map.ply).

    ``detector`` defaults to ``default_detector``'s choice; ``cache`` holds detections
    between runs (``StageCache.from_env()`` is the default on the command line);
    ``camera``: a real TUM folder's camera (``eval/cli/camera.py``), recorded in the metrics.
    """
    job = RunJob(
        Path(sequence_dir),
        strategy,
        detector if detector is not None else default_detector(Path(sequence_dir), strategy, camera),
        tuple(sorted((settings or {}).items())),
        tracker or TrackerConfig(),
        dense_map,
        camera,
    )
    return run_job(job, Path(out_dir), progress=progress, overwrite=overwrite, cache=cache).metrics


@dataclass(frozen=True)
class Finished:
    """A run done: its metrics (the run folder's metrics.json) and its typed record."""

    metrics: dict[str, Any]
    record: RunRecord


def run_job(
    job: RunJob,
    out_dir: Path | None,
    *,
    progress: bool = True,
    overwrite: bool = False,
    cache: StageCache | None = None,
) -> Finished:
    """Run ``job``; with ``out_dir``, leave the run folder there (trajectory, frames,
    diagnostics, metrics and record, swapped into place whole), else write nothing."""
    sequence, config = prepare(job)
    if out_dir is None:
        tracked = _execute(job, sequence, config, cache, progress)
        return Finished(tracked.metrics, record_of(job, sequence, tracked.metrics))
    # The output is checked, locked and staged first: a place that must not or cannot be
    # written is refused before the run, not after it.
    with StagedOutput(out_dir, OutputKind.RUN, overwrite=overwrite, inputs=(job.sequence,)) as output:
        started = time.perf_counter()
        try:
            tracked = _execute(job, sequence, config, cache, progress)
        except TrackerError as exc:
            if not job.tracker.type.external or (exc.evidence is None and not exc.log):
                raise  # refused before the program ran: one line, no folder
            _keep_failure(output, job, sequence, exc, time.perf_counter() - started)
            raise TrackerError(
                f"{exc}; what it was given and wrote is in {out_dir} (failure.json, program.log, scratch/)",
                exc.log,
            ) from None
        run = tracked.run
        estimate = run.trajectory()
        if estimate is not None:
            write_tum(output.path / "trajectory.txt", estimate, header=tracked.header)
        _write_frames(output.path / "frames.csv", run, tracked.decisions)
        if run.log:
            (output.path / "program.log").write_text(run.log, encoding="utf-8")
        arrays = run_diagnostics(run, tracked.decisions)
        if arrays is not None:
            np.savez_compressed(output.path / "diagnostics.npz", **arrays)
        if tracked.map is not None and len(tracked.map.points):  # no keyframe point: no file
            write_ply(output.path / "map.ply", tracked.map.points, tracked.map.colours)
        (output.path / "metrics.json").write_text(dumps_json(tracked.metrics) + "\n", encoding="utf-8")
        record = record_of(job, sequence, tracked.metrics)
        (output.path / "record.json").write_text(dumps_json(record.to_row()) + "\n", encoding="utf-8")
        output.commit()
    return Finished(tracked.metrics, record)


def _keep_failure(
    output: StagedOutput, job: RunJob, sequence: Sequence, exc: TrackerError, wall_s: float
) -> None:
    """A failed program's run folder: its failed record and what it was given and wrote
    (``evidence.write_evidence``), swapped into place as a finished run's is."""
    write_evidence(output.path, str(exc), exc.log, exc.evidence)
    identity = run_identity(job, sequence)
    record = RunRecord.failed(identity, str(exc), len(sequence), wall_s, code_version())
    (output.path / "record.json").write_text(dumps_json(record.to_row()) + "\n", encoding="utf-8")
    output.commit()


def _time_stats(values_ms: np.ndarray) -> dict[str, float | None]:
    finite = values_ms[np.isfinite(values_ms)]
    if not len(finite):
        return {"mean_ms": None, "median_ms": None}
    return {"mean_ms": float(finite.mean()), "median_ms": float(np.median(finite))}


def _metrics(
    sequence: Sequence,
    run: TrackerRun,
    config: SlamConfig,
    strategy: str,
    detector: DetectorConfig,
    detections: SequenceDetections | None,
    tracker: TrackerConfig,
    truth: Comparison | None,
    decisions: tuple[list[np.ndarray], list[np.ndarray]] | None,
) -> dict[str, Any]:
    states = run.states
    stage = {name: _time_stats(values) for name, values in run.stage_ms.items()}
    stage.setdefault("tracking_total", _time_stats(run.track_ms))
    settings: dict[str, Any] = {"tracking": asdict(config.tracking), "rejection": asdict(config.rejection)}
    if not tracker.type.per_keypoint:
        settings = {"mask": {k: getattr(config.rejection, k) for k in MASK_SETTINGS}}
        settings["command"] = tracker.command
    metrics: dict[str, Any] = {
        "sequence": str(sequence.root),
        "tracker": tracker.label,
        "tracker_kind": tracker.kind,
        "parameters": dict(tracker.parameters),
        "strategy": strategy,
        "detector": detector.label,
        "detector_config": detector.to_dict(),
        "config": settings,
        "camera": camera_json(sequence.intrinsics, sequence.camera_source),
        "frames": len(states),
        "tracked_frames": int(run.tracked.sum()),
        "lost_frames": sum(s == TrackingState.LOST for s in states),
        "relocalized_frames": sum(s == TrackingState.RELOCALIZED for s in states),
        "keyframes": run.keyframes,
        "stage_time": stage,
        "wall_time_s": run.total_s,
        "peak_memory_mb": run.peak_memory_mb,
        "cpu_time_s": run.cpu_s,
        # Compiled (or loaded) before the first timed frame, once per process: kept apart so
        # that no per-frame time includes it (14 s compiling, 0.5 s loading).
        "kernels_s": kernels.ready() if tracker.type.per_keypoint else None,
    }
    if detections is not None:
        metrics["detector_time"] = _time_stats(detections.latency_ms) | {"cached": detections.from_cache}
    if truth is not None:
        comparison = truth.to_dict()
        for key in ("ate_m", "rpe_translation_m", "rpe_rotation_deg"):
            metrics[key] = comparison[key]
    if decisions is not None:
        metrics["rejection"] = _rejection(*decisions, run.results)
    return metrics


def _against_truth(sequence: Sequence, run: TrackerRun) -> Comparison | None:
    """The run's trajectory against the sequence's ground truth (ATE aligned in SE(3), RPE per
    frame), or None without either or with fewer than 3 tracked frames."""
    estimate = run.trajectory()
    if sequence.groundtruth is None or estimate is None or len(estimate) < 3:
        return None
    gt = sequence.groundtruth
    reference = Trajectory.from_quaternions(gt.timestamps_s, gt.positions_m, gt.quats_xyzw, "groundtruth")
    return compare(reference, estimate, ComparisonOptions())


def frame_decisions(sequence: Sequence, run: TrackerRun) -> tuple[list[np.ndarray], list[np.ndarray]] | None:
    """Per frame, which keypoints the tracker rejected and which lie on a moving instance
    (the exact label): the built-in tracker's own, or an external program's keypoint file
    labelled here. None where there are no decisions or no ground truth to label them."""
    if run.results is not None and run.labels:
        kept = REJECTION_CODES[Rejection.KEPT]
        return [r.diagnostics.rejection != kept for r in run.results], list(run.labels)
    if run.decisions is None or not sequence.is_generated:
        return None
    from depotbench.eval.trackers.builtin import true_moving_labels

    objects = sequence.objects()
    moving = [
        true_moving_labels(sequence, i, points, {o.instance_id for o in objects[i] if o.moving})
        if len(points)
        else np.zeros(0, bool)
        for i, points in enumerate(run.decisions.keypoints_px)
    ]
    return [~kept for kept in run.decisions.kept], moving


def _rejection(
    rejected_per_frame: list[np.ndarray], labels: list[np.ndarray], results: list[FrameResult] | None
) -> dict[str, Any]:
    """Rejection as a classification of keypoints against their true moving labels; moving
    inliers where the tracker says which keypoints its pose used (the built-in one)."""
    rejected = np.concatenate(rejected_per_frame) if rejected_per_frame else np.zeros(0, bool)
    moving = np.concatenate(labels) if labels else np.zeros(0, bool)
    true_positive = int((rejected & moving).sum())
    inliers = None
    if results is not None:
        inliers = int(sum((r.diagnostics.inlier & lab).sum() for r, lab in zip(results, labels, strict=True)))
    return {
        "keypoints": int(len(moving)),
        "moving_keypoints": int(moving.sum()),
        "rejected_keypoints": int(rejected.sum()),
        "precision": true_positive / int(rejected.sum()) if rejected.any() else None,
        "recall": true_positive / int(moving.sum()) if moving.any() else None,
        "moving_inliers": inliers,
    }


def _write_frames(
    path: Path, run: TrackerRun, decisions: tuple[list[np.ndarray], list[np.ndarray]] | None
) -> None:
    """Per frame: state and time, and where the run's keypoint decisions are known, how
    many keypoints, on moving things, rejected, and rejected on moving things (per-frame
    precision is the last over the third, recall the last over the second)."""
    header = "timestamp_s,state,track_ms"
    if decisions is not None:
        header += ",keypoints,moving_keypoints,rejected_keypoints,rejected_moving"
    rows = [header]
    for i, (t, state, ms) in enumerate(zip(run.timestamps_s, run.states, run.track_ms, strict=True)):
        row = f"{t:.6f},{state.value},{'' if not np.isfinite(ms) else f'{ms:.3f}'}"
        if decisions is not None:
            rejected, moving = decisions[0][i], decisions[1][i]
            row += (
                f",{len(moving)},{int(moving.sum())},{int(rejected.sum())},{int((rejected & moving).sum())}"
            )
        rows.append(row)
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


def run_diagnostics(
    run: TrackerRun, decisions: tuple[list[np.ndarray], list[np.ndarray]] | None
) -> dict[str, np.ndarray] | None:
    """What ``diagnostics.npz`` holds of a run (the report draws its frames from it): the
    built-in tracker's per-keypoint decisions, or an external program's keypoint file (where
    it wrote one); None where there are neither."""
    if run.results is not None:
        return diagnostics_arrays(run.results, run.labels or [])
    if run.decisions is not None:
        return decision_arrays(run.decisions, decisions[1] if decisions is not None else [])
    return None


PROGRAM_REJECTED = "rejected"
"""An external program's rejection: its reason words are its own, not the bench's reasons."""


def decision_arrays(decisions, labels: list[np.ndarray]) -> dict[str, np.ndarray]:
    """An external program's keypoint decisions (``protocol.KeypointDecisions``) in the arrays
    ``diagnostics_arrays`` writes for the built-in tracker: per frame its keypoints, each kept
    (code 0) or rejected (code 1), and the true moving labels where the sequence has them."""
    counts = np.array([len(points) for points in decisions.keypoints_px], dtype=np.int64)
    points = [np.asarray(p, np.float64).reshape(-1, 2) for p in decisions.keypoints_px]
    codes = [np.where(np.asarray(kept, bool), 0, 1).astype(np.int16) for kept in decisions.kept]
    arrays = {
        "keypoint_counts": counts,
        "keypoints_px": np.concatenate(points) if points else np.zeros((0, 2)),
        "rejection": np.concatenate(codes) if codes else np.zeros(0, np.int16),
        "rejection_names": np.array([Rejection.KEPT.value, PROGRAM_REJECTED]),
    }
    if labels:
        arrays["moving"] = np.concatenate(labels)
    return arrays


def diagnostics_arrays(results: list[FrameResult], labels: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Per-keypoint decisions of a run as flat arrays (``diagnostics.npz``; the report reads them)."""
    counts = np.array([len(r.diagnostics.keypoints_px) for r in results])
    classes = sorted({c for r in results for c in r.diagnostics.keypoint_classes})
    class_index = {c: i for i, c in enumerate(classes)}
    stages = sorted(results[0].diagnostics.stage_ms) if results else []
    arrays = {
        "timestamps_s": np.array([r.timestamp_s for r in results]),
        "state": np.array([r.state.value for r in results]),
        "keyframe": np.array([r.diagnostics.keyframe for r in results]),
        "keypoint_counts": counts,
        "keypoints_px": np.concatenate([r.diagnostics.keypoints_px for r in results])
        if results
        else np.zeros((0, 2)),
        "keypoint_class": np.concatenate(
            [[class_index[c] for c in r.diagnostics.keypoint_classes] for r in results]
        ).astype(np.int16)
        if results
        else np.zeros(0),
        "class_names": np.array(classes),
        "rejection": np.concatenate([r.diagnostics.rejection for r in results]) if results else np.zeros(0),
        "rejection_names": np.array([r.value for r in Rejection]),
        "inlier": np.concatenate([r.diagnostics.inlier for r in results]) if results else np.zeros(0, bool),
        "stage_names": np.array(stages),
        "stage_ms": np.array([[r.diagnostics.stage_ms[s] for s in stages] for r in results]),
    }
    if labels:
        arrays["moving"] = np.concatenate(labels)
    return arrays
