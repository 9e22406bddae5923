"""A tracker that exists only for a test of the registry: it "tracks" by reading the
sequence's true camera poses, offset by a fixed ``offset_m`` parameter along x. It is a
module with ``build`` and ``check``, as every tracker the registry names."""

from __future__ import annotations

import time

import numpy as np
from depotbench.core.errors import InputError
from depotbench.eval.trackers.base import TrackerRun
from depotbench.slam.types import TrackingState


class TruthTracker:
    name = "truth"

    def __init__(self, offset_m: float) -> None:
        self.offset_m = offset_m

    def run(self, frames, progress: bool) -> TrackerRun:
        started = time.perf_counter()
        sequence = frames.sequence
        poses = []
        for i in range(len(frames)):
            pose = np.array(sequence.world_from_camera(i), dtype=np.float64)
            pose[0, 3] += self.offset_m * (i % 2)  # every other frame off by offset_m
            poses.append(pose)
        n = len(frames)
        return TrackerRun(
            timestamps_s=np.array([frames.timestamp_s(i) for i in range(n)]),
            states=(TrackingState.OK,) * n,
            poses=tuple(poses),
            track_ms=np.zeros(n),
            keyframes=None,
            total_s=time.perf_counter() - started,
        )


def build(tracker, config, progress: bool, stages=None) -> TruthTracker:
    return TruthTracker(float(dict(tracker.parameters).get("offset_m", 0.0)))


def check(tracker, camera_sequence=None) -> None:
    unknown = set(dict(tracker.parameters)) - {"offset_m"}
    if unknown:
        raise InputError(f"truth takes only offset_m, not {sorted(unknown)[0]}")
