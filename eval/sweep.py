"""Run a sweep: expand its spec into jobs, run the missing ones, keep rows in SQLite.

The parent process owns the database and writes each finished job's row in one
transaction; workers (spawned processes that ignore Ctrl-C and die with their
parent) only compute. So a sweep killed at any moment keeps every finished row,
and running it again does exactly the jobs that are missing.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, replace
from pathlib import Path

from tqdm import tqdm

from detectors.config import DetectorConfig
from eval.cache import StageCache, content_hash
from eval.detections import detect_sequence, sequence_fingerprint
from eval.harness import RunJob, TrackerConfig, prepare, stages_for, track, uses_stages
from eval.record import RECORD_VERSION, RunRecord
from eval.stages import decision_signature, features_key
from eval.store import ResultStore
from eval.sweep_spec import (
    MAX_JOBS,
    SweepSpec,
    Variant,
    check_variants,
    detector_configs,
    resolve,
    tracker_configs,
    variants,
)
from eval.trackers.base import TrackerKind
from scenes.schema import SpecError
from sim.errors import InputError
from sim.executors import make_pool
from sim.sequence import Sequence
from sim.version import generator_version

DATABASE = "results.sqlite"


@dataclass(frozen=True)
class SweepJob:
    key: str
    family: str
    job: RunJob


def _family(sequence: Sequence) -> str:
    """A sequence's scenario name (a suite variation's number dropped), or its folder's name."""
    scenario = (sequence.meta or {}).get("scenario") or {}
    name = scenario.get("name") if isinstance(scenario, dict) else None
    return re.sub(r"-\d{4}$", "", str(name)) if name else sequence.root.name


def job_key(
    fingerprint: str, tracker: TrackerConfig, detector: DetectorConfig, strategy: str, settings
) -> str:
    return content_hash(
        RECORD_VERSION,
        generator_version(),
        fingerprint,
        tracker.kind.value,
        detector.key(),
        detector.faults.to_dict(),
        strategy,
        list(settings),
    )


def expand(spec: SweepSpec, spec_path: Path, sequences: list[tuple[Path, str]]) -> list[SweepJob]:
    """Every job of the sweep, in a stable order."""
    source = str(spec_path)
    trackers = tracker_configs(spec, source)
    detectors = detector_configs(spec, source)
    found = variants(spec)
    check_variants(spec, found, trackers, source)
    total = len(sequences) * len(trackers) * len(detectors) * len(found)
    if total > MAX_JOBS:
        raise SpecError(f"{source}: {total} jobs exceed the limit of {MAX_JOBS}")
    return jobs_for(found, trackers, detectors, sequences)


def jobs_for(
    found: list[Variant],
    trackers: list[TrackerConfig],
    detectors: list[DetectorConfig],
    sequences: list[tuple[Path, str]],
) -> list[SweepJob]:
    """Sequences x trackers x detectors x variants, in this order (external trackers: none/mask)."""
    jobs = []
    for root, family in sequences:
        fingerprint = sequence_fingerprint(Sequence.open(root))
        for tracker in trackers:
            for detector in detectors:
                for v in found:
                    if tracker.kind is not TrackerKind.BUILTIN and v.strategy not in ("none", "mask"):
                        continue
                    key = job_key(fingerprint, tracker, detector, v.strategy, v.settings)
                    jobs.append(
                        SweepJob(key, family, RunJob(root, v.strategy, detector, v.settings, tracker))
                    )
    return jobs


def validate(spec: SweepSpec, spec_path: Path) -> None:
    """Everything that can be checked before an output folder is made: trackers,
    detectors, threshold values, the sequence folders and the suite file."""
    source = str(spec_path)
    trackers = tracker_configs(spec, source)
    detector_configs(spec, source)
    check_variants(spec, variants(spec), trackers, source)
    for i, name in enumerate(spec.sequences):
        root = resolve(spec, spec_path, name)
        if not root.is_dir():
            raise InputError(f"{spec_path}: sequences.{i}: {root} is not a folder")
        Sequence.open(root)
    if spec.suite is not None:
        from scenes.suite import load_suite

        suite_path = resolve(spec, spec_path, spec.suite)
        if not suite_path.is_file():
            raise InputError(f"{spec_path}: suite: {suite_path} is not a file")
        load_suite(suite_path)


def sequences_of(
    spec: SweepSpec,
    spec_path: Path,
    out: Path,
    workers: int,
    progress: bool,
    backend: str = "local",
    address: str | None = None,
) -> list[tuple[Path, str]]:
    """The spec's sequence folders and their families, its suite generated (and resumed)
    under OUT/sequences. A suite's family is its name with the knobs other than the seed,
    so seeds of one setting are averaged together."""
    roots = []
    for i, name in enumerate(spec.sequences):
        root = resolve(spec, spec_path, name)
        if not root.is_dir():
            raise InputError(f"{spec_path}: sequences.{i}: {root} is not a folder")
        roots.append((root, _family(Sequence.open(root))))
    if spec.suite is not None:
        from scenes.generation import run_suite
        from scenes.suite import load_suite

        suite_path = resolve(spec, spec_path, spec.suite)
        if not suite_path.is_file():
            raise InputError(f"{spec_path}: suite: {suite_path} is not a file")
        index = run_suite(
            load_suite(suite_path),
            suite_path,
            out / "sequences",
            workers,
            progress=progress,
            backend=backend,
            address=address,
        )
        for entry in index["sequences"]:
            knobs = " ".join(f"{k}={v}" for k, v in sorted(entry["knobs"].items()) if k != "seed")
            roots.append((out / "sequences" / entry["name"], f"{index['suite']} {knobs}".strip()))
    return roots


def signature_job(job: SweepJob) -> tuple[str, str | None]:
    """Worker entry point of phase 1: which keypoints the job keeps, frame by frame, as a hash.

    None for jobs that are not deduplicated (external trackers, ``mask``).
    """
    run = job.job
    if not uses_stages(run):
        return job.key, None
    cache = StageCache.from_env()
    sequence, config = prepare(run)
    stages = stages_for(sequence, config, cache)
    detections = detect_sequence(sequence, run.detector, cache)
    boxes = list(detections.per_frame) if detections is not None else None
    decided = decision_signature(stages, boxes, config, config.tracking.seed)
    return job.key, content_hash(features_key(sequence, config.tracking), decided)


def run_job(job: SweepJob, bench_version: str, signature: str | None) -> RunRecord:
    """Worker entry point of phase 2: track, and make the row."""
    tracked = track(job.job, StageCache.from_env())
    settings = dict(job.job.settings)
    return RunRecord.from_metrics(job.key, job.family, settings, tracked.metrics, bench_version, signature)


def _same_run(record: RunRecord, job: SweepJob) -> RunRecord:
    """The row of a job whose run is ``record``'s run (same kept keypoints in every frame)."""
    return replace(
        record,
        key=job.key,
        family=job.family,
        detector=job.job.detector.label,
        settings=json.dumps(dict(job.job.settings), sort_keys=True),
        computed_by=record.computed_by,
    )


def run_jobs(
    jobs: list[SweepJob],
    store: ResultStore,
    workers: int,
    progress: bool = True,
    dedupe: bool = True,
    backend: str = "local",
    address: str | None = None,
) -> tuple[int, int]:
    """Run the jobs whose rows are missing; returns (runs tracked, rows written).

    Phase 1 finds, per job, which keypoints it keeps (cheap: no tracking); phase 2
    tracks one job per distinct decision and writes the others' rows from it.
    """
    done = store.keys()
    pending = [j for j in jobs if j.key not in done]
    version = generator_version()
    pool = make_pool(backend, workers, address)
    failed = True
    try:
        signatures: dict[str, str | None] = {j.key: None for j in pending}
        if dedupe and pending:
            bar = tqdm(total=len(pending), desc="decisions", unit="run", disable=None if progress else True)
            with bar:
                for _, (key, signature) in pool.map_unordered(signature_job, [(j,) for j in pending]):
                    signatures[key] = signature
                    bar.update()
        groups: dict[str, list[SweepJob]] = {}
        order: list[tuple[SweepJob, list[SweepJob]]] = []
        for job in pending:
            signature = signatures[job.key]
            if signature is None:
                order.append((job, []))
                continue
            existing = store.by_signature(signature)
            if existing is not None:
                store.add(_same_run(existing, job))
                continue
            if signature in groups:
                groups[signature].append(job)
            else:
                groups[signature] = []
                order.append((job, groups[signature]))
        bar = tqdm(
            total=len(jobs),
            initial=len(jobs) - sum(1 + len(rest) for _, rest in order),
            desc="sweep",
            unit="run",
            disable=None if progress else True,
            smoothing=0.1,
        )
        tracked = 0
        with bar:
            items = [(job, version, signatures[job.key]) for job, _ in order]
            followers = {job.key: rest for job, rest in order}
            for (job, _, _), record in pool.map_unordered(run_job, items):
                store.add(record)
                tracked += 1
                for other in followers[job.key]:
                    store.add(_same_run(record, other))
                bar.update(1 + len(followers[job.key]))
        failed = False
    finally:
        pool.close(failed)
    return tracked, len(pending)


def open_store(out: Path, spec: SweepSpec) -> ResultStore:
    out.mkdir(parents=True, exist_ok=True)
    store = ResultStore(out / DATABASE)
    # Rows are keyed by content: after a change of spec the old ones stay valid and new ones add.
    store.set_meta("spec", spec.model_dump_json())
    store.set_meta("bench_version", generator_version())
    return store
