"""``benchmark run``: one tracker configuration over every sequence of a benchmark, repeated
where the tracker is not deterministic, into a results file others can check.

Each run leaves its folder (``runs/SCENARIO/NAME/rK``: trajectory, metrics, record). The
figures in ``results.json`` are computed from the trajectory file as written, the way
``benchmark verify`` recomputes them, so a result and its check read the same bytes. A run
whose record holds the job's key (sequence bytes, tracker and program, detector, strategy,
settings, bench version) is kept when the command is given again: an interrupted benchmark
resumes. A run that fails (a program's exit, a time limit) is a failed run in the results,
counted and shown, never dropped.
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError
from depotbench.core.files import file_digest, read_json
from depotbench.eval.benchmark.results import FORMAT, FORMAT_VERSION, figures_of
from depotbench.eval.benchmark.sequences import Prepared, draw_fresh_seeds, prepare, prepare_fresh
from depotbench.eval.benchmark.spec import Benchmark
from depotbench.eval.run.harness import RunJob
from depotbench.sim.machine import machine_summary

LOG = logging.getLogger(__name__)
RESULTS_NAME = "results.json"
MIN_REPEATS = 3
"""Runs per sequence of a tracker that is not deterministic: ORB-SLAM3 gave 390 and 119 mm
on one walking sequence in two runs, so one run is never the answer, and three give a median."""


@dataclass(frozen=True)
class Plan:
    """What a benchmark run scores: a job template (its sequence replaced per sequence)."""

    job: RunJob
    repeats: int
    deterministic: bool


def repeats_for(deterministic: bool, asked: int | None) -> int:
    """The built-in tracker repeats itself bit for bit (a test holds it): once. Any other
    runs ``asked`` times, at least ``MIN_REPEATS``."""
    if deterministic:
        if asked not in (None, 1):
            raise InputError(
                f"--repeats {asked}: this tracker is deterministic (its runs repeat bit for bit): "
                "it runs once"
            )
        return 1
    if asked is None:
        return MIN_REPEATS
    if asked < MIN_REPEATS:
        raise InputError(
            f"--repeats {asked}: a tracker that is not deterministic runs at least {MIN_REPEATS} times a "
            "sequence (one run is no answer: its spread is the finding)"
        )
    return asked


def _run_one(job: RunJob, target: str, key: str | None) -> dict[str, Any]:
    """Worker: one run into ``target`` (kept where its record holds ``key``); its figures."""
    folder = Path(target)
    if _kept(folder, key):
        return _figures(job, folder, resumed=True)
    failed = _run_into(job, folder)
    return failed if failed is not None else _figures(job, folder, resumed=False)


def _kept(folder: Path, key: str | None) -> bool:
    """Whether ``folder`` holds a finished run of the job keyed ``key`` (an earlier command's)."""
    record = folder / "record.json"
    if key is None or not record.is_file():
        return False
    kept = read_json(record, 1 << 20, "run record")
    return isinstance(kept, dict) and kept.get("key") == key and (folder / "metrics.json").is_file()


def _run_into(job: RunJob, folder: Path) -> dict[str, Any] | None:
    """One run into ``folder``; None, or the failed outcome of a program that failed."""
    from depotbench.eval.run.harness import run_job
    from depotbench.eval.trackers.base import TrackerError

    try:
        run_job(job, folder, progress=False, overwrite=True)
    except TrackerError as exc:
        return _failed(str(exc).splitlines()[0])
    return None


def _failed(reason: str) -> dict[str, Any]:
    return {"status": "failed", "failure": reason, "resumed": False}


def _run_on_node(job: RunJob, source: Any, fingerprint: str | None) -> bytes | dict[str, Any]:
    """Worker entry point on a cluster's node: the run in a folder of the node's own, sent
    back packed for the driver to write; or the failed outcome (a program that failed, or
    this node's program not the driver's)."""
    import tempfile
    from dataclasses import replace

    from depotbench.eval.run.nodes import local_sequence, program_differs
    from depotbench.scenes.shipping import node_root_made, pack_folder

    differs = program_differs(job.tracker, fingerprint)
    if differs is not None:
        return _failed(differs)
    job = replace(job, sequence=local_sequence(source))
    with tempfile.TemporaryDirectory(prefix="depotbench-run-", dir=node_root_made()) as work:
        folder = Path(work) / "run"
        failed = _run_into(job, folder)
        return failed if failed is not None else pack_folder(folder)


def _on_nodes(pool: Any, items: list[tuple], prepared: list[Prepared], fingerprint: str):
    """``_run_one`` over ``items`` on a cluster whose nodes share no folder with this
    machine: runs kept from an earlier command are found here, each sequence is put into
    Ray's object store as its first run is submitted (``Shipments``), and each run's folder
    comes back to be written here."""
    from depotbench.core.output import OutputKind
    from depotbench.eval.run.nodes import Shipments
    from depotbench.scenes.shipping import unpack_output

    todo = []
    for job, target, key in items:
        if _kept(Path(target), key):
            yield (job, target, key), _figures(job, Path(target), resumed=True)
        else:
            todo.append((job, target, key))
    shipments = Shipments(pool.put, {str(p.path): p.files_key for p in prepared})
    by_call: dict[int, tuple] = {}

    def calls():
        for (job, target, key), sources in shipments.around(todo, lambda item: {str(item[0].sequence)}):
            call = (job, sources[str(job.sequence)], fingerprint)
            by_call[id(call)] = (job, target, key)
            yield call

    for call, answer in pool.map_unordered(_run_on_node, calls()):
        job, target, key = by_call.pop(id(call))
        if isinstance(answer, dict):
            yield (job, target, key), answer
            continue
        unpack_output(answer, Path(target), OutputKind.RUN)
        yield (job, target, key), _figures(job, Path(target), resumed=False)


def _figures(job: RunJob, folder: Path, resumed: bool) -> dict[str, Any]:
    metrics = json.loads((folder / "metrics.json").read_text(encoding="utf-8"))
    trajectory = folder / "trajectory.txt"
    figures = figures_of(job.sequence, trajectory if trajectory.is_file() else None, metrics["frames"])
    return {
        "status": "ok",
        "resumed": resumed,
        "figures": figures.to_dict(),
        "trajectory_sha256": file_digest(trajectory, "trajectory").hex() if trajectory.is_file() else None,
        "wall_time_s": metrics["wall_time_s"],
    }


def _score(
    prepared: list[Prepared],
    plan: Plan,
    out: Path,
    runs: str,
    workers: int,
    progress: bool,
    desc: str,
    backend: str = "local",
    address: str | None = None,
) -> tuple[list[dict[str, Any]], int]:
    """Every sequence's runs (``plan.repeats`` each, under ``out/runs``), as results entries;
    and how many runs were kept from an earlier command."""
    from depotbench.core.executors import make_pool
    from depotbench.core.progress import progress_bar
    from depotbench.eval.run.harness import job_key, tracker_fingerprint, tracker_identity

    identity = tracker_identity(plan.job.tracker)
    items = []
    for p in prepared:
        job = RunJob(p.path, plan.job.strategy, plan.job.detector, plan.job.settings, plan.job.tracker)
        key = job_key(p.files_key, identity, job.detector, job.strategy, job.settings)
        for repeat in range(plan.repeats):
            items.append((job, str(out / runs / p.sequence.folder / f"r{repeat}"), key))
    # An external program runs alone here: ORB-SLAM3's mapping thread falls behind on shared
    # cores. A cluster runs one job per CPU its nodes give.
    alone = plan.job.tracker.type.external and backend == "local"
    pool = make_pool(backend, 1 if alone else workers, address)
    outcomes: dict[str, dict[str, Any]] = {}
    bar = progress_bar(total=len(items), unit="run", desc=desc, disable=not progress)
    failed = True
    try:
        if pool.ships:
            answers = _on_nodes(pool, items, prepared, tracker_fingerprint(identity))
        else:
            answers = pool.map_unordered(_run_one, items)
        for (_, target, _), outcome in answers:
            outcomes[target] = outcome
            bar.update(1)
        failed = False
    finally:
        bar.close()
        pool.close(failed)
    sequences = []
    for p in prepared:
        entries = []
        for repeat in range(plan.repeats):
            target = out / runs / p.sequence.folder / f"r{repeat}"
            outcome = {k: v for k, v in outcomes[str(target)].items() if k != "resumed"}
            entries.append({"repeat": repeat, "folder": target.relative_to(out).as_posix(), **outcome})
        sequences.append(
            {
                "name": p.sequence.folder,
                "folder": Path(os.path.relpath(p.path, out)).as_posix(),
                "scenario": p.sequence.scenario,
                "seed": p.sequence.seed,
                "frames": p.sequence.frames,
                "files_key": p.files_key,
                "frozen": p.sequence.files_key is not None,
                "frozen_on": [on for key, on in p.sequence.machines() if key == p.files_key],
                "runs": entries,
            }
        )
    return sequences, sum(o["resumed"] for o in outcomes.values())


def run_benchmark(
    benchmark: Benchmark,
    plan: Plan,
    out: Path,
    workers: int,
    progress: bool = True,
    fresh_seeds: int = 0,
    entropy: int | None = None,
    backend: str = "local",
    address: str | None = None,
    sequences_root: Path | None = None,
) -> dict[str, Any]:
    """Generate and check the benchmark's sequences under ``out/sequences``, run the plan on
    each (``plan.repeats`` times), write ``out/results.json`` and return its content.

    ``sequences_root``: where the sequences are kept instead (one folder for the runs of
    several trackers: made once, checked against the lock by every run); results.json
    names them by their path from ``out``.

    ``fresh_seeds``: as many new seeds per scenario, drawn now (from ``entropy``, or the
    operating system's, recorded either way) and scored alike under ``out/fresh``: a tracker
    tuned on the frozen seeds shows there whether its tuning carries over.

    ``backend`` ``ray`` with ``address``: generation and runs on a Ray cluster whose nodes
    share no folder with this machine (``docs/cluster.md``); the results are the same."""
    import numpy as np
    from depotbench.core.output import write_text_atomic
    from depotbench.core.version import code_version
    from depotbench.eval.run.harness import tracker_fingerprint, tracker_identity

    started = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    where = {"backend": backend, "address": address}
    prepared = prepare(benchmark, sequences_root or out / "sequences", workers, progress, **where)
    sequences, resumed = _score(prepared, plan, out, "runs", workers, progress, benchmark.name, **where)
    fresh = None
    if fresh_seeds:
        if entropy is None:
            entropy = int(np.random.SeedSequence().entropy)
        drawn = draw_fresh_seeds(benchmark, fresh_seeds, entropy)
        found = prepare_fresh(benchmark, drawn, out / "fresh", workers, progress, **where)
        scored, again = _score(
            found, plan, out, "fresh-runs", workers, progress, f"{benchmark.name} fresh", **where
        )
        fresh = {"entropy": str(entropy), "seeds": drawn, "sequences": scored}
        resumed += again
    tracker = plan.job.tracker
    identity = tracker_identity(tracker)
    results = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "benchmark": benchmark.name,
        "benchmark_generator": benchmark.spec.generator,
        # the code that scored it: a checkout's version carries a digest of its files, which
        # change under one version number
        "depotbench": code_version(),
        # where it was scored: a tracker's outcome on a hard sequence moves with its pixels
        # and BLAS (crowd's last poses by 0.47 m between two CPUs, docs/determinism.md)
        "scored_on": machine_summary(),
        "tracker": {
            "label": tracker.label,
            "kind": tracker.kind,
            "fingerprint": tracker_fingerprint(identity),
            "identity": {k: _plain(v) for k, v in identity},
            "parameters": dict(tracker.parameters),
            "strategy": plan.job.strategy,
            "detector": plan.job.detector.label,
            "detector_config": plan.job.detector.to_dict(),
            "settings": {k: v for k, v in plan.job.settings},
            "deterministic": plan.deterministic,
        },
        "repeats": plan.repeats,
        "seconds": time.perf_counter() - started,
        "resumed_runs": resumed,
        "sequences": sequences,
        "fresh": fresh,
    }
    write_text_atomic(out / RESULTS_NAME, json.dumps(results, indent=1) + "\n")
    return results


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value
