"""Keyframes and map points, held in arrays for vectorised projection."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from depotbench.slam.features import FrameFeatures


@dataclass(eq=False)
class KeyFrame:
    id: int
    frame_index: int
    world_from_camera: np.ndarray
    features: FrameFeatures
    usable: np.ndarray
    """Keypoints that passed rejection."""
    point_ids: np.ndarray
    """Map point id per keypoint, -1 where none."""


@dataclass
class Map:
    """Map points as growable arrays; keyframes in insertion order."""

    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    descriptors: np.ndarray = field(default_factory=lambda: np.zeros((0, 32), np.uint8))
    alive: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    first_keyframe: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    visible: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    found: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    n_observations: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    """Keyframes observing each point (kept equal to len(observations[point]))."""
    observation_weight: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    """ORB-SLAM's MapPoint::Observations(): 2 per keyframe whose keypoint has depth, else 1."""
    keyframes: list[KeyFrame] = field(default_factory=list)
    observations: dict[int, dict[int, int]] = field(default_factory=dict)
    """point id -> {keyframe id: keypoint index}."""

    def add_points(self, positions: np.ndarray, descriptors: np.ndarray, keyframe_id: int) -> np.ndarray:
        start = len(self.positions)
        n = len(positions)
        self.positions = np.vstack([self.positions, positions])
        self.descriptors = np.vstack([self.descriptors, descriptors])
        self.alive = np.r_[self.alive, np.ones(n, bool)]
        self.first_keyframe = np.r_[self.first_keyframe, np.full(n, keyframe_id)]
        self.visible = np.r_[self.visible, np.ones(n, int)]
        self.found = np.r_[self.found, np.ones(n, int)]
        self.n_observations = np.r_[self.n_observations, np.zeros(n, int)]
        self.observation_weight = np.r_[self.observation_weight, np.zeros(n, int)]
        return np.arange(start, start + n)

    def _weight(self, keyframe_id: int, keypoint: int) -> int:
        return 2 if self.keyframes[keyframe_id].features.depth_m[keypoint] > 0 else 1

    def observe(self, point_id: int, keyframe_id: int, keypoint: int) -> None:
        seen = self.observations.setdefault(point_id, {})
        if keyframe_id not in seen:
            self.n_observations[point_id] += 1
            self.observation_weight[point_id] += self._weight(keyframe_id, keypoint)
        seen[keyframe_id] = keypoint

    def forget(self, point_id: int, keyframe_id: int) -> None:
        """Drop one observation (an outlier found by bundle adjustment)."""
        keypoint = self.observations.get(point_id, {}).pop(keyframe_id, None)
        if keypoint is not None:
            self.n_observations[point_id] -= 1
            self.observation_weight[point_id] -= self._weight(keyframe_id, keypoint)
            self.keyframes[keyframe_id].point_ids[keypoint] = -1

    def copy(self) -> Map:
        """An independent copy (features are shared: nothing changes them)."""
        arrays = {
            name: getattr(self, name).copy()
            for name in (
                "positions",
                "descriptors",
                "alive",
                "first_keyframe",
                "visible",
                "found",
                "n_observations",
                "observation_weight",
            )
        }
        keyframes = [
            replace(kf, world_from_camera=kf.world_from_camera.copy(), point_ids=kf.point_ids.copy())
            for kf in self.keyframes
        ]
        observations = {point: dict(seen) for point, seen in self.observations.items()}
        return Map(**arrays, keyframes=keyframes, observations=observations)

    def keyframe(self, keyframe_id: int) -> KeyFrame:
        return self.keyframes[keyframe_id]

    def cull(self, current_keyframe_id: int, recent_keyframes: int) -> int:
        """ORB-SLAM's MapPointCulling: while a point is recent (its keyframe is at most
        ``recent_keyframes`` old), drop it when found where predicted in under a quarter of
        the frames that should see it, or when two keyframes later at most one keyframe
        with depth (observation weight <= 3) sees it. Older points are never culled here."""
        age = current_keyframe_id - self.first_keyframe
        candidates = np.flatnonzero(self.alive & (age <= recent_keyframes))
        ratio = self.found[candidates] / np.maximum(self.visible[candidates], 1)
        old = age[candidates] >= 2
        bad = (ratio < 0.25) | (old & (self.observation_weight[candidates] <= 3))
        removed = candidates[bad]
        self.alive[removed] = False
        for point in removed:
            for kf_id, keypoint in self.observations.pop(int(point), {}).items():
                self.keyframes[kf_id].point_ids[keypoint] = -1
        self.n_observations[removed] = 0
        self.observation_weight[removed] = 0
        return len(removed)
