"""Tracking time per frame and per stage, the built-in pipeline beside ORB-SLAM3.

Usage: python benchmarks/tracking.py [--scenario walking_xyz] [--frames 150] [--seed 11 ...]
       [--strategy none ...] [--kernels numpy|numba|both] [--set NAME=VALUE ...]
       [--vocabulary FILE] [--orbslam3-pace P ...] [--no-orbslam3]

Generates the scenario once per seed (into a temporary folder), then, on that sequence in
this run: the built-in pipeline with each strategy pinned to one core (tracking as ORB-SLAM
reports it: extraction + rejection + tracking; local mapping runs synchronously and is
reported apart), and ORB-SLAM3 (if the orbslam3 extra is installed) with its local-mapping
thread on the other core, as it is built to run: its time is that of ``track_rgbd``, and its
tracked frames are printed beside it. ORB-SLAM3 is fed at the camera's rate (``pace`` 1), as
its own ``rgbd_tum`` example feeds a sequence and times ``TrackRGBD``: fed back to back
(``--orbslam3-pace 0``), its mapping thread competes with tracking for the cores. Several
paces run one after the other on the same sequence. Mean and median milliseconds per frame;
per seed and over the seeds, each strategy's median over ORB-SLAM3's (issue 40's speed
criterion), for each pace.

``--kernels both`` tracks each strategy on the NumPy reference path and on the compiled
kernels (``DEPOTBENCH_KERNELS``, ``depotbench.slam.kernels``) in the order numpy, numba,
numba, numpy, so that a machine whose load drifts charges both alike; each path's figures
are over its two runs' frames, and a ratio row divides NumPy's median by Numba's. It first
measures what the kernels cost a process before its first frame: compiling them into an
empty cache, and loading them from that cache, each in a fresh interpreter. Every timed run
starts with the kernels loaded (``kernels.warm_up``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from depotbench.core.errors import InputError  # noqa: E402
from depotbench.detectors.config import DetectorConfig  # noqa: E402
from depotbench.eval.run.detections import detect_sequence  # noqa: E402
from depotbench.eval.trackers.builtin import STAGES, BuiltinTracker  # noqa: E402
from depotbench.eval.trackers.frames import FrameSource  # noqa: E402
from depotbench.eval.trackers.orbslam3 import PACE, pace_of  # noqa: E402
from depotbench.eval.trackers.registry import parameter_text, tracker_parameters  # noqa: E402
from depotbench.scenes import library  # noqa: E402
from depotbench.scenes.schema import to_scenario  # noqa: E402
from depotbench.sim.generate import generate  # noqa: E402
from depotbench.sim.sequence import Sequence  # noqa: E402
from depotbench.slam import kernels  # noqa: E402
from depotbench.slam.config import ConfigError, SlamConfig, parse_settings  # noqa: E402
from depotbench.slam.kernels import Kernels  # noqa: E402
from depotbench.slam.rejection import STRATEGIES  # noqa: E402
from depotbench.slam.types import TrackingState  # noqa: E402

TRACKED = (TrackingState.OK, TrackingState.RELOCALIZED)
"""States of a tracked frame: ORB-SLAM3's tracked count is printed, since a lost run looks fast."""
ORDER = (Kernels.NUMPY, Kernels.NUMBA, Kernels.NUMBA, Kernels.NUMPY)
"""--kernels both: each path twice, mirrored, so that a linear drift in load cancels."""

_WARM_UP = (
    "import time; started = time.perf_counter(); import numba; imported = time.perf_counter()\n"
    "from depotbench.slam import kernels\n"
    "print(imported - started, kernels.warm_up())\n"
)


def _cell(values: np.ndarray) -> str:
    return f"{values.mean():11.2f} /{np.median(values):10.2f}"


def _compile_cost() -> str:
    """Numba's import, then all kernels compiled into an empty cache, then loaded from it: each
    in a fresh interpreter, as a sweep's worker process meets them."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        seconds = []
        for _ in ("compile", "load"):
            result = subprocess.run(
                [sys.executable, "-c", _WARM_UP], env=env, capture_output=True, text=True, check=True
            )
            seconds.append([float(x) for x in result.stdout.split()])
    (import_s, compile_s), (_, load_s) = seconds
    return (
        f"kernels before the first frame: import numba {import_s:.2f} s, "
        f"compile all {compile_s:.2f} s (empty cache), load all {load_s:.2f} s (from the cache)"
    )


def _run(frames: FrameSource, config: SlamConfig, path: Kernels | None) -> dict[str, np.ndarray]:
    if path is None:
        return BuiltinTracker(config).run(frames, False).stage_ms
    with kernels.using(path):
        return BuiltinTracker(config).run(frames, False).stage_ms


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenario", default="walking_xyz")
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--seed", type=int, nargs="+", help="scenario seeds (default: the library's)")
    parser.add_argument(
        "--strategy", action="append", choices=STRATEGIES, help="a built-in strategy (default: every one)"
    )
    parser.add_argument(
        "--kernels",
        choices=("numpy", "numba", "both"),
        help="the built-in's hot paths: NumPy, compiled, or both side by side (default: DEPOTBENCH_KERNELS)",
    )
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a SLAM setting")
    parser.add_argument("--vocabulary", type=Path, help="ORB-SLAM3's vocabulary (default: the bench's)")
    parser.add_argument(
        "--orbslam3-pace",
        type=float,
        nargs="+",
        default=[1.0],
        metavar="P",
        help="how ORB-SLAM3 is fed: P x the frames' gaps (1: the camera's rate, 0: back to back); "
        "several run one after the other (default: 1)",
    )
    parser.add_argument("--no-orbslam3", action="store_true", help="the built-in pipeline only")
    args = parser.parse_args()
    try:
        settings = parse_settings(args.set)
    except ConfigError as exc:
        parser.error(f"--set: {exc}")
    for pace in args.orbslam3_pace:
        try:  # checked as the tracker checks its pace parameter
            pace_of(((PACE, parameter_text(pace)),))
        except InputError as exc:
            parser.error(f"--orbslam3-pace: {exc}")
    paths: tuple[Kernels | None, ...] = (None,)
    if args.kernels == "both":
        paths = ORDER
    elif args.kernels:
        paths = (Kernels(args.kernels),)
    strategies = args.strategy or list(STRATEGIES)
    cv2.setNumThreads(1)
    if Kernels.NUMBA in paths or (paths == (None,) and kernels.compiled()):
        if args.kernels == "both":
            print(_compile_cost())
        kernels.warm_up()
    every_core = os.sched_getaffinity(0)
    ratios: dict[str, list[float]] = {s: [] for s in strategies}
    to_orbslam3: dict[tuple[str, float], list[float]] = {}
    for seed in args.seed or [None]:
        with tempfile.TemporaryDirectory() as tmp:
            update = {"frames": args.frames, "duration_s": None}
            if seed is not None:
                update["seed"] = seed
            scenario = library.get(args.scenario).model_copy(update=update)
            seq = Sequence.open(generate(to_scenario(scenario), Path(tmp) / "seq", progress=False))
            frames = FrameSource(seq, detect_sequence(seq, DetectorConfig()).per_frame)
            print(
                f"{args.scenario} (seed {scenario.seed}), {len(seq)} frames, 640x480, 1000 ORB features; "
                f"built-in on core {min(every_core)}, cv2 threads {cv2.getNumThreads()}"
            )
            print(f"{'tracker / strategy':32s} " + " ".join(f"{s + ' mean/med ms':>24s}" for s in STAGES))
            os.sched_setaffinity(0, {min(every_core)})
            totals: dict[str, float] = {}
            for strategy in strategies:
                config = SlamConfig(strategy=strategy).with_settings(settings)
                runs: dict[Kernels | None, list[dict[str, np.ndarray]]] = {}
                for path in paths:
                    runs.setdefault(path, []).append(_run(frames, config, path))
                medians = {}
                for path, stage_runs in runs.items():
                    stages = {s: np.concatenate([r[s] for r in stage_runs]) for s in STAGES}
                    medians[path] = {s: float(np.median(v)) for s, v in stages.items()}
                    label = f"builtin {strategy}" + (f" [{path.value}]" if path else "")
                    print(f"{label:32s} " + " ".join(f"{_cell(stages[s]):>24s}" for s in STAGES))
                totals[strategy] = medians[paths[0]]["tracking_total"]
                if len(runs) == 2:
                    ratio = {s: medians[Kernels.NUMPY][s] / medians[Kernels.NUMBA][s] for s in STAGES}
                    ratios[strategy].append(ratio["tracking_total"])
                    print(
                        f"{'  numpy / numba, medians':32s} " + " ".join(f"{ratio[s]:>23.2f}x" for s in STAGES)
                    )
            os.sched_setaffinity(0, every_core)
            for pace in () if args.no_orbslam3 else args.orbslam3_pace:
                orbslam3_ms = _orbslam3(args, seq, pace)
                if orbslam3_ms is None:
                    break
                for strategy, total in totals.items():
                    to_orbslam3.setdefault((strategy, pace), []).append(total / orbslam3_ms)
                print(
                    f"{f'  built-in / orbslam3 pace {pace:g}':32s} "
                    + " ".join(f"{s} {to_orbslam3[s, pace][-1]:.2f}x" for s in strategies)
                )
    if args.kernels == "both":
        print("numpy / numba, median tracking_total per frame, by seed:")
        for strategy, values in ratios.items():
            print(f"  {strategy:20s} " + " ".join(f"{v:.2f}x" for v in values))
    if to_orbslam3:
        print("built-in / orbslam3, median tracking_total per frame, by seed; median over seeds:")
        for (strategy, pace), values in to_orbslam3.items():
            line = " ".join(f"{v:.2f}x" for v in values)
            print(f"  {strategy:20s} pace {pace:<4g} {line}; {float(np.median(values)):.2f}x")
    print("built-in: tracking_total = extract + reject + track; mapping (synchronous) apart, per frame")
    print("orbslam3: track_rgbd per frame (extraction and tracking; mapping in its own thread)")


def _orbslam3(args: argparse.Namespace, seq: Sequence, pace: float) -> float | None:
    """ORB-SLAM3's median ms per frame, fed at ``pace`` (None where it is not installed). Its
    tracked frames are printed beside it: a run that got lost tracks nothing and looks fast."""
    from depotbench.eval.trackers.orbslam3 import Orbslam3Tracker, available

    if not available():
        print("orbslam3: not installed (pip install 'depotbench[orbslam3]')")
        return None
    from depotbench.eval.trackers.vocabulary import default_vocabulary

    vocabulary = args.vocabulary or default_vocabulary()
    parameters = tracker_parameters("orbslam3", {PACE: str(pace)})
    run = Orbslam3Tracker(vocabulary, parameters=parameters).run(FrameSource(seq), progress=False)
    tracked = sum(state in TRACKED for state in run.states)
    print(
        f"{f'orbslam3 none pace {pace:g}':32s} {'':>24s} {'':>24s} {'':>24s} {_cell(run.track_ms):>24s}"
        f"   tracked {tracked}/{len(run.states)} frames"
    )
    return float(np.median(run.track_ms))


if __name__ == "__main__":
    main()
