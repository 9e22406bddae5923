"""ORB features spread over the image, with their depth: the cacheable front-end stage.

ORB-SLAM detects FAST corners per pyramid level in ~30 px cells, each cell with a
threshold of 20 that falls back to 7 where the cell has no corner, and gives each
level a share of the budget that shrinks with its area. Here OpenCV's ORB detects
once at the low threshold with FAST scores; a cell keeps only its strong corners
when it has any (the per-cell fallback), and each level's share is taken
round-robin over its cells by score, so neither a textured corner of the image
nor a high-contrast background takes the budget from low-contrast surfaces
(clothes, skin) that ORB-SLAM would still sample.
"""

from __future__ import annotations

from dataclasses import dataclass
from operator import attrgetter

import cv2
import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam.config import TrackingConfig

CANDIDATE_FACTOR = 5
"""OpenCV keeps this many times the budget of FAST candidates (best by score, per level) before
the per-cell selection: 5 keeps ~5,000 of the ~7,000 corners at threshold 7 and costs 4 ms less
per frame than keeping all of them (person/background density 0.38 vs 0.42 on walking_xyz)."""

_RESPONSE, _OCTAVE, _ANGLE = attrgetter("response"), attrgetter("octave"), attrgetter("angle")


@dataclass(frozen=True, eq=False)
class FrameFeatures:
    grey: np.ndarray
    keypoints_px: np.ndarray
    """(N, 2) float32 pixel positions at full resolution, as in the image (boxes, flow, depth)."""
    undistorted_px: np.ndarray
    """(N, 2) float64 positions through a distortion-free lens: what geometry uses (equal to
    ``keypoints_px`` for an undistorted camera)."""
    octaves: np.ndarray
    descriptors: np.ndarray
    """(N, 32) uint8 ORB descriptors."""
    depth_m: np.ndarray
    """(N,) depth at each keypoint, 0 where missing or out of range."""
    angles_deg: np.ndarray
    """(N,) ORB orientation of each keypoint."""

    def __len__(self) -> int:
        return len(self.keypoints_px)

    def right_px(self, baseline_fx: float) -> np.ndarray:
        """Each keypoint's column in a virtual right image, u - bf / depth (ORB-SLAM's mvuRight
        for RGB-D), NaN where it has no depth: what every depth check and stereo residual reads."""
        depth = self.depth_m
        right = self.undistorted_px[:, 0] - baseline_fx / np.where(depth > 0, depth, 1.0)
        return np.where(depth > 0, right, np.nan)


class FeatureExtractor:
    def __init__(self, config: TrackingConfig) -> None:
        self.config = config
        self._orb = cv2.ORB_create(
            nfeatures=CANDIDATE_FACTOR * config.n_features,
            scaleFactor=config.scale_factor,
            nlevels=config.n_levels,
            edgeThreshold=19,
            patchSize=31,
            fastThreshold=config.fast_threshold_min,
            scoreType=cv2.ORB_FAST_SCORE,
        )
        inverse = 1.0 / config.scale_factor
        share = inverse ** np.arange(config.n_levels)
        self._per_level = np.round(config.n_features * share / share.sum()).astype(int)

    def extract(self, rgb: np.ndarray, depth_m: np.ndarray, camera: Intrinsics) -> FrameFeatures:
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
        keypoints = self._spread(self._orb.detect(grey, None))
        keypoints, descriptors = self._orb.compute(grey, keypoints)
        if descriptors is None or not keypoints:
            return FrameFeatures(
                grey,
                np.zeros((0, 2), np.float32),
                np.zeros((0, 2)),
                np.zeros(0, int),
                np.zeros((0, 32), np.uint8),
                np.zeros(0),
                np.zeros(0),
            )
        pts = cv2.KeyPoint_convert(keypoints).reshape(-1, 2).astype(np.float32, copy=False)
        octaves = np.fromiter(map(_OCTAVE, keypoints), int, len(keypoints))
        h, w = depth_m.shape
        cols = np.clip(np.rint(pts[:, 0]).astype(int), 0, w - 1)
        rows = np.clip(np.rint(pts[:, 1]).astype(int), 0, h - 1)
        depth = depth_m[rows, cols].astype(np.float64)
        depth[(depth < self.config.min_depth_m) | (depth > self.config.max_depth_m)] = 0.0
        angles = np.fromiter(map(_ANGLE, keypoints), np.float64, len(keypoints))
        return FrameFeatures(grey, pts, camera.undistort(pts), octaves, descriptors, depth, angles)

    def _spread(self, keypoints: tuple) -> list:
        """Per level: drop a cell's weak corners where it has strong ones, then take the
        level's share round-robin over cells, strongest first."""
        if not keypoints:
            return []
        c = self.config
        pts = cv2.KeyPoint_convert(keypoints)
        score = np.fromiter(map(_RESPONSE, keypoints), np.float32, len(keypoints))
        level = np.fromiter(map(_OCTAVE, keypoints), np.int64, len(keypoints))
        size = c.grid_cell_px * c.scale_factor**level  # a cell of the level's image, in level-0 pixels
        cells = level * 1_000_000 + (pts[:, 1] // size).astype(int) * 1000 + (pts[:, 0] // size).astype(int)
        return [keypoints[i] for i in spread(cells, score, level, c.fast_threshold, self._per_level)]


def spread(
    cells: np.ndarray, score: np.ndarray, level: np.ndarray, strong_score: float, per_level: np.ndarray
) -> np.ndarray:
    """Indices (ascending) of the candidates kept: in each cell, those scoring at least
    ``strong_score`` where it has any, else all; then per level its ``per_level`` share,
    round-robin over the level's cells (each cell's best, then each one's second best, ...,
    by score within a round). Scores are FAST scores, whole numbers 0-255, so each ordering
    packs into one int64 key with the position as the tie-break: two plain argsorts take
    0.29 ms a frame where two lexsorts took 0.72."""
    n = len(cells)
    if not n:
        return np.zeros(0, int)
    if score.min() < 0 or score.max() > 255 or not np.array_equal(score, np.floor(score)):
        raise ValueError("keypoint scores must be FAST scores: whole numbers 0-255")
    weak = 255 - score.astype(np.int64)  # ascending key = best first
    position = np.arange(n, dtype=np.int64)
    by_cell = np.argsort((cells.astype(np.int64) * 256 + weak) * n + position)  # by cell, best first
    cell_sorted = cells[by_cell]
    new_cell = np.r_[True, cell_sorted[1:] != cell_sorted[:-1]]
    group = np.cumsum(new_cell) - 1
    has_strong = score[by_cell[new_cell]] >= strong_score  # a cell's best decides
    kept = (score[by_cell] >= strong_score) | ~has_strong[group]
    order, group = by_cell[kept], group[kept]
    first = np.r_[True, group[1:] != group[:-1]]
    starts = np.flatnonzero(first)
    rank = np.arange(len(order)) - starts[np.cumsum(first) - 1]
    m = len(order)
    # per level, round by round, by score within a round, then the earlier cell
    round_key = (level[order].astype(np.int64) * n + rank) * 256 + weak[order]
    rounds = order[np.argsort(round_key * m + np.arange(m))]
    at_level = level[rounds]
    level_start = np.searchsorted(at_level, np.arange(len(per_level)))
    within = np.arange(len(rounds)) - level_start[at_level]
    return np.sort(rounds[within < per_level[at_level]])
