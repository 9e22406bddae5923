"""SLAM time per frame and per stage at 640x480, 1000 ORB features, one core.

Usage: taskset -c 0 python benchmarks/tracking.py [--scenario walking_xyz] [--frames 150]
Generates the scenario (once, into a temporary folder), then tracks it with each
strategy and prints mean and median milliseconds per stage. Tracking time is
measured as ORB-SLAM reports it: extraction + rejection + tracking, local mapping apart.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from eval.harness import camera_of, make_detector  # noqa: E402
from scenes import library  # noqa: E402
from scenes.schema import to_scenario  # noqa: E402
from sim.generate import generate  # noqa: E402
from sim.sequence import Sequence  # noqa: E402
from slam.config import SlamConfig  # noqa: E402
from slam.rejection import STRATEGIES  # noqa: E402
from slam.system import Slam  # noqa: E402
from slam.types import Frame  # noqa: E402

STAGES = ("extract", "reject", "track", "tracking_total", "mapping")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenario", default="walking_xyz")
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a SLAM setting for every strategy, e.g. lk_window_px=11",
    )
    args = parser.parse_args()
    settings = dict(item.split("=", 1) for item in args.set)
    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as tmp:
        scenario = library.get(args.scenario).model_copy(update={"frames": args.frames, "duration_s": None})
        seq = Sequence.open(generate(to_scenario(scenario), Path(tmp) / "seq", progress=False))
        detector = make_detector("groundtruth", seq)
        camera = camera_of(seq)
        frames = [
            Frame(seq.frames[i].timestamp_s, seq.rgb(i), seq.depth_m(i), camera, detector.detect(i))
            for i in range(len(seq))
        ]
    print(
        f"{args.scenario}, {len(frames)} frames, 640x480, 1000 ORB features, "
        f"cv2 threads {cv2.getNumThreads()}, affinity {sorted(os.sched_getaffinity(0))}"
    )
    print(f"{'strategy':18s} " + " ".join(f"{s + ' mean/med ms':>24s}" for s in STAGES))
    for strategy in STRATEGIES:
        slam = Slam(SlamConfig(strategy=strategy).with_settings(settings), camera)
        results = [slam.process(f) for f in frames]
        row = []
        for stage in STAGES:
            values = np.array([r.diagnostics.stage_ms[stage] for r in results])
            row.append(f"{values.mean():11.2f} /{np.median(values):10.2f}")
        print(f"{strategy:18s} " + " ".join(f"{c:>24s}" for c in row))
    print("total per frame = tracking_total + mapping (mapping runs only on keyframes)")


if __name__ == "__main__":
    main()
