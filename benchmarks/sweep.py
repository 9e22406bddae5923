"""Sweep throughput, and what the stage cache saves over a naive sweep of the same work.

Usage: python benchmarks/sweep.py [--frames 40] [--seeds 1 2 3 4] [--configs 20] [--workers 2]
                                  [--detector groundtruth|onnx] [--skip-naive] [--baseline [REV]]

Generates a walking_static suite (one sequence per seed), then runs the same jobs
three times through the engine, each time on a fresh cache folder:
- naive: no stage cache (every run detects, extracts ORB features and runs LK itself);
- cache: the stage cache (detections, features and flow computed once per sequence);
- cache + dedupe: and jobs that keep the same keypoints in every frame tracked once.
The jobs: ``none`` plus ``--configs`` box_epipolar_flow configurations (a grid over
epsilon_px x l_thr1_px x l_thr2_px, first N). Prints runs per minute of each and the
speed-up, and checks that both gave the same rows (timings aside). Below each mode, the
seconds of each phase of the engine that ran (``depotbench -v`` shows the same lines): the
shared stages, the decision paths, tracking.

``--baseline [REV]`` (REV defaults to ``BEFORE_ISSUE_40``) also runs the cache + dedupe sweep
on the code of revision REV, in this run, on this machine and on the same sequences: the
revision's files come out of git into a temporary folder, and a child process runs this
script's sweep with its ``depotbench`` imported from there (settings passed as that code
takes them). It runs first; then this code's modes, and the speed-up of this code over REV.
"""

from __future__ import annotations

import argparse
import io
import itertools
import logging
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import time
import tomllib
from dataclasses import replace
from pathlib import Path

from depotbench.eval.metrics.record import DETERMINISTIC_FIELDS
from depotbench.eval.run.detections import sequence_fingerprint
from depotbench.eval.run.harness import job_key, tracker_identity
from depotbench.eval.sweep.engine import SweepJob, expand, run_jobs
from depotbench.eval.sweep.spec import SweepSpec
from depotbench.eval.sweep.store import ResultStore
from depotbench.sim.sequence import Sequence

REPO = Path(__file__).resolve().parent.parent
BEFORE_ISSUE_40 = "1010605"
"""The last commit before issue 40 (local mapping as ORB-SLAM builds it, compiled hot paths),
which asked for a sweep at least 2x faster than this code's."""
BASELINE_LINE = re.compile(r"^cache \+ dedupe\s+([0-9.]+) s", re.M)
"""The child's line that gives the revision's cache + dedupe time."""
PHASE_LINE = re.compile(r"^phase (\d), (.*), took ([0-9.]+) s$")
"""The engine's ``-v`` line that times one of its phases (``engine.PHASES``)."""


class _Phases(logging.Handler):
    """Seconds of each phase of ``run_jobs`` that ran, by its name, from the engine's ``-v``
    lines (none from a revision whose engine does not time them)."""

    def __init__(self) -> None:
        super().__init__()
        self.seconds: dict[str, float] = {}

    def emit(self, record: logging.LogRecord) -> None:
        found = PHASE_LINE.match(record.getMessage())
        if found:
            self.seconds[found[2]] = float(found[3])


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


def _typed_settings() -> bool:
    """Whether the imported depotbench takes typed settings (0.5: parsed at the edge) or the
    text of ``--set`` (before issue 39)."""
    from depotbench.slam import config

    return hasattr(config, "setting_value")


def _use_cache(folder: Path | None) -> None:
    """Point the stage cache at ``folder`` (None: off), in both forms the code has read:
    ``DEPOTBENCH_CACHE=FOLDER|off`` now, ``DEPOTBENCH_CACHE_DIR`` and ``on|off`` before 0.5."""
    from depotbench.eval.run import cache

    if hasattr(cache, "cache_enabled"):  # before 0.5: DEPOTBENCH_CACHE is on or off
        os.environ["DEPOTBENCH_CACHE_DIR"] = str(folder)
        os.environ["DEPOTBENCH_CACHE"] = "off" if folder is None else "on"
    else:
        os.environ["DEPOTBENCH_CACHE"] = "off" if folder is None else str(folder.absolute())


def _timed(
    jobs, out: Path, workers: int, cache: bool, dedupe: bool
) -> tuple[float, int, list[dict], dict[str, float]]:
    """(seconds, runs tracked, the rows' deterministic fields, seconds of each phase)."""
    from depotbench.eval.sweep import engine

    _use_cache(out / "cache" if cache else None)
    fields = [f for f in DETERMINISTIC_FIELDS if f not in ("signature", "computed_by")]
    out.mkdir(parents=True)
    log, phases = logging.getLogger(engine.__name__), _Phases()
    level = log.level
    log.addHandler(phases)
    if hasattr(engine, "PHASES"):  # a baseline revision's engine may time none (nor have core.logs)
        from depotbench.core.logs import DETAIL

        log.setLevel(DETAIL)  # this logger's alone: the workers keep the package's level
    try:
        with ResultStore(out / "results.sqlite") as store:
            started = time.perf_counter()
            tracked, _ = run_jobs(jobs, store, workers, progress=True, dedupe=dedupe)
            elapsed = time.perf_counter() - started
            rows = [{k: r[k] for k in fields} for r in store.rows()]
    finally:
        log.removeHandler(phases)
        log.setLevel(level)
    return elapsed, tracked, rows, phases.seconds


def _work(root: Path, sequences: list[tuple[Path, str]], configs: int, detector: str) -> list[SweepJob]:
    """``none`` and the first ``configs`` box_epipolar_flow grid points on each sequence."""
    combos = list(itertools.product(*GRID.values()))[:configs]
    spec = SweepSpec(
        sweep="bench", sequences=["-"], detectors=[detector], strategies=["none", "box_epipolar_flow"]
    )
    jobs = expand(spec, root / "spec.yaml", sequences)
    typed = _typed_settings()
    work = [j for j in jobs if j.job.strategy == "none"]
    for base in (j for j in jobs if j.job.strategy == "box_epipolar_flow"):
        fingerprint = sequence_fingerprint(Sequence.open(base.job.sequence))
        for combo in combos:
            values = (float(v) if typed else repr(float(v)) for v in combo)
            settings = tuple(zip(GRID, values, strict=True))
            tracker = tracker_identity(base.job.tracker)
            key = job_key(fingerprint, tracker, base.job.detector, "box_epipolar_flow", settings)
            job = replace(base.job, settings=settings)
            run = replace(base.run, key=key, settings=settings)
            work.append(SweepJob(key, base.family, job, fingerprint, run))
    return work


def _is_commit(rev: str) -> bool:
    found = subprocess.run(
        ["git", "-C", str(REPO), "rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}"],
        capture_output=True,
        check=False,
    )
    return found.returncode == 0


def _revision_tree(rev: str, root: Path) -> Path:
    """Revision ``rev``'s files under ``root``, laid out so that ``import depotbench`` finds
    them with ``root`` on PYTHONPATH: each subpackage its pyproject maps to a root folder
    becomes a link inside the ``depotbench`` folder, as an install places it."""
    archive = subprocess.run(["git", "-C", str(REPO), "archive", rev], capture_output=True, check=False)
    if archive.returncode:
        raise SystemExit(f"--baseline {rev}: {archive.stderr.decode().strip()}")
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
        tar.extractall(root, filter="data")
    folders = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    for package, folder in folders.items():
        parts = package.split(".")
        if len(parts) == 2:
            (root / "depotbench" / parts[1]).symlink_to(root / folder, target_is_directory=True)
    return root


def _baseline_seconds(rev: str, args: argparse.Namespace, sequences_root: Path) -> float:
    """Seconds revision ``rev``'s code took for the cache + dedupe sweep of the same work on
    the same sequences: this script in a child process, ``depotbench`` imported from the
    revision (its output is shown, indented, when it ends)."""
    with tempfile.TemporaryDirectory(prefix="depotbench-baseline-") as tmp:
        tree = _revision_tree(rev, Path(tmp) / "tree")
        command = [sys.executable, str(Path(__file__).resolve()), "--on-sequences", str(sequences_root)]
        command += [
            "--configs",
            str(args.configs),
            "--workers",
            str(args.workers),
            "--detector",
            args.detector,
        ]
        env = {**os.environ, "PYTHONPATH": str(tree)}
        print(f"baseline: revision {rev}", flush=True)
        child = subprocess.run(command, cwd=tmp, env=env, stdout=subprocess.PIPE, text=True, check=False)
        print("\n".join("  | " + line for line in child.stdout.splitlines()), flush=True)
        found = BASELINE_LINE.search(child.stdout)
        if child.returncode or not found:
            raise SystemExit(f"--baseline {rev}: its sweep failed (exit {child.returncode})")
        return float(found[1])


def _child(args: argparse.Namespace) -> None:
    """--on-sequences: the cache + dedupe sweep alone on sequences already made (the baseline's
    child; the ``depotbench`` it imports is the revision's)."""
    import depotbench

    sequences = [(path, "walking_static") for path in sorted(args.on_sequences.iterdir()) if path.is_dir()]
    print(f"depotbench from {Path(depotbench.__file__).parent.parent}")
    with tempfile.TemporaryDirectory() as tmp:
        work = _work(Path(tmp), sequences, args.configs, args.detector)
        elapsed, tracked, *_ = _timed(work, Path(tmp) / "run", args.workers, True, True)
    print(f"cache + dedupe  {elapsed:8.1f} s ({tracked} tracked, {len(work) - tracked} shared)")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--configs", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip-naive", action="store_true", help="only the cached sweeps")
    parser.add_argument(
        "--detector",
        default="groundtruth",
        help="the boxes: groundtruth (free) or onnx (the shipped YOLOX-nano, ~31 ms a frame)",
    )
    parser.add_argument(
        "--baseline",
        nargs="?",
        const=BEFORE_ISSUE_40,
        metavar="REV",
        help=f"also time revision REV's cache + dedupe sweep (REV: {BEFORE_ISSUE_40}, before issue 40)",
    )
    parser.add_argument("--on-sequences", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.baseline is not None and not _is_commit(args.baseline):
        print(f"sweep.py: --baseline {args.baseline}: not a commit of this repository", file=sys.stderr)
        sys.exit(2)  # before any sequence is generated
    if args.on_sequences is not None:
        _child(args)
        return
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        sequences = _sequences(root, args.frames, args.seeds, args.workers)
        baseline_s = (
            None if args.baseline is None else _baseline_seconds(args.baseline, args, root / "sequences")
        )
        work = _work(root, sequences, args.configs, args.detector)
        print(
            f"{len(sequences)} walking_static sequences x {args.frames} frames; {len(work)} runs "
            f"(none + {args.configs} box_epipolar_flow configurations each), {args.workers} workers, "
            f"{args.detector} boxes"
        )
        results = {}
        modes = [("cache + dedupe", True, True), ("cache", True, False)]
        if not args.skip_naive:
            modes.append(("naive", False, False))
        for label, cache, dedupe in modes:
            folder = root / label.replace(" ", "").replace("+", "_")
            elapsed, tracked, rows, phases = _timed(work, folder, args.workers, cache, dedupe)
            results[label] = (elapsed, rows)
            print(
                f"{label:16s}{elapsed:8.1f} s {len(work) / elapsed * 60:9.1f} runs/min "
                f"({tracked} tracked, {len(work) - tracked} shared)"
            )
            if phases:
                print("  of which " + ", ".join(f"{name} {s:.1f} s" for name, s in phases.items()))
        if baseline_s is not None:
            elapsed = results["cache + dedupe"][0]
            print(
                f"speed-up of cache + dedupe over revision {args.baseline}: "
                f"{baseline_s / elapsed:.2f}x ({baseline_s:.1f} s there, {elapsed:.1f} s here)"
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
