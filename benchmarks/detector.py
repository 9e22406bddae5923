"""Detector latency on one core, frames per second with SLAM, and rho with each detector.

Usage: python benchmarks/detector.py [SEQ ...] [--frames 100] [--rho]

Without sequences, a walking_static sequence is generated. Prints, per sequence:
the ONNX detector's latency per frame (one intra-op thread, pinned to one core;
preprocessing, inference and NMS), the ground-truth detector's, and the total
frames per second of detection + built-in SLAM (box_epipolar_flow) on one core.
With ``--rho``, every strategy runs with true boxes, YOLOX-nano boxes and faulted
true boxes (miss 0.3, latency 2 frames): ATE, rho over ``none``, rejection
precision and recall.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from depotbench.detectors.config import DetectorConfig, parse_detector  # noqa: E402
from depotbench.eval.metrics.accuracy import improvement_rate  # noqa: E402
from depotbench.eval.run.detections import build_detector, detect_sequence  # noqa: E402
from depotbench.eval.run.harness import run_sequence  # noqa: E402
from depotbench.eval.trackers.builtin import BuiltinTracker  # noqa: E402
from depotbench.eval.trackers.frames import FrameSource  # noqa: E402
from depotbench.sim.sequence import Sequence  # noqa: E402
from depotbench.slam.config import SlamConfig  # noqa: E402
from depotbench.slam.rejection import STRATEGIES  # noqa: E402

DETECTORS = {
    "true boxes": DetectorConfig(),
    "yolox-nano": parse_detector("onnx"),
    "true, miss 0.3 + latency 2": parse_detector("groundtruth", faults={"miss": "0.3", "latency": "2"}),
}


def _generate(tmp: Path, frames: int) -> Path:
    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.generate import generate

    scenario = library.get("walking_static").model_copy(update={"frames": frames, "duration_s": None})
    return generate(to_scenario(scenario), tmp / "walking_static", progress=False)


def _latency(sequence: Sequence, config: DetectorConfig) -> np.ndarray:
    detector = build_detector(config, sequence)
    from depotbench.detectors.base import DetectorFrame

    times = []
    for i in range(len(sequence)):
        frame = DetectorFrame(i, sequence.frames[i].timestamp_s, sequence.rgb(i))
        started = time.perf_counter()
        detector.detect(frame)
        times.append((time.perf_counter() - started) * 1e3)
    return np.array(times)


def _throughput(sequence: Sequence, config: DetectorConfig) -> float:
    """Frames per second of detection + built-in SLAM over the sequence (no cache)."""
    started = time.perf_counter()
    detections = detect_sequence(sequence, config, cache=None)
    frames = FrameSource(sequence, detections.per_frame)
    BuiltinTracker(SlamConfig(strategy="box_epipolar_flow")).run(frames, progress=False)
    return len(sequence) / (time.perf_counter() - started)


def _rho_table(roots: list[Path], out: Path) -> None:
    from depotbench.eval.run.cache import StageCache

    cache = StageCache(out / "cache")
    print(
        f"\n{'sequence':28s}{'detector':30s}{'strategy':20s}"
        f"{'ATE mm':>9s}{'rho %':>8s}{'prec':>7s}{'recall':>7s}"
    )
    for root in roots:
        none = run_sequence(
            root, out / root.name / "none", "none", progress=False, overwrite=True, cache=cache
        )
        base = none["ate_m"]["rmse"]
        print(f"{root.name:28s}{'-':30s}{'none':20s}{base * 1e3:9.1f}{0.0:8.1f}")
        for label, config in DETECTORS.items():
            for strategy in STRATEGIES[1:]:
                target = out / root.name / f"{label}-{strategy}".replace(" ", "_").replace(",", "")
                m = run_sequence(root, target, strategy, config, progress=False, overwrite=True, cache=cache)
                ate = m["ate_m"]["rmse"]
                rej = m["rejection"]
                prec = "-" if rej["precision"] is None else f"{rej['precision']:.3f}"
                print(
                    f"{'':28s}{label:30s}{strategy:20s}{ate * 1e3:9.1f}"
                    f"{improvement_rate(base, ate):8.1f}{prec:>7s}{rej['recall']:7.3f}"
                )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("sequences", nargs="*", type=Path)
    parser.add_argument("--frames", type=int, default=100, help="frames of the generated sequence")
    parser.add_argument("--rho", action="store_true", help="also run every strategy with each detector")
    parser.add_argument("-o", "--output", type=Path, help="keep runs here (default: temporary)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    every_core = os.sched_getaffinity(0)
    with tempfile.TemporaryDirectory() as tmp:
        roots = args.sequences or [_generate(Path(tmp), args.frames)]
        print(f"one core ({min(every_core)}), onnxruntime 1 thread, cv2 1 thread")
        print(
            f"{'sequence':28s}{'onnx ms mean/median/p95':>26s}{'gt ms':>8s}"
            f"{'fps onnx+slam':>15s}{'fps gt+slam':>13s}"
        )
        os.sched_setaffinity(0, {min(every_core)})
        try:
            for root in roots:
                sequence = Sequence.open(root)
                onnx = _latency(sequence, DETECTORS["yolox-nano"])
                gt = _latency(sequence, DetectorConfig())
                fps_onnx = _throughput(sequence, DETECTORS["yolox-nano"])
                fps_gt = _throughput(sequence, DetectorConfig())
                print(
                    f"{root.name:28s}{onnx.mean():10.1f} /{np.median(onnx):6.1f}"
                    f" /{np.percentile(onnx, 95):6.1f}"
                    f"{gt.mean():8.2f}{fps_onnx:15.1f}{fps_gt:13.1f}"
                )
        finally:
            os.sched_setaffinity(0, every_core)
        if args.rho:
            _rho_table(roots, args.output or Path(tmp) / "runs")


if __name__ == "__main__":
    main()
