"""Run a sequence through a detector and SLAM, and leave machine-readable results.

``run_sequence`` is a pure function of (sequence, detector, strategy, settings):
it writes ``trajectory.txt`` (TUM), ``diagnostics.npz`` (per keypoint and per
stage) and ``metrics.json`` into a temporary folder renamed into place.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from detectors.groundtruth import GroundTruthDetector
from eval.comparison import ComparisonOptions, compare
from eval.trajectory import Trajectory, write_tum
from sim.errors import InputError
from sim.files import dumps_json
from sim.output import OutputKind, StagedOutput
from sim.sequence import Sequence
from slam.config import ConfigError, SlamConfig
from slam.rejection import STRATEGIES
from slam.system import Slam
from slam.types import REJECTION_CODES, Frame, FrameResult, PinholeCamera, Rejection, TrackingState

DETECTORS = ("groundtruth", "none")


def make_detector(name: str, sequence: Sequence):
    if name == "groundtruth":
        return GroundTruthDetector(sequence)
    if name == "none":
        return None
    raise InputError(f"unknown detector {name!r}; choose one of {', '.join(DETECTORS)}")


def camera_of(sequence: Sequence) -> PinholeCamera:
    k = sequence.intrinsics
    return PinholeCamera(k.fx, k.fy, k.cx, k.cy, k.width, k.height)


def true_moving_labels(
    sequence: Sequence, index: int, keypoints: np.ndarray, moving_ids: set[int]
) -> np.ndarray:
    """True where a keypoint lies on an instance that moves in this frame."""
    instances = sequence.instances(index)
    h, w = instances.shape
    cols = np.clip(np.rint(keypoints[:, 0]).astype(int), 0, w - 1)
    rows = np.clip(np.rint(keypoints[:, 1]).astype(int), 0, h - 1)
    return np.isin(instances[rows, cols], list(moving_ids))


def estimated_trajectory(results: list[FrameResult]) -> Trajectory | None:
    """The poses of the tracked frames (lost frames have none), or None if no frame was tracked."""
    tracked = [r for r in results if r.world_from_camera is not None]
    if not tracked:
        return None
    return Trajectory.from_poses(
        np.array([r.timestamp_s for r in tracked]), np.array([r.world_from_camera for r in tracked])
    )


def run_sequence(
    sequence_dir: Path,
    out_dir: Path,
    strategy: str,
    detector: str = "groundtruth",
    settings: dict[str, str] | None = None,
    progress: bool = True,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Track a sequence; return (and write) its metrics."""
    if strategy not in STRATEGIES:
        raise InputError(f"unknown strategy {strategy!r}; choose one of {', '.join(STRATEGIES)}")
    try:
        config = SlamConfig(strategy=strategy).with_settings(settings or {})
    except ConfigError as exc:
        raise InputError(f"--set: {exc}") from None
    sequence = Sequence.open(sequence_dir)
    det = make_detector(detector, sequence)
    # The output is checked, locked and staged first: a place that must not or cannot be
    # written is refused before the run, not after it.
    try:
        slam = Slam(config, camera_of(sequence))
    except ConfigError as exc:
        raise InputError(f"--set: {exc}") from None
    with StagedOutput(out_dir, OutputKind.RUN, overwrite=overwrite, inputs=(Path(sequence_dir),)) as output:
        objects = sequence.objects() if sequence.is_generated else None
        results: list[FrameResult] = []
        labels: list[np.ndarray] = []
        frames = tqdm(
            range(len(sequence)),
            desc=f"slam {strategy}",
            unit="frame",
            disable=None if progress else True,  # None: only on a terminal
            leave=False,
        )
        with frames:  # closed (and its line cleared) before an error is printed
            for i in frames:
                frame = Frame(
                    sequence.frames[i].timestamp_s,
                    sequence.rgb(i),
                    sequence.depth_m(i),
                    slam.camera,
                    det.detect(i) if det else (),
                )
                result = slam.process(frame)
                results.append(result)
                if objects is not None:
                    moving = {o.instance_id for o in objects[i] if o.moving}
                    labels.append(true_moving_labels(sequence, i, result.diagnostics.keypoints_px, moving))
        metrics = _metrics(sequence, slam, results, labels, config, detector)
        estimate = estimated_trajectory(results)
        if estimate is not None:
            write_tum(
                output.path / "trajectory.txt",
                estimate,
                header=f"depotbench slam, strategy {strategy}, detector {detector}",
            )
        _write_diagnostics(output.path / "diagnostics.npz", results, labels)
        (output.path / "metrics.json").write_text(dumps_json(metrics) + "\n", encoding="utf-8")
        output.commit()
    return metrics


def _metrics(
    sequence: Sequence,
    slam: Slam,
    results: list[FrameResult],
    labels: list[np.ndarray],
    config: SlamConfig,
    detector: str,
) -> dict[str, Any]:
    states = [r.state for r in results]
    stage = {}
    for key in ("extract", "reject", "track", "tracking_total", "mapping"):
        values = np.array([r.diagnostics.stage_ms[key] for r in results])
        stage[key] = {"mean_ms": float(values.mean()), "median_ms": float(np.median(values))}
    metrics: dict[str, Any] = {
        "sequence": str(sequence.root),
        "strategy": config.strategy,
        "detector": detector,
        "config": {"tracking": asdict(config.tracking), "rejection": asdict(config.rejection)},
        "frames": len(results),
        "tracked_frames": sum(s in (TrackingState.OK, TrackingState.RELOCALIZED) for s in states),
        "lost_frames": sum(s == TrackingState.LOST for s in states),
        "relocalized_frames": sum(s == TrackingState.RELOCALIZED for s in states),
        "keyframes": len(slam.map.keyframes),
        "stage_time": stage,
    }
    estimate = estimated_trajectory(results)
    if sequence.groundtruth is not None and estimate is not None and len(estimate) >= 3:
        gt = sequence.groundtruth
        reference = Trajectory.from_quaternions(gt.timestamps_s, gt.positions_m, gt.quats_xyzw, "groundtruth")
        comparison = compare(reference, estimate, ComparisonOptions()).to_dict()
        for key in ("ate_m", "rpe_translation_m", "rpe_rotation_deg"):
            metrics[key] = comparison[key]
    if labels:
        kept = REJECTION_CODES[Rejection.KEPT]
        rejected = np.concatenate([r.diagnostics.rejection != kept for r in results])
        moving = np.concatenate(labels)
        true_positive = int((rejected & moving).sum())
        metrics["rejection"] = {
            "keypoints": int(len(moving)),
            "moving_keypoints": int(moving.sum()),
            "rejected_keypoints": int(rejected.sum()),
            "precision": true_positive / int(rejected.sum()) if rejected.any() else None,
            "recall": true_positive / int(moving.sum()) if moving.any() else None,
            "moving_inliers": int(
                sum((r.diagnostics.inlier & lab).sum() for r, lab in zip(results, labels, strict=True))
            ),
        }
    return metrics


def _write_diagnostics(path: Path, results: list[FrameResult], labels: list[np.ndarray]) -> None:
    counts = np.array([len(r.diagnostics.keypoints_px) for r in results])
    classes = sorted({c for r in results for c in r.diagnostics.keypoint_classes})
    class_index = {c: i for i, c in enumerate(classes)}
    stages = sorted(results[0].diagnostics.stage_ms) if results else []
    arrays = {
        "timestamps_s": np.array([r.timestamp_s for r in results]),
        "state": np.array([r.state.value for r in results]),
        "keyframe": np.array([r.diagnostics.keyframe for r in results]),
        "keypoint_counts": counts,
        "keypoints_px": np.concatenate([r.diagnostics.keypoints_px for r in results])
        if results
        else np.zeros((0, 2)),
        "keypoint_class": np.concatenate(
            [[class_index[c] for c in r.diagnostics.keypoint_classes] for r in results]
        ).astype(np.int16)
        if results
        else np.zeros(0),
        "class_names": np.array(classes),
        "rejection": np.concatenate([r.diagnostics.rejection for r in results]) if results else np.zeros(0),
        "rejection_names": np.array([r.value for r in Rejection]),
        "inlier": np.concatenate([r.diagnostics.inlier for r in results]) if results else np.zeros(0, bool),
        "stage_names": np.array(stages),
        "stage_ms": np.array([[r.diagnostics.stage_ms[s] for s in stages] for r in results]),
    }
    if labels:
        arrays["moving"] = np.concatenate(labels)
    np.savez_compressed(path, **arrays)
