"""Sweep throughput, and what the stage cache saves over a naive sweep of the same work.

Usage: python benchmarks/sweep.py [--frames 40] [--seeds 1 2 3 4] [--configs 20] [--workers 2]

Generates a walking_static suite (one sequence per seed), then runs the same jobs
twice through the engine, each time on a fresh cache folder:
- naive: no stage cache (every run detects, extracts ORB features and runs LK itself);
- cached: the stage cache (detections, features and flow computed once per sequence).
The jobs: ``none`` plus ``--configs`` box_epipolar_flow configurations (a grid over
epsilon_px x l_thr1_px x l_thr2_px, first N). Prints runs per minute of each and the
speed-up, and checks that both gave the same rows (timings aside).
"""

from __future__ import annotations

import argparse
import itertools
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from eval.detections import sequence_fingerprint
from eval.record import DETERMINISTIC_FIELDS
from eval.store import ResultStore
from eval.sweep import SweepJob, expand, job_key, run_jobs
from eval.sweep_spec import SweepSpec
from sim.sequence import Sequence

GRID = {
    "epsilon_px": [0.25, 0.5, 1.0, 2.0, 4.0],
    "l_thr1_px": [0.5, 1.0, 1.5, 2.0, 2.5],
    "l_thr2_px": [1.0, 2.0, 3.0, 5.0],
}


def _sequences(out: Path, frames: int, seeds: list[int], workers: int) -> list[tuple[Path, str]]:
    from scenes.generation import run_suite
    from scenes.suite import Suite

    suite = Suite(
        suite="walking", base="walking_static", overrides={"frames": frames, "duration_s": None}, seeds=seeds
    )
    index = run_suite(suite, out / "suite.yaml", out / "sequences", workers, progress=False)
    return [(out / "sequences" / e["name"], "walking_static") for e in index["sequences"]]


def _timed(jobs, out: Path, workers: int, cache: bool) -> tuple[float, list[dict]]:
    os.environ["DEPOTBENCH_CACHE_DIR"] = str(out / "cache")
    os.environ["DEPOTBENCH_CACHE"] = "on" if cache else "off"
    with ResultStore(out / "results.sqlite") as store:
        started = time.perf_counter()
        run_jobs(jobs, store, workers, progress=True)
        elapsed = time.perf_counter() - started
        rows = [{k: r[k] for k in DETERMINISTIC_FIELDS} for r in store.rows()]
    return elapsed, rows


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--configs", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip-naive", action="store_true", help="only the cached sweep")
    args = parser.parse_args()
    combos = list(itertools.product(*GRID.values()))[: args.configs]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        sequences = _sequences(root, args.frames, args.seeds, args.workers)
        spec = SweepSpec(sweep="bench", sequences=["-"], strategies=["none", "box_epipolar_flow"])
        jobs = expand(spec, root / "spec.yaml", sequences)
        none_jobs = [j for j in jobs if j.job.strategy == "none"]
        template = [j for j in jobs if j.job.strategy == "box_epipolar_flow"]
        work = list(none_jobs)
        for base in template:
            fingerprint = sequence_fingerprint(Sequence.open(base.job.sequence))
            for combo in combos:
                settings = tuple(zip(GRID, (repr(float(v)) for v in combo), strict=True))
                key = job_key(fingerprint, base.job.tracker, base.job.detector, "box_epipolar_flow", settings)
                work.append(SweepJob(key, base.family, replace(base.job, settings=settings)))
        print(
            f"{len(sequences)} walking_static sequences x {args.frames} frames; {len(work)} runs "
            f"(none + {len(combos)} box_epipolar_flow configurations each), {args.workers} workers"
        )
        cached_s, cached_rows = _timed(work, root / "cached", args.workers, cache=True)
        print(f"cached: {cached_s:7.1f} s, {len(work) / cached_s * 60:7.1f} runs/min")
        if not args.skip_naive:
            naive_s, naive_rows = _timed(work, root / "naive", args.workers, cache=False)
            print(f"naive:  {naive_s:7.1f} s, {len(work) / naive_s * 60:7.1f} runs/min")
            print(f"speed-up of the cache: {naive_s / cached_s:.2f}x; same rows: {naive_rows == cached_rows}")


if __name__ == "__main__":
    main()
