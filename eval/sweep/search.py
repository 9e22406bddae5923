"""An Optuna search for the thresholds that minimise a sweep objective.

Each trial is one setting of the searched strategy's thresholds, run on every
sequence, tracker and detector of the sweep through the same engine, so its runs
are ordinary rows of ``results.sqlite`` (and a value tried twice is not run
twice). The study lives beside them in ``optuna.sqlite``; a killed search
resumes with the trials it completed (a trial cut short is marked failed). TPE
is seeded, but a resumed study does not replay the sampler's state, and with the
``ate_time`` objective timings enter the value: trials are reproducible run by
run, the search path only from a fresh start with ``mean_ate``.
"""

from __future__ import annotations

import logging
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from depotbench.core.errors import InputError
from depotbench.core.files import open_regular
from depotbench.core.parameters import parameter_text
from depotbench.detectors.config import DetectorConfig
from depotbench.eval.metrics.record import RunRecord
from depotbench.eval.run.cache import content_hash
from depotbench.eval.run.detections import sequence_fingerprint
from depotbench.eval.run.harness import tracker_identity
from depotbench.eval.sweep.engine import jobs_for, run_jobs, sequence_entries
from depotbench.eval.sweep.spec import (
    Search,
    SweepSpec,
    Variant,
    check_variants,
    detector_configs,
    threshold_value,
    tracker_configs,
)
from depotbench.eval.sweep.store import SQLITE_HEADER, ResultStore
from depotbench.eval.trackers.registry import TrackerConfig, tracker_parameters
from depotbench.eval.trackers.registry import check as check_tracker
from depotbench.sim.sequence import Sequence

LOG = logging.getLogger(__name__)
STUDY = "optuna.sqlite"


def _optuna():
    try:
        import optuna
    except ImportError:
        raise InputError("search: Optuna is not installed: pip install 'depotbench[search]'") from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna


def objective(records: list[RunRecord], search: Search) -> float:
    ates = [r.ate_rmse_m for r in records]
    if not records or any(a is None or not np.isfinite(a) for a in ates):
        return float("inf")  # a run without a trajectory is the worst outcome
    value = float(np.mean(ates))
    if search.objective == "ate_time":
        times = [r.track_ms_median for r in records if r.track_ms_median is not None]
        value += search.time_weight * float(np.mean(times)) if times else 0.0
    return value


def study_name(
    spec: SweepSpec,
    sequences: list,
    trackers: list[TrackerConfig],
    detectors: list[DetectorConfig],
) -> str:
    """The study's name: the sweep's, and a hash of everything a trial's value depends on
    (the space, objective, weight and seed; the sequences' content, trackers and detectors).
    A study resumed by the sweep's name alone counted trials of an old space or objective,
    and could report a "best" outside the space asked for."""
    assert spec.search is not None
    key = content_hash(
        spec.search.model_dump(mode="json"),
        [sequence_fingerprint(Sequence.open(entry.root)) for entry in sequence_entries(sequences)],
        [tracker_identity(t) for t in trackers],
        [(d.key(), d.faults.to_dict()) for d in detectors],
    )
    return f"{spec.sweep}-{key[:12]}"


def _open_study(optuna, path: Path, name: str, seed: int):
    """The study ``name`` in ``path``, created or resumed (a trial cut short by a kill is
    marked failed); a file that is not a readable Optuna database is refused untouched."""
    if path.exists():
        with os.fdopen(open_regular(path, 1 << 40, "Optuna study"), "rb") as handle:
            if handle.read(len(SQLITE_HEADER)) not in (b"", SQLITE_HEADER):
                raise InputError(f"{path}: not an Optuna study (not an SQLite file); move it away")
    from sqlalchemy.exc import SQLAlchemyError

    try:
        study = optuna.create_study(
            study_name=name,
            storage=f"sqlite:///{path}",
            sampler=optuna.samplers.TPESampler(seed=seed),
            direction="minimize",
            load_if_exists=True,
        )
        for stale in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,)):
            study.tell(stale.number, state=optuna.trial.TrialState.FAIL)
    except (SQLAlchemyError, optuna.exceptions.StorageInternalError) as exc:
        reason = str(getattr(exc, "orig", None) or exc).splitlines()[0]
        raise InputError(
            f"{path}: not a readable Optuna study ({reason}); move it away to search again"
        ) from None
    return study


def _trial_jobs(
    spec: SweepSpec,
    values: dict[str, float],
    trackers: list[TrackerConfig],
    detectors: list[DetectorConfig],
    sequences: list,
    source: str | None = None,
    anchor: Path | None = None,
) -> list:
    """A trial's jobs: the strategy's thresholds at ``values`` with every tracker, or the
    searched tracker's parameters at ``values`` with the strategy it runs. ``source``:
    check the values first (a new trial; an earlier one was checked when it ran)."""
    search = spec.search
    assert search is not None
    if search.tracker is None:
        settings = tuple((n, threshold_value(n, v)) for n, v in sorted(values.items()))
        variant = Variant(search.strategy, settings)
        if source is not None:
            check_variants(spec, [variant], trackers, source)
        return jobs_for([variant], trackers, detectors, sequences, anchor, spec.dense_map)
    base = next(t for t in trackers if t.label == search.tracker)
    settings = {n: parameter_text(v) for n, v in values.items()}  # a program's parameters are text
    tracker = replace(base, parameters=tracker_parameters(base.kind, dict(base.parameters) | settings))
    if source is not None:
        try:
            check_tracker(tracker)
        except InputError as exc:
            raise InputError(f"{source}: search.space: {exc}") from None
    return jobs_for([Variant(search.strategy, ())], [tracker], detectors, sequences, anchor, spec.dense_map)


def run_search(
    spec: SweepSpec,
    spec_path: Path,
    sequences: list[tuple[Path, str]],
    store: ResultStore,
    out: Path,
    workers: int,
    progress: bool = True,
    backend: str = "local",
    address: str | None = None,
) -> dict[str, Any]:
    """Run the missing trials; return the best one (settings, value, trial count) and
    ``families``: the sweep family of every row the trials own."""
    search = spec.search
    assert search is not None
    optuna = _optuna()
    source = str(spec_path)
    trackers, detectors = tracker_configs(spec, source), detector_configs(spec, source)
    study = _open_study(optuna, out / STUDY, study_name(spec, sequences, trackers, detectors), search.seed)
    complete = optuna.trial.TrialState.COMPLETE
    families: dict[str, str] = {}
    for trial in study.get_trials(deepcopy=False, states=(complete,)):  # earlier trials' rows
        earlier = _trial_jobs(spec, trial.params, trackers, detectors, sequences, anchor=out)
        families |= {j.key: j.family for j in earlier}
    while len(study.get_trials(deepcopy=False, states=(complete,))) < search.trials:
        trial = study.ask()
        values = {
            name: trial.suggest_float(name, interval.low, interval.high, log=interval.log)
            for name, interval in sorted(search.space.items())
        }
        jobs = _trial_jobs(spec, values, trackers, detectors, sequences, source, anchor=out)
        families |= {j.key: j.family for j in jobs}
        run_jobs(jobs, store, workers, progress=False, backend=backend, address=address)
        keys = {j.key for j in jobs}
        value = objective([r for r in store.records() if r.key in keys], search)
        study.tell(trial, value)
        if progress:
            shown = {n: parameter_text(v) for n, v in sorted(values.items())}
            LOG.info(f"trial {trial.number}: {shown} -> {search.objective} {value:.5f}")
    best = study.best_trial
    return {
        "strategy": search.strategy,
        "tracker": search.tracker,
        "objective": search.objective,
        "value": best.value,
        "settings": {n: parameter_text(v) for n, v in sorted(best.params.items())},
        "trials": len(study.get_trials(deepcopy=False, states=(complete,))),
        "families": families,
    }
