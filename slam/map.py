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
        return np.arange(start, start + n)

    def observe(self, point_id: int, keyframe_id: int, keypoint: int) -> None:
        self.observations.setdefault(point_id, {})[keyframe_id] = keypoint

    def keyframe(self, keyframe_id: int) -> KeyFrame:
        return self.keyframes[keyframe_id]

    def cull(self, current_keyframe_id: int) -> int:
        """Drop points rarely found where predicted, or seen by one keyframe after two more."""
        candidates = np.flatnonzero(self.alive)
        ratio = self.found[candidates] / np.maximum(self.visible[candidates], 1)
        n_obs = np.array([len(self.observations.get(int(p), {})) for p in candidates])
        old = current_keyframe_id - self.first_keyframe[candidates] >= 2
        bad = (ratio < 0.25) | (old & (n_obs < 2))
        removed = candidates[bad]
        self.alive[removed] = False
        for point in removed:
            for kf_id, keypoint in self.observations.pop(int(point), {}).items():
                self.keyframes[kf_id].point_ids[keypoint] = -1
        return len(removed)
