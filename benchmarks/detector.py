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
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

# depotbench first: numpy then runs the bench's code for the CPU (core/numerics.py)
import depotbench  # isort: skip  # noqa: E402, F401
import cv2  # noqa: E402
import numpy as np  # noqa: E402
from depotbench.core.text_table import Column, cell, render  # noqa: E402
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
    rows = []
    for root in roots:
        none = run_sequence(
            root, out / root.name / "none", "none", progress=False, overwrite=True, cache=cache
        )
        base = none["ate_m"]["rmse"]
        rows.append([root.name, "-", "none", f"{base * 1e3:.1f}", "0.0", "-", "-"])
        for label, config in DETECTORS.items():
            for strategy in STRATEGIES[1:]:
                target = out / root.name / f"{label}-{strategy}".replace(" ", "_").replace(",", "")
                m = run_sequence(root, target, strategy, config, progress=False, overwrite=True, cache=cache)
                ate, rej = m["ate_m"]["rmse"], m["rejection"]
                rows.append(
                    [
                        "",
                        label,
                        strategy,
                        f"{ate * 1e3:.1f}",
                        f"{improvement_rate(base, ate):.1f}",
                        cell(rej["precision"], ".3f"),
                        cell(rej["recall"], ".3f"),
                    ]
                )
                print(f"  ran {root.name} {label} {strategy}", file=sys.stderr, flush=True)
    words = [Column(h, "left") for h in ("sequence", "detector", "strategy")]
    print()
    print(render([*words, *(Column(h) for h in ("ATE mm", "rho %", "prec", "recall"))], rows))


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
        rows = []
        os.sched_setaffinity(0, {min(every_core)})
        try:
            for root in roots:
                sequence = Sequence.open(root)
                onnx = _latency(sequence, DETECTORS["yolox-nano"])
                gt = _latency(sequence, DetectorConfig())
                fps_onnx = _throughput(sequence, DETECTORS["yolox-nano"])
                fps_gt = _throughput(sequence, DetectorConfig())
                onnx_ms = f"{onnx.mean():.1f} / {np.median(onnx):.1f} / {np.percentile(onnx, 95):.1f}"
                rows.append([root.name, onnx_ms, f"{gt.mean():.2f}", f"{fps_onnx:.1f}", f"{fps_gt:.1f}"])
        finally:
            os.sched_setaffinity(0, every_core)
        headers = ("onnx ms mean/median/p95", "gt ms", "fps onnx+slam", "fps gt+slam")
        print(render([Column("sequence", "left"), *(Column(h) for h in headers)], rows))
        if args.rho:
            _rho_table(roots, args.output or Path(tmp) / "runs")


if __name__ == "__main__":
    main()
