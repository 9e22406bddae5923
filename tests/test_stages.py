"""Cached features and flow give bit-identical runs, and are reused across strategies and thresholds."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from depotbench.eval.run.cache import StageCache
from depotbench.eval.run.harness import RunJob, track
from depotbench.scenes import library
from depotbench.scenes.schema import to_scenario
from depotbench.slam.rejection import STRATEGIES

pytestmark = pytest.mark.render


@pytest.fixture(scope="module")
def walking(tmp_path_factory) -> Path:
    from depotbench.sim.generate import generate

    scenario = library.get("walking_static").model_copy(update={"frames": 30, "duration_s": None})
    return generate(to_scenario(scenario), tmp_path_factory.mktemp("walk") / "walking", progress=False)


def _fingerprint(tracked) -> tuple:
    run = tracked.run
    poses = np.array([p if p is not None else np.full((4, 4), np.nan) for p in run.poses])
    codes = np.concatenate([r.diagnostics.rejection for r in run.results])
    inliers = np.concatenate([r.diagnostics.inlier for r in run.results])
    return poses.tobytes(), codes.tobytes(), inliers.tobytes(), tuple(run.states)


@pytest.mark.parametrize(  # 4 s each: the first and the last (boxes, flow and epipolar) by default
    "strategy",
    [
        s if s in (STRATEGIES[0], STRATEGIES[-1]) else pytest.param(s, marks=pytest.mark.slow)
        for s in STRATEGIES
    ],
)
def test_a_run_on_cached_stages_is_bit_identical_to_a_live_one(walking: Path, tmp_path: Path, strategy: str):
    settings = (("k", 2.5),) if strategy == "prior_flow" else ()
    job = RunJob(walking, strategy, settings=settings)
    live = track(job)  # no cache: extracts and runs LK itself
    cache = StageCache(tmp_path / "cache")
    first = track(job, cache)  # computes the stages, then tracks on them
    again = track(job, cache)  # reads them
    assert _fingerprint(first) == _fingerprint(live) == _fingerprint(again)
    assert (
        first.metrics["ate_m"] == live.metrics["ate_m"]
        and first.metrics["rejection"] == live.metrics["rejection"]
    )
    assert again.metrics["stage_time"]["extract"]["mean_ms"] > 1.0  # the cached stage's own time is reported


def test_one_flow_stage_serves_every_flow_strategy_and_threshold(walking: Path, tmp_path: Path):
    cache = StageCache(tmp_path / "cache")
    track(RunJob(walking, "none"), cache)
    assert sorted(p.parent.name for p in (tmp_path / "cache").rglob("*") if p.is_file()) == [
        "detections",
        "features",
        "flow",
    ]
    entries = {p: p.stat().st_mtime_ns for p in (tmp_path / "cache").rglob("*") if p.is_file()}
    misses = cache.misses
    for job in (
        RunJob(walking, "prior_flow", settings=(("k", 1.5),)),
        RunJob(walking, "prior_flow", settings=(("k", 3.5),)),
        RunJob(walking, "box_epipolar_flow", settings=(("epsilon_px", 0.5),)),
    ):
        track(job, cache)
    assert cache.misses == misses  # every stage came from the cache
    assert {p for p in (tmp_path / "cache").rglob("*") if p.is_file()} == set(entries)
    # A tracking setting changes the features: a new entry.
    track(RunJob(walking, "none", settings=(("n_features", 800),)), cache)
    assert len([p for p in (tmp_path / "cache" / "features").iterdir()]) == 2


def test_deduplicated_sweep_rows_equal_tracking_every_job(walking: Path, tmp_path: Path, caplog):
    """Jobs that keep the same keypoints in every frame are tracked once; their rows equal
    those of tracking each job (here l_thr2_px 50/60/70 decide alike: the flow's std is
    always below them). ``-v`` times each phase that ran: the decision paths only where
    jobs are deduplicated."""
    from depotbench.core.logs import DETAIL
    from depotbench.eval.metrics.record import DETERMINISTIC_FIELDS
    from depotbench.eval.sweep.engine import PHASES, expand, run_jobs
    from depotbench.eval.sweep.spec import load_sweep
    from depotbench.eval.sweep.store import ResultStore

    spec_path = tmp_path / "s.yaml"
    spec_path.write_text(
        f"sweep: d\nsequences: [{walking}]\nstrategies: [none, prior_flow, box_epipolar_flow]\n"
        "thresholds:\n  prior_flow: {k: {grid: [2.0, 3.0]}}\n"
        "  box_epipolar_flow: {l_thr2_px: {grid: [50, 60, 70]}}\n"
    )
    jobs = expand(load_sweep(spec_path), spec_path, [(walking, "walking")])
    fields = [f for f in DETERMINISTIC_FIELDS if f not in ("signature", "computed_by")]
    tables = {}
    for dedupe in (True, False):
        caplog.clear()
        with ResultStore(tmp_path / f"{dedupe}.sqlite") as store:
            with caplog.at_level(DETAIL, "depotbench"):
                tracked, written = run_jobs(jobs, store, workers=1, progress=False, dedupe=dedupe)
            tables[dedupe] = [{k: r[k] for k in fields} for r in store.rows()]
            if dedupe:
                assert written == 6 and tracked <= 4  # the three l_thr2_px values are one run
                rows = store.rows()
                epipolar = [r for r in rows if r["strategy"] == "box_epipolar_flow"]
                assert len({r["computed_by"] for r in epipolar}) == 1
                assert len({r["signature"] for r in rows}) == tracked
            else:
                assert tracked == written == 6
        phases = [r.getMessage() for r in caplog.records if r.getMessage().startswith("phase ")]
        assert [p.rsplit(" took ", 1)[0] for p in phases] == (
            list(PHASES) if dedupe else [PHASES[0], PHASES[2]]
        )
        assert all(re.fullmatch(r".* took \d+\.\d\d s", p) for p in phases), phases
    assert tables[True] == tables[False]


def test_branching_runs_equal_each_configuration_tracked_alone(walking: Path, tmp_path: Path):
    """Thresholds whose decisions agree for some frames and then part are tracked once up
    to there and forked; every configuration's run is bit for bit its run alone."""
    from depotbench.eval.run.detections import detect_sequence
    from depotbench.eval.run.harness import prepare, stages_for, track_tree
    from depotbench.eval.run.stages import decision_path

    cache = StageCache(tmp_path / "cache")
    jobs = [
        RunJob(walking, "box_epipolar_flow", settings=(("epsilon_px", eps),))
        for eps in (0.25, 1.0, 2.0, 8.0, 16.0)
    ]
    paths = []
    for job in jobs:
        sequence, config = prepare(job)
        boxes = list(detect_sequence(sequence, job.detector, cache).per_frame)
        paths.append(decision_path(stages_for(sequence, config, cache), boxes, config))
    parted = [
        next((i for i, (a, b) in enumerate(zip(p, q, strict=False)) if a != b), None)
        for p, q in zip(paths, paths[1:], strict=False)
    ]
    assert any(i is not None and i > 1 for i in parted), parted  # some fork after shared frames
    together = track_tree(jobs, paths, cache)
    for job, shared in zip(jobs, together, strict=True):
        alone = track(job, cache)
        assert _fingerprint(shared) == _fingerprint(alone)
        assert shared.metrics["ate_m"] == alone.metrics["ate_m"]
        assert shared.metrics["rejection"] == alone.metrics["rejection"]


@pytest.mark.slow  # 9 s; test_sweep.py runs a search (then damages its study) by default
def test_an_optuna_search_runs_its_trials_as_sweep_rows_and_resumes(walking: Path, tmp_path: Path, capsys):
    pytest.importorskip("optuna")
    import json

    from depotbench.eval.cli.main import main

    spec = tmp_path / "search.yaml"
    spec.write_text(
        f"sweep: search\nsequences: [{walking}]\nstrategies: [none]\n"
        "search:\n  strategy: prior_flow\n  trials: 4\n  seed: 3\n"
        "  space: {k: {low: 1.0, high: 4.0}}\n"
    )
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "-o", str(out), "--workers", "1"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    search = summary["search"]
    assert search["trials"] == 4 and search["strategy"] == "prior_flow"
    trials = [c for c in summary["configurations"] if c["strategy"] == "prior_flow"]
    assert len(trials) == 4  # each trial is a row of the sweep (one sequence, one detector)
    assert search["value"] == pytest.approx(min(c["ate_rmse_m"] for c in trials))
    assert 1.0 <= float(search["settings"]["k"]) <= 4.0 and (out / "optuna.sqlite").is_file()
    capsys.readouterr()
    assert main(["sweep", str(spec), "-o", str(out), "--workers", "1"]) == 0  # resumed: nothing left
    assert "wrote 0 rows" in capsys.readouterr().out
    assert json.loads((out / "summary.json").read_text())["search"]["trials"] == 4
    _the_report_rebuilds_each_trials_job(spec, out, walking)


def _the_report_rebuilds_each_trials_job(spec_path: Path, out: Path, walking: Path) -> None:
    """The report tracks a featured trial again from its row alone (its settings read back
    from the row's JSON): the job it rebuilds must have the row's key, or it is not shown."""
    from depotbench.eval.report.html import _Grid, _job_of_row
    from depotbench.eval.run.detections import sequence_fingerprint
    from depotbench.eval.sweep.spec import (
        detector_configs,
        load_sweep,
        tracker_configs,
        tracker_variants,
        variants,
    )
    from depotbench.eval.sweep.store import ResultStore
    from depotbench.sim.sequence import Sequence

    spec, source = load_sweep(spec_path), str(spec_path)
    trackers = tracker_configs(spec, source)
    grid = _Grid(
        tracker_variants(spec, trackers, source), detector_configs(spec, source), variants(spec), out
    )
    sequence = Sequence.open(walking)
    with ResultStore(out / "results.sqlite", readonly=True) as store:
        trials = [r for r in store.rows() if r["strategy"] == "prior_flow"]
    assert len(trials) == 4
    for row in trials:
        job = _job_of_row(row, grid, sequence, sequence_fingerprint(sequence))
        assert job is not None and job.key == row["key"]


def test_a_run_folder_carries_the_row_a_sweep_stores_for_the_same_job(walking: Path, tmp_path: Path):
    """`depotbench run` and sweeps go through one engine: the run's record.json is the
    sweep's row for that job (deterministic fields; the sweep adds its signature)."""
    import json

    from depotbench.eval.metrics.record import DETERMINISTIC_FIELDS, RECORD_VERSION
    from depotbench.eval.run.harness import run_sequence
    from depotbench.eval.sweep.engine import expand, run_jobs
    from depotbench.eval.sweep.spec import load_sweep
    from depotbench.eval.sweep.store import ResultStore

    run_sequence(walking, tmp_path / "run", "box_rule", progress=False)
    record = json.loads((tmp_path / "run" / "record.json").read_text())
    spec_path = tmp_path / "s.yaml"
    spec_path.write_text(f"sweep: one\nsequences: [{walking}]\nstrategies: [box_rule]\n")
    jobs = expand(load_sweep(spec_path), spec_path, [(walking, "walking_static")])
    with ResultStore(tmp_path / "r.sqlite") as store:
        run_jobs(jobs, store, workers=1, progress=False)
        row = next(r for r in store.rows() if r["strategy"] == "box_rule")
    fields = [f for f in DETERMINISTIC_FIELDS if f not in ("signature", "computed_by")]
    assert {k: record[k] for k in fields} == {k: row[k] for k in fields}
    assert record["key"] == row["key"] and record["record_version"] == RECORD_VERSION
