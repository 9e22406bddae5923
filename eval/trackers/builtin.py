"""The built-in ORB-SLAM2-style pipeline behind the tracker interface."""

from __future__ import annotations

import time

import numpy as np
from tqdm import tqdm

from eval.frames import FrameSource
from eval.trackers.base import TrackerRun
from sim.sequence import Sequence
from slam.config import SlamConfig
from slam.system import Slam
from slam.types import Frame, PinholeCamera

STAGES = ("extract", "reject", "track", "tracking_total", "mapping")


def camera_of(sequence: Sequence) -> PinholeCamera:
    k = sequence.intrinsics
    return PinholeCamera(k.fx, k.fy, k.cx, k.cy, k.width, k.height, k.distortion)


def true_moving_labels(
    sequence: Sequence, index: int, keypoints: np.ndarray, moving_ids: set[int]
) -> np.ndarray:
    """True where a keypoint lies on an instance that moves in this frame."""
    instances = sequence.instances(index)
    h, w = instances.shape
    cols = np.clip(np.rint(keypoints[:, 0]).astype(int), 0, w - 1)
    rows = np.clip(np.rint(keypoints[:, 1]).astype(int), 0, h - 1)
    return np.isin(instances[rows, cols], list(moving_ids))


def _charge(result, stage) -> None:
    """Report a cached stage's time as if it had run now (it ran once, when cached)."""
    times = result.diagnostics.stage_ms
    times["extract"] = stage.extract_ms
    if stage.flow is not None:
        times["reject"] += stage.flow_ms
    times["tracking_total"] = times["extract"] + times["reject"] + times["track"]


class BuiltinTracker:
    name = "builtin"

    def __init__(self, config: SlamConfig, stages: list | None = None) -> None:
        """``stages``: per frame, cached features (and flow) from ``eval.stages``."""
        self.config = config
        self.stages = stages

    def run(self, frames: FrameSource, progress: bool) -> TrackerRun:
        sequence = frames.sequence
        started = time.perf_counter()
        slam = Slam(self.config, camera_of(sequence))
        if self.stages is not None and len(self.stages) != len(frames):
            raise ValueError(f"{len(self.stages)} frames of stages for {len(frames)} frames")
        k = sequence.intrinsics
        blank_rgb, blank_depth = (
            np.zeros((k.height, k.width, 3), np.uint8),
            np.zeros((k.height, k.width), np.float32),
        )
        objects = sequence.objects() if sequence.is_generated else None
        results, labels = [], []
        bar = tqdm(
            range(len(frames)),
            desc=f"slam {self.config.strategy}",
            unit="frame",
            disable=None if progress else True,  # None: only on a terminal
            leave=False,
        )
        with bar:  # closed (and its line cleared) before an error is printed
            for i in bar:
                if self.stages is not None:
                    stage = self.stages[i]
                    frame = Frame(
                        frames.timestamp_s(i), blank_rgb, blank_depth, slam.camera, frames.detections(i)
                    )
                    result = slam.process(frame, stage.features, stage.flow)
                    _charge(result, stage)
                    results.append(result)
                    if stage.labels is not None:
                        labels.append(stage.labels)
                    continue
                rgb, depth_raw = frames.images(i)
                depth_m = depth_raw.astype(np.float32) / np.float32(sequence.intrinsics.depth_scale)
                frame = Frame(frames.timestamp_s(i), rgb, depth_m, slam.camera, frames.detections(i))
                result = slam.process(frame)
                results.append(result)
                if objects is not None:
                    moving = {o.instance_id for o in objects[i] if o.moving}
                    labels.append(true_moving_labels(sequence, i, result.diagnostics.keypoints_px, moving))
        stage_ms = {s: np.array([r.diagnostics.stage_ms[s] for r in results]) for s in STAGES}
        return TrackerRun(
            timestamps_s=np.array([r.timestamp_s for r in results]),
            states=tuple(r.state for r in results),
            poses=tuple(r.world_from_camera for r in results),
            track_ms=stage_ms["tracking_total"],
            keyframes=len(slam.map.keyframes),
            total_s=time.perf_counter() - started,
            results=results,
            labels=labels or None,
            stage_ms=stage_ms,
        )
