"""ORB features spread over the image, with their depth: the cacheable front-end stage.

ORB-SLAM spreads features with a quadtree per pyramid level; here keypoints from
OpenCV's ORB are bucketed into grid cells and taken round-robin by response, so
no textured corner of the image takes all the budget.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from slam.config import TrackingConfig


@dataclass(frozen=True, eq=False)
class FrameFeatures:
    grey: np.ndarray
    keypoints_px: np.ndarray
    """(N, 2) float32 pixel positions at full resolution."""
    octaves: np.ndarray
    descriptors: np.ndarray
    """(N, 32) uint8 ORB descriptors."""
    depth_m: np.ndarray
    """(N,) depth at each keypoint, 0 where missing or out of range."""
    angles_deg: np.ndarray
    """(N,) ORB orientation of each keypoint."""

    def __len__(self) -> int:
        return len(self.keypoints_px)


class FeatureExtractor:
    def __init__(self, config: TrackingConfig) -> None:
        self.config = config
        self._orb = self._make_orb(config.fast_threshold)
        self._orb_low = self._make_orb(config.fast_threshold_min)

    def _make_orb(self, fast_threshold: int) -> cv2.ORB:
        c = self.config
        return cv2.ORB_create(
            nfeatures=2 * c.n_features,
            scaleFactor=c.scale_factor,
            nlevels=c.n_levels,
            edgeThreshold=19,
            patchSize=31,
            fastThreshold=fast_threshold,
        )

    def extract(self, rgb: np.ndarray, depth_m: np.ndarray) -> FrameFeatures:
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
        keypoints = self._orb.detect(grey, None)
        if len(keypoints) < self.config.n_features:
            keypoints = self._orb_low.detect(grey, None)
        keypoints = self._spread(keypoints, grey.shape)
        keypoints, descriptors = self._orb.compute(grey, keypoints)
        if descriptors is None or not keypoints:
            return FrameFeatures(
                grey,
                np.zeros((0, 2), np.float32),
                np.zeros(0, int),
                np.zeros((0, 32), np.uint8),
                np.zeros(0),
                np.zeros(0),
            )
        pts = np.array([k.pt for k in keypoints], dtype=np.float32)
        octaves = np.array([k.octave for k in keypoints], dtype=int)
        h, w = depth_m.shape
        cols = np.clip(np.rint(pts[:, 0]).astype(int), 0, w - 1)
        rows = np.clip(np.rint(pts[:, 1]).astype(int), 0, h - 1)
        depth = depth_m[rows, cols].astype(np.float64)
        depth[(depth < self.config.min_depth_m) | (depth > self.config.max_depth_m)] = 0.0
        angles = np.array([k.angle for k in keypoints], dtype=np.float64)
        return FrameFeatures(grey, pts, octaves, descriptors, depth, angles)

    def _spread(self, keypoints: list, shape: tuple[int, int]) -> list:
        if len(keypoints) <= self.config.n_features:
            return list(keypoints)
        cell = self.config.grid_cell_px
        pts = np.array([k.pt for k in keypoints])
        response = np.array([k.response for k in keypoints])
        cells = (pts[:, 1] // cell).astype(int) * (shape[1] // cell + 1) + (pts[:, 0] // cell).astype(int)
        order = np.lexsort((-response, cells))
        rank = np.empty(len(keypoints), dtype=int)
        sorted_cells = cells[order]
        starts = np.r_[0, np.flatnonzero(np.diff(sorted_cells)) + 1]
        run = np.arange(len(order)) - np.repeat(starts, np.diff(np.r_[starts, len(order)]))
        rank[order] = run
        chosen = np.lexsort((-response, rank))[: self.config.n_features]
        return [keypoints[i] for i in np.sort(chosen)]
