"""ORB features spread over the image, with their depth: the cacheable front-end stage.

ORB-SLAM detects FAST corners per pyramid level in ~30 px cells, each cell with a
threshold of 20 that falls back to 7 where the cell has no corner, and distributes each
level's share of the budget (shrinking with the level's area) with a quadtree
(DistributeOctTree): the level's corners are split into quadrants until there are as many
leaves as keypoints wanted, and each leaf keeps its strongest corner; only those are oriented
and described. Here FAST runs once per level at the low threshold; a cell keeps only its
strong corners when it has any (the per-cell fallback), and the quadtree then picks the
level's share. The quadtree spends keypoints where corners are dense but leaves no region
without one: 37 % of them lie closer than ThDepth on walking_xyz, as ORB-SLAM3's, and the
keyframe rule counts close points. The pyramid, the corners before the per-cell selection,
the orientations and the descriptors are OpenCV ORB's own (tests hold them equal).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
from depotbench.core.assets import asset
from depotbench.core.camera import Intrinsics
from depotbench.slam import kernels
from depotbench.slam.config import TrackingConfig

CANDIDATE_FACTOR = 10
"""Each level keeps this many times its share of the budget of FAST candidates (the best by
score, as OpenCV's ORB does) before the per-cell selection; ORB-SLAM keeps every corner. Weak
corners (clothes, skin) are the first cut: keypoint density on people over the background's,
median over 10 frames of walking_static, is 0.49 for ORB-SLAM3's own keypoints, 0.39 here
with 5, 0.48 with 10 and 0.53 with 20."""
EDGE_PX = 19
"""No corner closer than this to a level's edge (OpenCV ORB's edgeThreshold; ORB-SLAM's
EDGE_THRESHOLD is 19 too): the 31 px patch and its rotation stay inside the image."""
PATCH_PX = 31
"""ORB's patch: the orientation disc's diameter and the descriptor's extent."""


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
            nfeatures=config.n_features,
            scaleFactor=config.scale_factor,
            nlevels=config.n_levels,
            edgeThreshold=EDGE_PX,
            patchSize=PATCH_PX,
        )  # the reference's describer (``_describe_opencv``), on its own blurred pyramid
        n_levels, factor = config.n_levels, config.scale_factor
        self._per_level = features_per_level(config.n_features, factor, n_levels)
        self._candidates = features_per_level(CANDIDATE_FACTOR * config.n_features, factor, n_levels)
        self._scales = np.array([float(np.float32(factor)) ** level for level in range(n_levels)], np.float32)
        """Each level's scale as OpenCV's ORB takes it (its factor is a float32), so that the
        keypoints it describes land on the pixels they were found at."""
        self._half_widths = disc_half_widths(PATCH_PX // 2)

    def extract(self, rgb: np.ndarray, depth_m: np.ndarray, camera: Intrinsics) -> FrameFeatures:
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else np.ascontiguousarray(rgb)
        levels = self.pyramid(grey)
        kept = self._keypoints(levels)
        octaves = np.concatenate([np.full(len(xs), level) for level, (xs, *_) in enumerate(kept)])
        scale = self._scales[octaves]  # level-0 pixels as OpenCV's ORB has them
        xs, ys, scores, angles = (np.concatenate(part) for part in zip(*kept, strict=True))
        pts = np.c_[xs.astype(np.float32) * scale, ys.astype(np.float32) * scale]
        if not len(pts):
            return FrameFeatures(
                grey,
                np.zeros((0, 2), np.float32),
                np.zeros((0, 2)),
                np.zeros(0, int),
                np.zeros((0, 32), np.uint8),
                np.zeros(0),
                np.zeros(0),
            )
        if kernels.compiled():
            descriptors = describe(levels, xs, ys, octaves, angles)
        else:
            descriptors = self._describe_opencv(grey, pts, scale, angles, scores, octaves)
        angles = angles.astype(np.float64)
        h, w = depth_m.shape
        cols = np.clip(np.rint(pts[:, 0]).astype(int), 0, w - 1)
        rows = np.clip(np.rint(pts[:, 1]).astype(int), 0, h - 1)
        depth = depth_m[rows, cols].astype(np.float64)
        depth[(depth < self.config.min_depth_m) | (depth > self.config.max_depth_m)] = 0.0
        return FrameFeatures(grey, pts, camera.undistort(pts), octaves, descriptors, depth, angles)

    def _describe_opencv(
        self,
        grey: np.ndarray,
        pts: np.ndarray,
        scale: np.ndarray,
        angles: np.ndarray,
        scores: np.ndarray,
        octaves: np.ndarray,
    ) -> np.ndarray:
        """``describe`` by OpenCV's ORB (the reference): the keypoints as its objects, at the
        level-0 positions it scales back onto the pixels they were found at."""
        columns = (
            *pts.T.tolist(),
            (PATCH_PX * scale).tolist(),
            angles.tolist(),
            scores.tolist(),
            octaves.tolist(),
        )
        keypoints = [cv2.KeyPoint(*keypoint) for keypoint in zip(*columns, strict=True)]
        # keypoints sorted by level come back in their order, none dropped (all lie EDGE_PX inside
        # their level): the arrays of ``extract`` stay theirs
        described, descriptors = self._orb.compute(grey, keypoints)
        if descriptors is None or len(described) != len(keypoints):
            raise RuntimeError(f"ORB described {len(described)} of {len(keypoints)} keypoints")
        return descriptors

    def pyramid(self, grey: np.ndarray) -> list[np.ndarray]:
        """OpenCV ORB's pyramid: each level resized from the one above it, its size the image's
        over the level's scale, rounded; it stops at the first level too small to hold a
        corner EDGE_PX inside its edges."""
        height, width = grey.shape
        levels = [grey]
        for scale in self._scales[1:]:
            size = (int(np.rint(np.float32(width) / scale)), int(np.rint(np.float32(height) / scale)))
            if min(size) <= 2 * EDGE_PX:
                break
            levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR_EXACT))
        return levels

    def candidates(self, level_image: np.ndarray, level: int) -> tuple[np.ndarray, ...]:
        """A level's FAST corners at the low threshold, the best CANDIDATE_FACTOR times its
        share: columns, rows and scores, row by row (OpenCV's ORB keeps the same)."""
        xs, ys, scores = corners(level_image, self.config.fast_threshold_min, EDGE_PX)
        best = retain_best(scores, int(self._candidates[level]))
        return xs[best], ys[best], scores[best]

    def _keypoints(self, levels: list[np.ndarray]) -> list[tuple[np.ndarray, ...]]:
        """Per level of the pyramid: the columns, rows (in the level's image), scores and
        orientations of the keypoints kept, in the order ORB-SLAM would spread them
        (ComputeKeyPointsOctTree)."""
        c = self.config
        found = []
        for level, level_image in enumerate(levels):
            xs, ys, scores = self.candidates(level_image, level)
            per_row = level_image.shape[1] // c.grid_cell_px + 1
            strong = strong_per_cell(
                (ys // c.grid_cell_px) * per_row + xs // c.grid_cell_px, scores, c.fast_threshold
            )
            xs, ys, scores = xs[strong], ys[strong], scores[strong]
            inner_w, inner_h = level_image.shape[1] - 2 * BORDER_PX, level_image.shape[0] - 2 * BORDER_PX
            if len(xs) and inner_w > 0 and inner_h > 0:
                wanted = int(self._per_level[level])
                kept = distribute(xs - BORDER_PX, ys - BORDER_PX, scores, inner_w, inner_h, wanted)
                xs, ys, scores = xs[kept], ys[kept], scores[kept]
            else:
                xs, ys, scores = xs[:0], ys[:0], scores[:0]
            found.append((xs, ys, scores, orientations(level_image, xs, ys, self._half_widths)))
        return found


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
    has any, else all (ORB-SLAM's FAST at 20, again at 7 in a cell that found nothing).
    Cells are numbered from 0."""
    if not len(cells):
        return np.zeros(0, bool)
    best = np.zeros(int(cells.max()) + 1, score.dtype)
    np.maximum.at(best, cells, score)
    return (score >= strong_score) | (best[cells] < strong_score)


def corners(image: np.ndarray, threshold: int, border: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """FAST-9 corners of a uint8 image, ``border`` px inside its edges, after 3 x 3 non-maximum
    suppression: columns, rows and scores (OpenCV's FAST score), row by row (compiled unless
    ``DEPOTBENCH_KERNELS=numpy``; ``corners_opencv`` is the reference)."""
    if not kernels.compiled():
        return corners_opencv(image, threshold, border)
    from depotbench.slam.kernels import features as compiled

    return compiled.fast_corners(np.ascontiguousarray(image, np.uint8), int(threshold), int(border))


def corners_opencv(
    image: np.ndarray, threshold: int, border: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``corners`` by OpenCV's FAST detector (what OpenCV's ORB runs), in the same order."""
    found = cv2.FastFeatureDetector_create(int(threshold), True).detect(image)
    xy = np.rint(cv2.KeyPoint_convert(found)).astype(np.int64).reshape(-1, 2)
    scores = np.array([k.response for k in found], np.int32)
    h, w = image.shape
    inside = (xy[:, 0] >= border) & (xy[:, 0] < w - border) & (xy[:, 1] >= border) & (xy[:, 1] < h - border)
    xs, ys, scores = xy[inside, 0], xy[inside, 1], scores[inside]
    order = np.lexsort((xs, ys))
    return xs[order], ys[order], scores[order]


def retain_best(scores: np.ndarray, n: int) -> np.ndarray:
    """Which candidates a level keeps: the ``n`` best scores and every one tying the n-th
    (OpenCV's KeyPointsFilter::retainBest, which its ORB applies per level)."""
    if len(scores) <= n:
        return np.ones(len(scores), bool)
    if n <= 0:
        return np.zeros(len(scores), bool)
    return scores >= np.partition(scores, len(scores) - n)[len(scores) - n]


def disc_half_widths(radius: int) -> np.ndarray:
    """How far row v of ORB's orientation disc reaches either side of the centre, v = 0 ..
    radius: the circle's width up to 45 degrees (plus one row), the rows beyond from the
    columns' heights, so that the disc is the same after swapping x and y."""
    widths = np.zeros(radius + 1, np.int64)
    low = int(np.floor(radius * np.sqrt(2) / 2 + 1))
    for v in range(low + 1):
        widths[v] = int(np.rint(np.sqrt(radius * radius - v * v)))
    column = 0
    for v in range(radius, int(np.ceil(radius * np.sqrt(2) / 2)) - 1, -1):
        while widths[column] == widths[column + 1]:
            column += 1
        widths[v] = column
        column += 1
    return widths


def orientations(image: np.ndarray, xs: np.ndarray, ys: np.ndarray, half_widths: np.ndarray) -> np.ndarray:
    """ORB's orientation of keypoints at integer (xs, ys), in degrees: the direction from each
    to the intensity centroid of its disc, by OpenCV's arctangent (what its ORB uses; float32)."""
    if not len(xs):
        return np.zeros(0, np.float32)
    if kernels.compiled():
        from depotbench.slam.kernels import features as compiled

        m10, m01 = compiled.moments(np.ascontiguousarray(image, np.uint8), xs, ys, half_widths)
    else:
        m10, m01 = moments_numpy(image, xs, ys, half_widths)
    return cv2.phase(m10.astype(np.float32), m01.astype(np.float32), angleInDegrees=True).ravel()


BLUR_KERNEL = cv2.getGaussianKernel(7, 2, cv2.CV_32F)
"""The blur ORB describes on: a 7 x 7 Gaussian of sigma 2, reflected at the edges (OpenCV's ORB
and ORB-SLAM's extractor), applied as two float passes rounded to bytes as OpenCV's ORB
applies it. ``cv2.GaussianBlur`` on bytes takes a fixed-point path instead: one level apart
on 1 % of a ``tum`` frame's pixels (a fifth of a noise image's), one descriptor bit in 190."""


def orb_blur(level: np.ndarray) -> np.ndarray:
    """A pyramid level blurred as ORB describes on it (``BLUR_KERNEL``)."""
    return cv2.sepFilter2D(level, cv2.CV_8U, BLUR_KERNEL, BLUR_KERNEL, borderType=cv2.BORDER_REFLECT_101)


@functools.cache
def orb_pattern() -> np.ndarray:
    """(256, 4) int64: ORB's point pairs (x0, y0, x1, y1), bit 0 first (assets/orb/PROVENANCE.md)."""
    pattern = np.loadtxt(asset("orb", "bit_pattern_31.txt"), dtype=np.int64, ndmin=2)
    if pattern.shape != (256, 4) or np.abs(pattern).max() > PATCH_PX // 2:
        raise RuntimeError(f"{asset('orb', 'bit_pattern_31.txt')}: not 256 pairs on a {PATCH_PX} px patch")
    return pattern


def describe(
    levels: list[np.ndarray], xs: np.ndarray, ys: np.ndarray, octaves: np.ndarray, angles: np.ndarray
) -> np.ndarray:
    """(N, 32) uint8: ORB's descriptor of each keypoint at (xs, ys) of pyramid level ``octaves``
    with orientation ``angles`` (degrees), compiled: the levels used, each blurred once, laid
    end to end. Equal to OpenCV's ``ORB.compute`` on the same keypoints bit for bit
    (``FeatureExtractor._describe_opencv``, the reference; ``tests/test_orb_descriptors.py``).
    Every keypoint lies ``EDGE_PX`` inside its level, beyond the rotated pattern's reach."""
    from depotbench.slam.kernels import features as compiled

    used = levels[: int(octaves.max()) + 1]
    blurred = [orb_blur(level) for level in used]
    sizes = np.array([level.size for level in blurred], np.int64)
    return compiled.describe(
        np.concatenate([level.ravel() for level in blurred]),
        np.cumsum(sizes) - sizes,
        np.array([level.shape[1] for level in blurred], np.int64),
        xs.astype(np.int64),
        ys.astype(np.int64),
        octaves.astype(np.int64),
        angles.astype(np.float32),
        orb_pattern(),
    )


def moments_numpy(
    image: np.ndarray, xs: np.ndarray, ys: np.ndarray, half_widths: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The first moments (m10, m01) of each keypoint's disc, summed as integers."""
    radius = len(half_widths) - 1
    v, u = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    inside = np.abs(u) <= half_widths[np.abs(v)]
    u, v = u[inside], v[inside]
    values = image[ys[:, None] + v, xs[:, None] + u].astype(np.int64)
    return values @ u, values @ v


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
