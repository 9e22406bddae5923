"""Tracking time per frame and per stage, the built-in pipeline beside ORB-SLAM3.

Usage: python benchmarks/tracking.py [--scenario walking_xyz] [--frames 150] [--seed 11]
       [--set NAME=VALUE ...] [--vocabulary FILE]

Generates the scenario once (into a temporary folder), then, on that sequence in this
run: the built-in pipeline with each strategy pinned to one core (tracking as ORB-SLAM
reports it: extraction + rejection + tracking; local mapping runs synchronously and
is reported apart), and ORB-SLAM3 (if the orbslam3 extra is installed) with its
local-mapping thread on the other core, as it is built to run: its time is that of
``track_rgbd``. Mean and median milliseconds per frame.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from depotbench.detectors.config import DetectorConfig  # noqa: E402
from depotbench.eval.run.detections import detect_sequence  # noqa: E402
from depotbench.eval.trackers.builtin import STAGES, BuiltinTracker  # noqa: E402
from depotbench.eval.trackers.frames import FrameSource  # noqa: E402
from depotbench.scenes import library  # noqa: E402
from depotbench.scenes.schema import to_scenario  # noqa: E402
from depotbench.sim.generate import generate  # noqa: E402
from depotbench.sim.sequence import Sequence  # noqa: E402
from depotbench.slam.config import ConfigError, SlamConfig, parse_settings  # noqa: E402
from depotbench.slam.rejection import STRATEGIES  # noqa: E402


def _cell(values: np.ndarray) -> str:
    return f"{values.mean():11.2f} /{np.median(values):10.2f}"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenario", default="walking_xyz")
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--seed", type=int, help="scenario seed (default: the library's)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a SLAM setting")
    parser.add_argument("--vocabulary", type=Path, help="ORB-SLAM3's vocabulary (default: the bench's)")
    args = parser.parse_args()
    try:
        settings = parse_settings(args.set)
    except ConfigError as exc:
        parser.error(f"--set: {exc}")
    cv2.setNumThreads(1)
    every_core = os.sched_getaffinity(0)
    with tempfile.TemporaryDirectory() as tmp:
        update = {"frames": args.frames, "duration_s": None}
        if args.seed is not None:
            update["seed"] = args.seed
        scenario = library.get(args.scenario).model_copy(update=update)
        seq = Sequence.open(generate(to_scenario(scenario), Path(tmp) / "seq", progress=False))
        frames = FrameSource(seq, detect_sequence(seq, DetectorConfig()).per_frame)
        print(
            f"{args.scenario} (seed {scenario.seed}), {len(seq)} frames, 640x480, 1000 ORB features; "
            f"built-in on core {min(every_core)}, cv2 threads {cv2.getNumThreads()}"
        )
        print(f"{'tracker / strategy':24s} " + " ".join(f"{s + ' mean/med ms':>24s}" for s in STAGES))
        os.sched_setaffinity(0, {min(every_core)})
        for strategy in STRATEGIES:
            run = BuiltinTracker(SlamConfig(strategy=strategy).with_settings(settings)).run(frames, False)
            print(
                f"{'builtin ' + strategy:24s} " + " ".join(f"{_cell(run.stage_ms[s]):>24s}" for s in STAGES)
            )
        os.sched_setaffinity(0, every_core)
        from depotbench.eval.trackers.orbslam3 import Orbslam3Tracker, available

        if not available():
            print("orbslam3: not installed (pip install 'depotbench[orbslam3]')")
            return
        from depotbench.eval.trackers.vocabulary import default_vocabulary

        vocabulary = args.vocabulary or default_vocabulary()
        run = Orbslam3Tracker(vocabulary).run(FrameSource(seq), progress=False)
        print(f"{'orbslam3 none':24s} {'':>24s} {'':>24s} {'':>24s} {_cell(run.track_ms):>24s}")
    print("built-in: tracking_total = extract + reject + track; mapping (synchronous) apart, per frame")
    print("orbslam3: track_rgbd per frame (extraction and tracking; mapping in its own thread)")


if __name__ == "__main__":
    main()
