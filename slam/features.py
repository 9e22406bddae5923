"""ORB features spread over the image, with their depth: the cacheable front-end stage.

ORB-SLAM detects FAST corners per pyramid level in ~30 px cells, each cell with a
threshold of 20 that falls back to 7 where the cell has no corner, and distributes each
level's share of the budget (shrinking with the level's area) with a quadtree
(DistributeOctTree): the level's corners are split into quadrants until there are as many
leaves as keypoints wanted, and each leaf keeps its strongest corner. Here OpenCV's ORB
detects once at the low threshold with FAST scores; a cell keeps only its strong corners
when it has any (the per-cell fallback), and the quadtree then picks the level's share.
The quadtree spends keypoints where corners are dense but leaves no region without one:
37 % of them lie closer than ThDepth on walking_xyz, as ORB-SLAM3's, and the keyframe rule
counts close points.
"""

from __future__ import annotations

from dataclasses import dataclass
from operator import attrgetter

import cv2
import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam import kernels
from depotbench.slam.config import TrackingConfig

CANDIDATE_FACTOR = 10
"""OpenCV keeps this many times the budget of FAST candidates (best by score, per level) before
the per-cell selection; ORB-SLAM keeps every corner. Weak corners (clothes, skin) are the
first cut: keypoint density on people over the background's, median over 10 frames of
walking_static, is 0.49 for ORB-SLAM3's own keypoints, 0.39 here with 5, 0.48 with 10 and
0.53 with 20; 10 costs 1.5 ms a frame more than 5, 20 another 0.6 ms."""

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
        self._per_level = features_per_level(config.n_features, config.scale_factor, config.n_levels)

    def extract(self, rgb: np.ndarray, depth_m: np.ndarray, camera: Intrinsics) -> FrameFeatures:
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
        keypoints = self._spread(self._orb.detect(grey, None), grey.shape)
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

    def _spread(self, keypoints: tuple, shape: tuple[int, ...]) -> list:
        """Per cell, the strong corners where there are any; then per level the quadtree's
        pick of the level's share (ORB-SLAM's ComputeKeyPointsOctTree)."""
        if not keypoints:
            return []
        c = self.config
        pts = cv2.KeyPoint_convert(keypoints)
        score = np.fromiter(map(_RESPONSE, keypoints), np.float32, len(keypoints))
        level = np.fromiter(map(_OCTAVE, keypoints), np.int64, len(keypoints))
        scale = c.scale_factor**level
        size = c.grid_cell_px * scale  # a cell of the level's image, in level-0 pixels
        cells = level * 1_000_000 + (pts[:, 1] // size).astype(int) * 1000 + (pts[:, 0] // size).astype(int)
        strong = strong_per_cell(cells, score, c.fast_threshold)
        level_px = pts / scale[:, None] - BORDER_PX  # in the level's image, from its border
        chosen = []
        for lev in range(c.n_levels):
            rows = np.flatnonzero(strong & (level == lev))
            width = round(shape[1] / c.scale_factor**lev) - 2 * BORDER_PX
            height = round(shape[0] / c.scale_factor**lev) - 2 * BORDER_PX
            if len(rows) and width > 0 and height > 0:
                x, y = level_px[rows, 0], level_px[rows, 1]
                chosen.append(rows[distribute(x, y, score[rows], width, height, self._per_level[lev])])
        return [keypoints[i] for i in np.sort(np.concatenate(chosen))] if chosen else []


BORDER_PX = 16
"""ORB-SLAM's minBorderX/Y (EDGE_THRESHOLD - 3): the quadtree covers a level's image less this."""


def features_per_level(n_features: int, scale_factor: float, n_levels: int) -> np.ndarray:
    """ORB-SLAM's mnFeaturesPerLevel: a geometric share per level (ratio 1 / scale_factor),
    each rounded, the last level taking what is left."""
    factor = 1.0 / scale_factor
    desired = n_features * (1 - factor) / (1 - factor**n_levels)
    counts = []
    for _ in range(n_levels - 1):
        counts.append(int(np.rint(desired)))
        desired *= factor
    counts.append(max(n_features - sum(counts), 0))
    return np.array(counts, int)


def strong_per_cell(cells: np.ndarray, score: np.ndarray, strong_score: float) -> np.ndarray:
    """Which candidates a cell keeps: those scoring at least ``strong_score`` where the cell
    has any, else all (ORB-SLAM's FAST at 20, again at 7 in a cell that found nothing)."""
    if not len(cells):
        return np.zeros(0, bool)
    order = np.argsort(cells, kind="stable")
    by_cell = cells[order]
    new_cell = np.r_[True, by_cell[1:] != by_cell[:-1]]
    best = np.maximum.reduceat(score[order], np.flatnonzero(new_cell))[np.cumsum(new_cell) - 1]
    keep = np.empty(len(cells), bool)
    keep[order] = (score[order] >= strong_score) | (best < strong_score)
    return keep


def distribute(
    xs: np.ndarray, ys: np.ndarray, response: np.ndarray, width: int, height: int, wanted: int
) -> np.ndarray:
    """ORB-SLAM's DistributeOctTree on one level's candidates at (xs, ys) in [0, width) x
    [0, height): the indices (ascending) of those kept, one per leaf (compiled unless
    ``DEPOTBENCH_KERNELS=numpy``; ``distribute_numpy`` is the reference)."""
    if not kernels.compiled():
        return distribute_numpy(xs, ys, response, width, height, wanted)
    from depotbench.slam.kernels import features as compiled

    args = (np.ascontiguousarray(xs, np.float64), np.ascontiguousarray(ys, np.float64))
    return compiled.distribute(*args, np.ascontiguousarray(response, np.float64), width, height, wanted)


def distribute_numpy(
    xs: np.ndarray, ys: np.ndarray, response: np.ndarray, width: int, height: int, wanted: int
) -> np.ndarray:
    """The quadtree written out with lists, as ORB-SLAM's DistributeOctTree runs it.

    Start with round(width / height) columns. A pass splits every node holding more than one
    candidate into its quadrants (sides halved, rounded up; empty ones dropped). Stop once
    there are ``wanted`` nodes or a pass adds none; when a full pass would overshoot (nodes +
    3 x splittable > wanted), split the splittable nodes one by one instead, most candidates
    first (then the larger left edge, then the later made: ORB-SLAM's sort leaves that
    order open), until there are ``wanted``, round after round. Nodes are visited in the
    order they were made. Each node keeps its highest response (the lower index among
    equals)."""
    n = len(xs)
    if n == 0 or wanted <= 0:
        return np.zeros(0, int)
    n_ini = max(int(np.floor(width / height + 0.5)), 1)
    hx = width / n_ini
    columns: list[list[int]] = [[] for _ in range(n_ini)]
    for k in range(n):
        columns[min(int(xs[k] / hx), n_ini - 1)].append(k)
    # a node: [left, top, right, bottom, candidates, when made]; nodes are kept in that order
    nodes = [[int(hx * c), 0, int(hx * (c + 1)), height, keys] for c, keys in enumerate(columns) if keys]
    for made, node in enumerate(nodes):
        node.append(made)
    made = len(nodes)

    def divide(node: list) -> list[list]:
        nonlocal made
        left, top, right, bottom, keys, _ = node
        midx, midy = left + int(np.ceil((right - left) / 2)), top + int(np.ceil((bottom - top) / 2))
        quadrants = [
            [left, top, midx, midy, []],
            [midx, top, right, midy, []],
            [left, midy, midx, bottom, []],
            [midx, midy, right, bottom, []],
        ]
        for k in keys:
            quadrants[(0 if xs[k] < midx else 1) + (0 if ys[k] < midy else 2)][4].append(k)
        children = [q for q in quadrants if q[4]]
        for child in children:
            child.append(made)
            made += 1
        return children

    while True:
        before = len(nodes)
        expand, after = [], []
        for node in nodes:
            if len(node[4]) == 1:
                after.append(node)
                continue
            children = divide(node)
            after += children
            expand += [child for child in children if len(child[4]) > 1]
        nodes = sorted(after, key=lambda node: node[5])
        if len(nodes) >= wanted or len(nodes) == before:
            break
        if len(nodes) + 3 * len(expand) > wanted:
            while True:
                before = len(nodes)
                order = sorted(range(len(expand)), key=lambda i: (len(expand[i][4]), expand[i][0], i))
                splitting, expand = [expand[i] for i in reversed(order)], []
                for node in splitting:
                    nodes.remove(node)
                    children = divide(node)
                    nodes += children
                    expand += [child for child in children if len(child[4]) > 1]
                    if len(nodes) >= wanted:
                        break
                if len(nodes) >= wanted or len(nodes) == before:
                    break
            break
    kept = [max(node[4], key=lambda k: (response[k], -k)) for node in nodes]
    return np.sort(np.array(kept, int))
