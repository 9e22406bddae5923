"""Keyframes and map points, held in arrays for vectorised projection."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slam.features import FrameFeatures


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
        return np.arange(start, start + n)

    def observe(self, point_id: int, keyframe_id: int, keypoint: int) -> None:
        seen = self.observations.setdefault(point_id, {})
        if keyframe_id not in seen:
            self.n_observations[point_id] += 1
        seen[keyframe_id] = keypoint

    def forget(self, point_id: int, keyframe_id: int) -> None:
        """Drop one observation (an outlier found by bundle adjustment)."""
        keypoint = self.observations.get(point_id, {}).pop(keyframe_id, None)
        if keypoint is not None:
            self.n_observations[point_id] -= 1
            self.keyframes[keyframe_id].point_ids[keypoint] = -1

    def keyframe(self, keyframe_id: int) -> KeyFrame:
        return self.keyframes[keyframe_id]

    def cull(self, current_keyframe_id: int) -> int:
        """Drop points rarely found where predicted, or seen by one keyframe after two more."""
        candidates = np.flatnonzero(self.alive)
        ratio = self.found[candidates] / np.maximum(self.visible[candidates], 1)
        n_obs = self.n_observations[candidates]
        old = current_keyframe_id - self.first_keyframe[candidates] >= 2
        bad = (ratio < 0.25) | (old & (n_obs < 2))
        removed = candidates[bad]
        self.alive[removed] = False
        for point in removed:
            for kf_id, keypoint in self.observations.pop(int(point), {}).items():
                self.keyframes[kf_id].point_ids[keypoint] = -1
        self.n_observations[removed] = 0
        return len(removed)
