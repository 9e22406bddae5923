"""Run a sweep: expand its spec into jobs, run the missing ones, keep rows in SQLite.

The parent process owns the database and writes each finished job's row in one
transaction; workers (spawned processes that ignore Ctrl-C and die with their
parent) only compute. So a sweep killed at any moment keeps every finished row,
and running it again does exactly the jobs that are missing.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError
from depotbench.core.executors import make_pool
from depotbench.core.logs import DETAIL, timed
from depotbench.core.progress import progress_bar
from depotbench.core.version import code_version
from depotbench.detectors.config import DetectorConfig
from depotbench.eval.metrics.record import RunIdentity, RunRecord
from depotbench.eval.run.cache import StageCache
from depotbench.eval.run.detections import detect_sequence, sequence_fingerprint, stored_path
from depotbench.eval.run.harness import (
    EXTERNAL_STRATEGIES,
    RunJob,
    branch_root,
    family_of,
    identity_of,
    job_key,
    maps_itself,
    prepare,
    seed_of,
    slam_config,
    stages_for,
    track,
    track_tree,
    tracker_fingerprint,
    tracker_identity,
    uses_stages,
)
from depotbench.eval.run.nodes import SequenceSource, Shipments, local_sequence, program_differs
from depotbench.eval.run.stages import decision_path, decision_signature, features_key, sequence_stages
from depotbench.eval.sweep.spec import (
    MAX_JOBS,
    SweepSpec,
    Variant,
    check_search,
    check_variants,
    detector_configs,
    resolve,
    tracker_configs,
    tracker_count,
    tracker_variants,
    variant_count,
    variants,
)
from depotbench.eval.sweep.store import ResultStore
from depotbench.eval.trackers.base import TrackerError
from depotbench.eval.trackers.evidence import Evidence, write_evidence
from depotbench.eval.trackers.registry import TrackerConfig
from depotbench.eval.trackers.registry import check as check_tracker
from depotbench.scenes.schema import SpecError
from depotbench.sim.sequence import Sequence
from depotbench.slam.config import TrackingConfig

DATABASE = "results.sqlite"
LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class SequenceEntry:
    """A sequence a sweep runs on: its folder, its family (what its seeds are averaged as)
    and, for a suite's sequence, the knobs of its variation."""

    root: Path
    family: str
    knobs: tuple[tuple[str, Any], ...] = ()


def sequence_entries(sequences: list) -> list[SequenceEntry]:
    """Entries from ``(root, family)`` pairs too (tests and benchmarks pass those)."""
    return [s if isinstance(s, SequenceEntry) else SequenceEntry(Path(s[0]), s[1]) for s in sequences]


@dataclass(frozen=True)
class SweepJob:
    key: str
    family: str
    job: RunJob
    fingerprint: str
    """``detections.sequence_fingerprint`` of the job's sequence when it was expanded."""
    run: RunIdentity
    """What its row records of it (sequence as stored, seed, knobs, configuration)."""


def expand(spec: SweepSpec, spec_path: Path, sequences: list, anchor: Path | None = None) -> list[SweepJob]:
    """Every job of the sweep, in a stable order; ``anchor``: the sweep folder, which the
    rows name their sequences relative to."""
    source = str(spec_path)
    trackers = tracker_configs(spec, source)
    detectors = detector_configs(spec, source)
    total = len(sequences) * tracker_count(spec) * len(detectors) * variant_count(spec)
    if total > MAX_JOBS:  # counted before a job is built: the grid may be far larger than memory
        raise SpecError(f"{source}: {total} jobs exceed the limit of {MAX_JOBS}")
    found = variants(spec)
    check_variants(spec, found, trackers, source)
    trackers = tracker_variants(spec, trackers, source)
    return jobs_for(found, trackers, detectors, sequences, anchor, spec.dense_map)


def jobs_for(
    found: list[Variant],
    trackers: list[TrackerConfig],
    detectors: list[DetectorConfig],
    sequences: list,
    anchor: Path | None = None,
    dense_map: bool = False,
) -> list[SweepJob]:
    """Sequences x trackers x detectors x variants, in this order (external trackers: none/mask);
    ``dense_map``: the built-in tracker's runs also build and score their dense maps."""
    jobs = []
    identities = {tracker: tracker_identity(tracker) for tracker in trackers}
    versions = {tracker: tracker_fingerprint(identity) for tracker, identity in identities.items()}
    named: dict[str, Path] = {}
    for entry in sequence_entries(sequences):
        root, family = entry.root, entry.family
        opened = Sequence.open(root)
        fingerprint = sequence_fingerprint(opened)
        if named.setdefault(fingerprint, root) != root:
            raise InputError(_named_twice(named[fingerprint], root))
        stored, seed = stored_path(root, anchor), seed_of(opened)
        for tracker in trackers:
            mapped = dense_map and maps_itself(tracker)  # built-in keyframes, or a program's {map}
            for detector in detectors:
                for v in found:
                    if not tracker.type.per_keypoint and v.strategy not in EXTERNAL_STRATEGIES:
                        continue
                    key = job_key(fingerprint, identities[tracker], detector, v.strategy, v.settings, mapped)
                    run = RunJob(root, v.strategy, detector, v.settings, tracker, mapped)
                    identity = identity_of(
                        run, key, family, stored, fingerprint, seed, dict(entry.knobs), versions[tracker]
                    )
                    jobs.append(SweepJob(key, family, run, fingerprint, identity))
    return jobs


def _named_twice(first: Path, second: Path) -> str:
    """A sequence named twice would be one job (one key) labelled twice: one row, a family
    gone from the summary. A suite and one of its sequences, a folder and its copy, a link."""
    how = "is named twice" if first.resolve() == second.resolve() else f"holds the same sequence as {first}"
    return f"sequences: {second} {how} (the same files and camera, so the same runs); name each sequence once"


def validate(spec: SweepSpec, spec_path: Path) -> None:
    """Everything that can be checked before an output folder is made: trackers,
    detectors, threshold values, the sequence folders (suite folders and globs
    expanded, each sequence opened) and the suite file."""
    source = str(spec_path)
    trackers = tracker_configs(spec, source)
    detectors = detector_configs(spec, source)
    count = tracker_count(spec) * len(detectors) * variant_count(spec)
    if count > MAX_JOBS:  # per sequence; ``expand`` counts the sequences too
        raise SpecError(f"{source}: thresholds: {count} jobs per sequence exceed the limit of {MAX_JOBS}")
    check_variants(spec, variants(spec), trackers, source)
    tracker_variants(spec, trackers, source)
    check_search(spec, trackers, source)
    opened = [Sequence.open(entry.root) for entry in named_sequences(spec, spec_path)]
    for i, tracker in enumerate(trackers):  # a settings template, rendered on a real camera
        if tracker.settings_template is not None and opened:
            try:
                check_tracker(tracker, opened[0])
            except InputError as exc:
                raise SpecError(f"{source}: trackers.{i} ({tracker.label}): {exc}") from None
    if spec.suite is not None:
        from depotbench.scenes.suite import load_suite

        suite_path = suite_file(spec, spec_path)
        load_suite(suite_path)


def spec_inputs(spec: SweepSpec, spec_path: Path) -> tuple[Path, ...]:
    """What a sweep or gate run reads and must never write into: the spec file, the
    sequence and suite folders it names, what its globs match, and its suite file."""
    named = [resolve(spec, spec_path, name) for name in spec.sequences]
    named += [entry.root for entry in named_sequences(spec, spec_path)]
    if spec.suite is not None:
        named.append(suite_file(spec, spec_path))
    return (spec_path, *named)


def suite_file(spec: SweepSpec, spec_path: Path) -> Path:
    """The spec's suite file: a path relative to the spec where that file exists, else a
    shipped suite of that name (``suite: walking4``, as ``depotbench generate`` takes it), so
    a spec copied alone into another folder still finds it."""
    from depotbench.core.examples import Kind, named

    assert spec.suite is not None
    path = resolve(spec, spec_path, spec.suite)
    if path.is_file():
        return path
    shipped = named(spec.suite, Kind.SUITE)
    if shipped is not None and not path.exists():
        return shipped
    raise InputError(f"{spec_path}: suite: {path} is not a file, nor a shipped suite's name")


def sequences_of(
    spec: SweepSpec,
    spec_path: Path,
    out: Path,
    workers: int,
    progress: bool,
    backend: str = "local",
    address: str | None = None,
) -> list[SequenceEntry]:
    """The spec's sequence folders and their families (``named_sequences``: suite folders
    and globs expanded), its suite generated (and resumed) under OUT/sequences. A suite's
    family is its name with the knobs other than the seed, so seeds of one setting are
    averaged together."""
    roots = named_sequences(spec, spec_path)
    if spec.suite is not None:
        from depotbench.scenes.generation import run_suite
        from depotbench.scenes.suite import load_suite

        suite_path = suite_file(spec, spec_path)
        index = run_suite(
            load_suite(suite_path),
            suite_path,
            out / "sequences",
            workers,
            progress=progress,
            backend=backend,
            address=address,
        )
        roots.extend(suite_entry(index["suite"], entry, out / "sequences") for entry in index["sequences"])
    return roots


def suite_entry(suite: str, entry: dict[str, Any], folder: Path) -> SequenceEntry:
    """A suite's sequence (an entry of its ``index.json``, the suite written into
    ``folder``) with its family: the suite's name and the knobs other than the seed."""
    knobs = " ".join(f"{k}={v}" for k, v in sorted(entry["knobs"].items()) if k != "seed")
    family = f"{suite} {knobs}".strip()
    return SequenceEntry(folder / entry["name"], family, tuple(sorted(entry["knobs"].items())))


def named_sequences(spec: SweepSpec, spec_path: Path) -> list[SequenceEntry]:
    """The folders ``sequences:`` names, in order, with their families. An entry is a
    sequence folder, a suite folder (``depotbench generate SUITE.yaml -o DIR``: its
    sequences, in its ``index.json``'s order, with the family and knobs a ``suite:``
    entry gives them) or a glob (``seqs/*``, relative to the spec file; a folder whose
    name holds ``*``, ``?`` or ``[`` is that folder) of such folders, sorted, skipping
    depotbench's other outputs (``_other_output``); a glob matching no folder is refused
    naming the entry."""
    import glob

    entries = []
    for i, name in enumerate(spec.sequences):
        where = f"{spec_path}: sequences.{i}"
        if glob.has_magic(name) and not resolve(spec, spec_path, name).is_dir():
            pattern = str(Path(name).expanduser())
            if Path(pattern).is_absolute():
                found = glob.glob(pattern)
            else:  # the spec's folder is no part of the pattern: it may hold * or [ itself
                found = [str(spec_path.parent / p) for p in glob.glob(pattern, root_dir=spec_path.parent)]
            folders = sorted(Path(p) for p in found if Path(p).is_dir() and not _other_output(Path(p)))
            if not folders:
                start = spec_path.parent.absolute()
                raise InputError(f"{where}: {name!r} matches no folder (relative to {start})")
        else:
            folders = [resolve(spec, spec_path, name)]
            if not folders[0].is_dir():
                raise InputError(f"{where}: {folders[0]} is not a folder")
        for folder in folders:
            entries.extend(_folder_entries(folder, where))
    return entries


def _other_output(folder: Path) -> bool:
    """Whether depotbench wrote ``folder`` as an output that holds no sequence (a sweep, a
    run, a report): a glob skips it, the sweep's own ``-o`` folder among them, which is
    made (and marked) before the glob is expanded."""
    from depotbench.core.output import OutputKind, read_marker

    marker = read_marker(folder)
    return marker is not None and marker.kind not in (OutputKind.SEQUENCE, OutputKind.SUITE)


def _folder_entries(folder: Path, where: str) -> list[SequenceEntry]:
    """A sequence folder's entry, or a suite folder's sequences, each checked complete."""
    from depotbench.core.errors import FileError
    from depotbench.core.files import read_json
    from depotbench.core.output import OutputKind, read_marker
    from depotbench.scenes.generation import INDEX_MAX_BYTES, INDEX_NAME, is_complete

    marker = read_marker(folder)
    if marker is None or marker.kind is not OutputKind.SUITE:
        return [SequenceEntry(folder, family_of(Sequence.open(folder)))]
    again = f"run `depotbench generate SUITE.yaml -o {folder}` again"
    try:
        index = read_json(folder / INDEX_NAME, INDEX_MAX_BYTES, "suite index")
        suite, listed = str(index["suite"]), list(index["sequences"])
        for entry in listed:
            name = entry["name"]
            if not isinstance(name, str) or name in ("", ".", "..") or Path(name).name != name:
                raise ValueError(f"bad sequence name {name!r}")
            if not isinstance(entry["knobs"], dict) or not isinstance(entry["content_key"], str):
                raise ValueError("knobs or content_key missing")
    except FileNotFoundError:
        raise InputError(
            f"{where}: {folder} is a suite folder without {INDEX_NAME} "
            f"(its generation did not finish: {again})"
        ) from None
    except FileError as exc:  # not a regular file, over its bound, not JSON, nested too deeply
        raise InputError(f"{where}: {exc}; {again}") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{where}: {folder / INDEX_NAME} cannot be read ({exc}); {again}") from None
    entries = []
    for entry in listed:
        if not is_complete(folder / entry["name"], entry["content_key"]):
            raise InputError(
                f"{where}: {folder / entry['name']} is not the complete sequence its suite's "
                f"{INDEX_NAME} names; {again}"
            )
        entries.append(suite_entry(suite, entry, folder))
    return entries


@dataclass(frozen=True)
class Decision:
    """Phase 1's answer for a job: which keypoints it keeps, per frame and in all."""

    key: str
    signature: str | None
    """Hash of the whole path; None for jobs that are not shared (external trackers, ``mask``)."""
    root: str | None
    """``harness.branch_root``: jobs with one root can be tracked as one branching run."""
    path: tuple[str, ...] | None


def stage_groups(jobs: list[SweepJob]) -> list[SweepJob]:
    """One job per set of shared stages (sequence, detector, tracking and flow settings):
    computing those first, one task each, keeps two workers from computing the same ones."""
    chosen: dict[tuple, SweepJob] = {}
    for job in jobs:
        run = job.job
        if not uses_stages(run):
            continue
        config = slam_config(run.strategy, dict(run.settings), run.tracker.kind)
        flow = (config.rejection.lk_window_px, config.rejection.lk_levels)
        key = (str(run.sequence), repr(run.detector), config.tracking, flow)
        chosen.setdefault(key, job)
    return list(chosen.values())


def compute_stages(job: SweepJob) -> None:
    """Worker entry point of phase 0: detections, features and flow of a job, into the cache."""
    cache = StageCache.from_env()
    sequence, config = prepare(job.job)
    detect_sequence(sequence, job.job.detector, cache)
    sequence_stages(sequence, config.tracking, config.rejection, True, cache)


def decide(jobs: list[SweepJob]) -> list[Decision]:
    """Worker entry point of phase 1: each job's decision path (cheap: no tracking).

    Jobs come in expansion order, so those of one sequence and detector are neighbours
    and the stages are loaded once for them."""
    cache = StageCache.from_env()
    loaded: dict[str, tuple] = {}
    features: dict[tuple[Path, TrackingConfig], str] = {}
    decisions = []
    sequence = None
    for job in jobs:
        run = job.job
        if not uses_stages(run):
            decisions.append(Decision(job.key, None, None, None))
            continue
        sequence, config = prepare(run, sequence)
        at = (sequence.root, config.tracking)
        if at not in features:  # a fingerprint stats every frame file: once per sequence and setting
            features[at] = features_key(sequence, config.tracking)
        root = branch_root(run, features[at], config)
        if root not in loaded:
            detections = detect_sequence(sequence, run.detector, cache)
            boxes = list(detections.per_frame) if detections is not None else None
            stages = stages_for(sequence, config, cache)
            loaded = {root: (stages, boxes, [{} for _ in stages])}  # one at a time
        stages, boxes, memos = loaded[root]
        path = decision_path(stages, boxes, config, memos, reasons=run.dense_map)
        signature = decision_signature(path, features[at], run.strategy, run.dense_map)
        decisions.append(Decision(job.key, signature, root, path))
    return decisions


@dataclass(frozen=True)
class Failure:
    """A failed row with what its program was given and wrote (``failures/<key>/``)."""

    record: RunRecord
    log: str
    evidence: Evidence | None


def run_job(job: SweepJob, bench_version: str) -> list[RunRecord | Failure]:
    """Worker entry point of phase 2 for a job tracked alone. An external program that
    fails (its exit, its time limit, output that cannot be read) gives a failed row, and
    the sweep goes on; the built-in tracker failing is a bug of ours, and raises."""
    started = time.perf_counter()
    try:
        tracked = track(job.job, StageCache.from_env())
    except TrackerError as exc:
        if not job.job.tracker.type.external:
            raise
        record = _failed(job, str(exc), time.perf_counter() - started, bench_version)
        return [Failure(record, exc.log, exc.evidence)]
    return [_record(job, tracked.metrics, bench_version, None)]


FAILURES = "failures"
KEEP_FAILURES = 20
"""Failed runs whose folders a sweep keeps (the newest): enough to debug a program that fails
on some sequences, bounded for one that fails on all of a 2000-run sweep (64 MiB each at most)."""


def keep_failure(folder: Path, failure: Failure, keep: int = KEEP_FAILURES) -> Path:
    """Write a failed run's folder at ``folder/<key>`` (staged and swapped in whole, with the
    marker of a run folder) and remove the oldest such folders past ``keep``. The caller
    holds the sweep folder's lock."""
    from depotbench.core.files import dumps_json
    from depotbench.core.output import MARKER_NAME, Marker, OutputKind, read_marker, replace_folder

    record = failure.record
    target = folder / record.key
    if target.exists() and getattr(read_marker(target), "kind", None) is not OutputKind.RUN:
        raise InputError(f"{target}: not a failed run's folder of depotbench; move it away and run again")
    folder.mkdir(exist_ok=True)
    for stale in folder.glob(".*.partial-*"):  # a sweep killed while keeping one
        shutil.rmtree(stale, ignore_errors=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{record.key}.partial-", dir=folder))
    try:
        write_evidence(staging, record.failure or "", failure.log, failure.evidence)
        (staging / "record.json").write_text(dumps_json(record.to_row()) + "\n", encoding="utf-8")
        (staging / MARKER_NAME).write_text(Marker(OutputKind.RUN).to_json(), encoding="utf-8")
        replace_folder(staging, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    kept = []
    for child in folder.iterdir():
        marker = read_marker(child) if child.is_dir() and not child.name.startswith(".") else None
        if marker is not None and marker.kind is OutputKind.RUN:
            kept.append(((child / MARKER_NAME).stat().st_mtime_ns, child.name, child))
    for *_, old in sorted(kept, reverse=True)[keep:]:
        shutil.rmtree(old)
    return target


def _failed(job: SweepJob, reason: str, wall_s: float, bench_version: str) -> RunRecord:
    frames = len(Sequence.open(job.job.sequence))
    return RunRecord.failed(job.run, reason, frames, wall_s, bench_version)


def run_branches(
    jobs: list[SweepJob], paths: list[tuple[str, ...]], signatures: list[str], bench_version: str
) -> list[RunRecord]:
    """Worker entry point of phase 2 for jobs of one branch root, tracked as one branching run."""
    tracked = track_tree([j.job for j in jobs], paths, StageCache.from_env())
    return [
        _record(job, t.metrics, bench_version, signature)
        for job, t, signature in zip(jobs, tracked, signatures, strict=True)
    ]


def _dispatch(fn, args: tuple):
    return fn(*args)


def _record(job: SweepJob, metrics: dict, bench_version: str, signature: str | None) -> RunRecord:
    return RunRecord.of_run(job.run, metrics, bench_version, signature)


def _same_run(record: RunRecord, job: SweepJob) -> RunRecord:
    """The row of a job whose run is ``record``'s run (same kept keypoints in every frame)."""
    own = RunRecord.identity_columns(job.run)
    names = ("key", "family", "sequence", "seed", "knobs", "detector", "detector_config", "settings")
    return replace(record, **{name: own[name] for name in names})


def _chunks(items: list, count: int) -> list[list]:
    size = max(1, -(-len(items) // max(1, count)))
    return [items[i : i + size] for i in range(0, len(items), size)]


def _split(tasks: list[list[Decision]], target: int) -> list[list[Decision]]:
    """Split the largest branching tasks where their paths first part, until there are
    ``target`` tasks (so every worker has work and progress moves). A part re-runs the
    shared frames before the split: cheap, since paths part early or not at all."""
    tasks = [list(t) for t in tasks]
    while len(tasks) < target:
        splittable = [t for t in tasks if len(t) > 1]
        if not splittable:
            break
        task = max(splittable, key=len)
        depth = next(i for i in range(len(task[0].path)) if len({d.path[i] for d in task}) > 1)
        parts: dict[str, list[Decision]] = {}
        for decision in task:
            parts.setdefault(decision.path[depth], []).append(decision)
        tasks.remove(task)
        tasks.extend(parts.values())
    return tasks


def _tasks(fn, items: list[tuple], shipments: Shipments | None) -> tuple:
    """``fn`` over ``items`` as the pool runs them: as they are, or on a cluster through
    ``_on_node`` with the sources of the sequences each item's jobs name (put into Ray's
    object store as the items are taken: ``Shipments``)."""
    if shipments is None:
        return fn, items
    return _on_node, ((fn, sources, item) for item, sources in shipments.around(items, _roots))


def _roots(value) -> set[str]:
    if isinstance(value, SweepJob):
        return {str(value.job.sequence)}
    if isinstance(value, (list, tuple)):
        return set().union(*(_roots(v) for v in value)) if value else set()
    return set()


def _on_node(fn, sources: dict[str, SequenceSource], args: tuple):
    """Worker entry point on a cluster's node: each job's sequence made on this node
    (``local_sequence``) and its program checked against the driver's, then ``fn``."""
    if fn is _dispatch:  # phase 2: (run_job | run_branches, their arguments)
        inner, inner_args = args
        inner_args = _localized(inner_args, sources)
        jobs = [inner_args[0]] if inner is run_job else inner_args[0]  # run_branches: one tracker
        differs = program_differs(jobs[0].job.tracker, jobs[0].run.tracker_fingerprint)
        if differs is not None:  # a failed row each, as for a program that fails
            return [Failure(_failed(job, differs, 0.0, inner_args[-1]), "", None) for job in jobs]
        return inner(*inner_args)
    return fn(*_localized(args, sources))


def _localized(value, sources: dict[str, SequenceSource]):
    if isinstance(value, SweepJob):
        local = local_sequence(sources[str(value.job.sequence)])
        return replace(value, job=replace(value.job, sequence=local))
    if isinstance(value, list):
        return [_localized(v, sources) for v in value]
    if isinstance(value, tuple):
        return tuple(_localized(v, sources) for v in value)
    return value


PHASES = ("phase 0, the shared stages,", "phase 1, the decision paths,", "phase 2, tracking,")
"""How ``run_jobs`` names its phases in the ``-v`` lines that time them ("... took 2.61 s"):
``benchmarks/sweep.py`` reads them to say where a sweep's time went."""


def run_jobs(
    jobs: list[SweepJob],
    store: ResultStore,
    workers: int,
    progress: bool = True,
    dedupe: bool = True,
    backend: str = "local",
    address: str | None = None,
    retry_failed: bool = False,
) -> tuple[int, int]:
    """Run the jobs whose rows are missing (``retry_failed``: or failed, time-outs included);
    returns (runs tracked, rows written). A failed program's row is stored as any row, and
    what it was given and wrote in ``failures/<key>/`` beside the store (``keep_failure``).

    Phase 0 computes the stages jobs share (detections, features, flow), one task per
    sequence and setting, into the stage cache. Phase 1 finds, per job, which keypoints
    it keeps in every frame (cheap: no tracking). Phase 2 tracks one job per distinct
    decision path, the jobs of one sequence and strategy together, sharing the frames
    where their paths agree; jobs with a path already tracked get its row. ``dedupe=False`` tracks every job
    alone (the reference the tests compare against).
    """
    done = store.keys() - (store.failed_keys() if retry_failed else set())
    pending = [j for j in jobs if j.key not in done]
    by_key = {j.key: j for j in pending}
    version = code_version()
    pool = make_pool(backend, workers, address)
    failed = True
    try:
        shipments = None
        if pool.ships:  # a cluster: sequences travel with the jobs (eval/run/nodes.py)
            shipments = Shipments(pool.put, {str(j.job.sequence): j.fingerprint for j in pending})
        decisions = [Decision(j.key, None, None, None) for j in pending]
        if StageCache.from_env() is not None:
            groups = stage_groups(pending)
            bar = progress_bar(total=len(groups), desc="stages", unit="seq", disable=not progress)
            with bar, timed(LOG, PHASES[0]):
                for _ in pool.map_unordered(*_tasks(compute_stages, [(j,) for j in groups], shipments)):
                    bar.update(1)
        if dedupe and pending:
            bar = progress_bar(total=len(pending), desc="decisions", unit="run", disable=not progress)
            decisions = []
            with bar, timed(LOG, PHASES[1]):
                chunks = [(c,) for c in _chunks(pending, 4 * workers)]
                for _, answer in pool.map_unordered(*_tasks(decide, chunks, shipments)):
                    decisions.extend(answer)
                    bar.update(len(answer))
            order = {j.key: i for i, j in enumerate(pending)}
            decisions.sort(key=lambda d: order[d.key])
        alone: list[SweepJob] = []
        leaders: dict[str, Decision] = {}
        followers: dict[str, list[SweepJob]] = {}
        for decision in decisions:
            job = by_key[decision.key]
            if decision.signature is None:
                alone.append(job)
                continue
            existing = store.by_signature(decision.signature)
            if existing is not None:
                store.add(_same_run(existing, job))
            elif decision.signature in leaders:
                followers[leaders[decision.signature].key].append(job)
            else:
                leaders[decision.signature] = decision
                followers[decision.key] = []
        roots: dict[str, list[Decision]] = {}
        for decision in leaders.values():
            roots.setdefault(decision.root, []).append(decision)
        trees = _split(list(roots.values()), 4 * workers - len(alone))
        trees.sort(key=len, reverse=True)  # the longest first: the workers finish together
        tasks = [(run_job, (job, version)) for job in alone] + [
            (
                run_branches,
                ([by_key[d.key] for d in tree], [d.path for d in tree], [d.signature for d in tree], version),
            )
            for tree in trees
        ]
        remaining = len(alone) + sum(1 + len(followers[d.key]) for d in leaders.values())
        bar = progress_bar(
            total=len(jobs),
            initial=len(jobs) - remaining,
            desc="sweep",
            unit="run",
            disable=not progress,
            smoothing=0.1,
        )
        tracked = 0
        failures = []
        with bar, timed(LOG, PHASES[2]):
            for _, records in pool.map_unordered(*_tasks(_dispatch, tasks, shipments)):
                for record in records:
                    if isinstance(record, Failure):
                        if record.evidence is not None or record.log:  # the program ran
                            failures.append(keep_failure(store.path.parent / FAILURES, record))
                        record = record.record
                    store.add(record)
                    tracked += 1
                    for other in followers.get(record.key, []):
                        store.add(_same_run(record, other))
                    bar.update(1 + len(followers.get(record.key, [])))
        failed = False
        if shipments is not None:
            LOG.log(DETAIL, "%d sequences put into Ray's object store over the phases", shipments.put_count)
    finally:
        pool.close(failed)
    if failures:
        LOG.warning(
            f"{len(failures)} runs failed; what each program was given and wrote is in "
            f"{failures[-1].parent}/KEY/ (the last {KEEP_FAILURES} failed runs are kept)"
        )
    return tracked, len(pending)


def open_store(out: Path, spec: SweepSpec, spec_path: Path | None = None) -> ResultStore:
    out.mkdir(parents=True, exist_ok=True)
    store = ResultStore(out / DATABASE)
    # Rows are keyed by content: after a change of spec the old ones stay valid and new ones add.
    store.set_meta("spec", spec.model_dump_json())
    if spec_path is not None:  # where the spec's relative paths start, for a report's re-runs
        store.set_meta("spec_path", str(spec_path.resolve()))
    store.set_meta("bench_version", code_version())
    return store
