"""Sweep throughput, and what the stage cache saves over a naive sweep of the same work.

Usage: python benchmarks/sweep.py [--frames 40] [--seeds 1 2 3 4] [--configs 20] [--workers 2]
                                  [--detector groundtruth|onnx]

Generates a walking_static suite (one sequence per seed), then runs the same jobs
three times through the engine, each time on a fresh cache folder:
- naive: no stage cache (every run detects, extracts ORB features and runs LK itself);
- cache: the stage cache (detections, features and flow computed once per sequence);
- cache + dedupe: and jobs that keep the same keypoints in every frame tracked once.
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

from depotbench.eval.metrics.record import DETERMINISTIC_FIELDS
from depotbench.eval.run.detections import sequence_fingerprint
from depotbench.eval.run.harness import job_key, tracker_identity
from depotbench.eval.sweep.engine import SweepJob, expand, run_jobs
from depotbench.eval.sweep.spec import SweepSpec
from depotbench.eval.sweep.store import ResultStore
from depotbench.sim.sequence import Sequence

GRID = {
    "epsilon_px": [0.25, 0.5, 1.0, 2.0, 4.0],
    "l_thr1_px": [0.5, 1.0, 1.5, 2.0, 2.5],
    "l_thr2_px": [1.0, 2.0, 3.0, 5.0],
}


def _sequences(out: Path, frames: int, seeds: list[int], workers: int) -> list[tuple[Path, str]]:
    from depotbench.scenes.generation import run_suite
    from depotbench.scenes.suite import Suite

    suite = Suite(
        suite="walking", base="walking_static", overrides={"frames": frames, "duration_s": None}, seeds=seeds
    )
    index = run_suite(suite, out / "suite.yaml", out / "sequences", workers, progress=False)
    return [(out / "sequences" / e["name"], "walking_static") for e in index["sequences"]]


def _timed(jobs, out: Path, workers: int, cache: bool, dedupe: bool) -> tuple[float, int, list[dict]]:
    os.environ["DEPOTBENCH_CACHE"] = str((out / "cache").absolute()) if cache else "off"
    fields = [f for f in DETERMINISTIC_FIELDS if f not in ("signature", "computed_by")]
    out.mkdir(parents=True)
    with ResultStore(out / "results.sqlite") as store:
        started = time.perf_counter()
        tracked, _ = run_jobs(jobs, store, workers, progress=True, dedupe=dedupe)
        elapsed = time.perf_counter() - started
        rows = [{k: r[k] for k in fields} for r in store.rows()]
    return elapsed, tracked, rows


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--configs", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip-naive", action="store_true", help="only the cached sweep")
    parser.add_argument(
        "--detector",
        default="groundtruth",
        help="the boxes: groundtruth (free) or onnx (the shipped YOLOX-nano, ~31 ms a frame)",
    )
    args = parser.parse_args()
    combos = list(itertools.product(*GRID.values()))[: args.configs]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        sequences = _sequences(root, args.frames, args.seeds, args.workers)
        spec = SweepSpec(
            sweep="bench",
            sequences=["-"],
            detectors=[args.detector],
            strategies=["none", "box_epipolar_flow"],
        )
        jobs = expand(spec, root / "spec.yaml", sequences)
        none_jobs = [j for j in jobs if j.job.strategy == "none"]
        template = [j for j in jobs if j.job.strategy == "box_epipolar_flow"]
        work = list(none_jobs)
        for base in template:
            fingerprint = sequence_fingerprint(Sequence.open(base.job.sequence))
            for combo in combos:
                settings = tuple(zip(GRID, (repr(float(v)) for v in combo), strict=True))
                tracker = tracker_identity(base.job.tracker)
                key = job_key(fingerprint, tracker, base.job.detector, "box_epipolar_flow", settings)
                job = replace(base.job, settings=settings)
                run = replace(base.run, key=key, settings=settings)
                work.append(SweepJob(key, base.family, job, fingerprint, run))
        print(
            f"{len(sequences)} walking_static sequences x {args.frames} frames; {len(work)} runs "
            f"(none + {len(combos)} box_epipolar_flow configurations each), {args.workers} workers, "
            f"{args.detector} boxes"
        )
        results = {}
        modes = [("cache + dedupe", True, True), ("cache", True, False)]
        if not args.skip_naive:
            modes.append(("naive", False, False))
        for label, cache, dedupe in modes:
            folder = root / label.replace(" ", "").replace("+", "_")
            elapsed, tracked, rows = _timed(work, folder, args.workers, cache, dedupe)
            results[label] = (elapsed, rows)
            print(
                f"{label:16s}{elapsed:8.1f} s {len(work) / elapsed * 60:9.1f} runs/min "
                f"({tracked} tracked, {len(work) - tracked} shared)"
            )
        if "naive" in results:
            naive_s, naive_rows = results["naive"]
            for label in ("cache", "cache + dedupe"):
                elapsed, rows = results[label]
                print(
                    f"speed-up of {label} over naive: {naive_s / elapsed:.2f}x; "
                    f"same rows: {rows == naive_rows}"
                )


if __name__ == "__main__":
    main()
