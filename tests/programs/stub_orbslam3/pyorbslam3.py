"""A stand-in for the ``pyorbslam3`` wheel with its interface and no SLAM: it tracks nothing
and writes, at shutdown, the monotonic time of each ``track_rgbd`` call to the file named by
``STUB_ORBSLAM3_CALLS``. Tests of how the bench's worker feeds ORB-SLAM3 use it (on the
path before the real wheel), so they need neither the GPL wheel nor a vocabulary."""

from __future__ import annotations

import enum
import json
import os
import time
from types import SimpleNamespace

import numpy as np


class Sensor(enum.Enum):
    RGBD = 2


class State(enum.Enum):
    NOT_INITIALIZED = 1


class Slam:
    def __init__(self, vocabulary: str, settings: str, sensor: Sensor, use_viewer: bool = False) -> None:
        self.calls: list[float] = []

    def track_rgbd(self, rgb: np.ndarray, depth: np.ndarray, timestamp: float) -> SimpleNamespace:
        self.calls.append(time.monotonic())
        return SimpleNamespace(
            state=State.NOT_INITIALIZED, pose_valid=False, pose_wc=None, num_tracked_points=0
        )

    def tracked_map_points(self) -> np.ndarray:
        return np.zeros((0, 3), np.float32)

    def save_keyframe_trajectory_tum(self, path: str) -> None:
        with open(path, "w", encoding="utf-8") as f:
            f.write("")

    def shutdown(self) -> None:
        with open(os.environ["STUB_ORBSLAM3_CALLS"], "w", encoding="utf-8") as f:
            json.dump(self.calls, f)
