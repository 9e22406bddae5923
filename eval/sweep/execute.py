"""A whole sweep into a folder: sequences, rows, CSV, summary and plots.

``depotbench sweep``, ``depotbench check`` and ``depotbench demo`` all run their
matrix through this one function (and so through ``depotbench.eval.sweep.engine.run_jobs``).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from depotbench.core.files import dumps_json
from depotbench.core.output import OutputContainer, OutputKind, write_text_atomic
from depotbench.eval.metrics.record import RunRecord
from depotbench.eval.metrics.statistics import SuccessRule
from depotbench.eval.run.cache import StageCache
from depotbench.eval.sweep.engine import (
    SweepJob,
    expand,
    open_store,
    run_jobs,
    sequences_of,
    spec_inputs,
    validate,
)
from depotbench.eval.sweep.spec import SweepSpec, load_sweep
from depotbench.eval.sweep.store import ResultStore
from depotbench.eval.sweep.summary import best_per_family, configurations, pareto, plot, unqualified, with_rho
from depotbench.slam import kernels

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class SweepOutcome:
    records: list[RunRecord]
    """This sweep's runs (with this sweep's families; sequences named absolutely)."""
    summary: dict[str, Any]
    jobs: int
    written: int
    tracked: int
    seconds: float
    plots: list[Path]
    search: dict[str, Any] | None


def _older_versions(store: ResultStore, jobs: list[SweepJob], prune: bool) -> None:
    """Rows of an older version of one of this sweep's trackers (another fingerprint) are
    kept apart (here and, through the store's record of the current versions, in ``report``),
    said in one line per version; ``prune`` removes them, each version named before its rows
    go."""
    current = {j.run.tracker: j.run.tracker_fingerprint or "" for j in jobs}
    store.set_versions(current)
    for tracker, fingerprint, rows in store.older_versions(current):
        what = f"{rows} row{'s' if rows != 1 else ''} of tracker {tracker} fingerprint {fingerprint}"
        if prune:
            LOG.info(f"--prune-stale: removing {what} (now {current[tracker]})")
            store.remove_version(tracker, fingerprint)
        else:
            LOG.info(f"{what} (now {current[tracker]}) kept apart, not reused; --prune-stale removes them")


def execute_sweep(
    spec: SweepSpec,
    spec_path: Path,
    out: Path,
    workers: int,
    *,
    progress: bool = True,
    dedupe: bool = True,
    backend: str = "local",
    address: str | None = None,
    announce: bool = True,
    retry_failed: bool = False,
    prune_stale: bool = False,
) -> SweepOutcome:
    """Generate (or resume) the sequences, run the missing rows (``retry_failed``: and the
    failed ones), write results.csv, summary.json and plots under ``out`` (a folder the
    caller owns)."""
    from depotbench.eval.sweep.search import run_search

    where = {"backend": backend, "address": address}
    baseline = None if spec.baseline is None else spec.baseline.to_baseline()
    sequences = sequences_of(spec, spec_path, out, workers, progress=progress, **where)
    jobs = expand(spec, spec_path, sequences, anchor=out)
    with open_store(out, spec, spec_path) as store:
        stored = store.keys()
        done = len(stored & {j.key for j in jobs})
        failed = len(store.failed_keys() & {j.key for j in jobs})
        if announce:
            LOG.info(
                f"sweep {spec.sweep}: {len(jobs)} runs over {len(sequences)} sequences ({done} already done"
                f"{_failed_ones(failed, retry_failed)})"
            )
        _older_versions(store, jobs, prune_stale)
        moved = store.relabel([j.run for j in jobs if j.key in stored])
        if moved and announce:
            LOG.info(f"{moved} done runs now name their sequence where this sweep finds it")
        if any(j.job.tracker.type.per_keypoint for j in jobs if j.key not in stored):
            # Compiled here once, into Numba's cache, before any worker starts: each worker
            # then loads them (0.5 s) instead of compiling its own (14 s, the first job's
            # worth of ETA), and none inside a timed frame (every worker also calls it).
            kernels.ready()
        stages = StageCache.from_env()
        if stages is not None:
            stages.probe()  # warned here, once, not by each worker (their lines lack the prefix)
        started = time.perf_counter()
        tracked, written = run_jobs(
            jobs, store, workers, progress=progress, dedupe=dedupe, retry_failed=retry_failed, **where
        )
        elapsed = time.perf_counter() - started
        # A family is how this sweep groups sequences, not part of a run's content:
        # rows carry the family of the sweep that asked for them now.
        family = {j.key: j.family for j in jobs}
        search = None
        if spec.search is not None:
            search = run_search(spec, spec_path, sequences, store, out, workers, **where)
            family |= search.pop("families")
        records = [replace(r, family=family[r.key]) for r in store.records() if r.key in family]
        store.export_csv(out / "results.csv", [run.to_row() for run in with_rho(records, baseline)])
        # Rows name a sequence inside the sweep folder relative to it (a moved sweep keeps its
        # figures); those handed on (gates, the plugin) name it absolutely.
        records = [
            replace(r, sequence=str(out.resolve() / r.sequence)) if not Path(r.sequence).is_absolute() else r
            for r in records
        ]
    rule = SuccessRule(spec.statistics.min_tracked_fraction)
    configs = configurations(records, rule, baseline)
    best = best_per_family(configs, spec.statistics.best_min_success_rate)
    summary = {
        "best": best,
        "unqualified": unqualified(configs, best),
        "success_rule": {
            "min_tracked_fraction": rule.min_tracked_fraction,
            "best_min_success_rate": spec.statistics.best_min_success_rate,
        },
        "pareto": pareto(configs),
        "baseline": None if baseline is None else baseline.to_dict(),
        "configurations": configs,
        "search": search,
    }
    write_text_atomic(out / "summary.json", dumps_json(summary) + "\n")
    plots = _plots(configs, out / "plots", records, rule, summary)
    return SweepOutcome(records, summary, len(jobs), written, tracked, elapsed, plots, search)


PLOTS_INDEX = ".index.json"
"""Beside the plots: the key of what they were drawn from and each file's SHA-256."""


def _plots(configs: list[dict], folder: Path, records: list, rule: SuccessRule, summary: dict) -> list[Path]:
    """The sweep's plots, drawn again only when what they show changed: a resumed sweep with
    nothing new kept its plots (drawing them is 6 s of the demo's 13 s second run). Their key
    is the summary, every row and the code (``code_version``); a plot file changed or missing since
    is drawn again."""
    from depotbench.core.files import file_digest
    from depotbench.core.version import code_version
    from depotbench.eval.run.cache import content_hash

    key = content_hash(code_version(), dumps_json(summary), [r.to_row() for r in records])
    index = folder / PLOTS_INDEX
    try:
        kept = json.loads(index.read_text(encoding="utf-8")) if index.is_file() else None
    except (OSError, ValueError):
        kept = None
    if isinstance(kept, dict) and kept.get("key") == key and isinstance(kept.get("files"), dict):
        paths = [folder / name for name in kept["files"]]
        if all(p.is_file() and file_digest(p, "plot").hex() == kept["files"][p.name] for p in paths):
            LOG.debug("plots unchanged (key %s): kept", key)
            return paths
    written = plot(configs, folder, records, rule)
    files = {p.name: file_digest(p, "plot").hex() for p in written}
    write_text_atomic(index, json.dumps({"key": key, "files": files}, indent=1) + "\n")
    return written


def _failed_ones(failed: int, retry_failed: bool) -> str:
    """What the status line says of stored failed rows: a failure (a time-out on a loaded
    machine, say) is reused as any row unless the user asks to run it again."""
    if not failed:
        return ""
    if retry_failed:
        return f"; its {failed} failed runs run again"
    return f"; {failed} of them failed and are reused: --retry-failed runs them again"


def sweep_folder(
    spec_path: Path,
    out: Path,
    workers: int,
    *,
    progress: bool = True,
    dedupe: bool = True,
    backend: str = "local",
    address: str | None = None,
    retry_failed: bool = False,
    prune_stale: bool = False,
) -> SweepOutcome:
    """A sweep spec file run into the folder ``out``: the spec and every file it names are
    checked before the folder is made, and an existing folder is resumed only if it is a
    depotbench sweep folder (never someone else's files); ``prune_stale``: the rows of older
    versions of its trackers are removed."""
    spec = load_sweep(spec_path)
    validate(spec, spec_path)
    with OutputContainer(out, OutputKind.SWEEP, inputs=spec_inputs(spec, spec_path)) as container:
        return execute_sweep(
            spec,
            spec_path,
            container.path,
            workers,
            progress=progress,
            dedupe=dedupe,
            backend=backend,
            address=address,
            retry_failed=retry_failed,
            prune_stale=prune_stale,
        )
