"""Dense-map quality against the exact ground truth (issue 38): how accurate and complete a map
is against the static world, and how much of it is the "ghost" of a moving instance.

``reference_clouds`` builds the reference from a generated sequence (true poses, noise-free
depth, instance masks): the static world's cloud and, per moving instance, the cloud of its
surface over all frames. ``map_metrics`` scores a map (an (N, 3) point cloud in the frame of
the estimated trajectory, brought into the ground-truth frame by the trajectory's ATE
alignment) against it, at distance thresholds:

- accuracy: share of map points within t of the static reference (and their mean distance);
- completeness: share of the static reference within t of the map;
- F-score: their harmonic mean, as Tanks and Temples (Knapitsch, Park, Zhou and Koltun,
  "Tanks and Temples: Benchmarking Large-Scale Scene Reconstruction", ACM TOG 36(4), 2017:
  precision, recall, F) and ETH3D (Schöps et al., "A Multi-View Stereo Benchmark with
  High-Resolution Images and Multi-Camera Videos", CVPR 2017: accuracy, completeness, F1)
  define them;
- ghosts: map points with no static surface within t but within t of some moving instance's
  surface at some frame, counted per instance; the rest ("neither") is noise and outliers.

Every map point is exactly one of static (within t of the static world), ghost or neither, so
at each threshold ``accuracy + ghost_fraction + neither_fraction == 1``.

What the static world is: pixels of instance id 0 and of instances that never move in the
sequence (a desk, a parked chair): those are fixed geometry a map should hold, and leaving
them out would count a perfect map's desk as outliers. An instance that moves in any frame
is a moving instance, its surface at every frame (rest positions included) ghost ground.

Sensor noise: the reference uses the noise-free depth (``gt/depth``, written when a sensor
model altered the depth; the depth itself otherwise), at the pixels where the sensor gave a
reading, so it is exact up to the voxel sampling. A map built from the sensor's depth with
the true poses is then only as accurate as the sensor: each point is displaced along its ray
by the axial noise (Kinect model, sim/sensor.py: sigma = 1.2 mm + 1.9 mm (z/m - 0.4)^2, 1.4 cm
at 3 m, 4.1 cm at 5 m, plus disparity quantisation in steps of z^2 / 348 m: 2.6 cm at 3 m,
7.2 cm at 5 m; no reading past 8 m). Measured on static_depot, 10 frames, with the
``kinect`` sensor (tests/test_map_metrics.py): such a map reaches an accuracy of 0.72 / 0.88 /
0.93 (seed 0; 0.75 / 0.87 / 0.93 seed 1) and a completeness of 0.69 / 0.92 / 1.00 (0.77 /
0.95 / 1.00) at 2 / 5 / 10 cm, F 0.70 / 0.90 / 0.97 (0.76 / 0.91 / 0.97), while the same
pixels' noise-free depth scores 1.00 everywhere, as does the default perfect sensor's (depth
quantised to 0.2 mm): the noise alone costs a quarter of the points at 2 cm. A map from this
sensor cannot do better without filtering the noise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from depotbench.eval.metrics.alignment import Similarity
from depotbench.sim.sequence import Sequence
from scipy.spatial import cKDTree

VOXEL_M = 0.01
"""Reference voxel: half the tightest default threshold (2 cm), as Tanks and Temples samples at
tau/2: the sampling puts surface points 2.4 mm from the reference on average, 1 cm at most
(measured on static_depot), well inside 2-10 cm, at ~0.5-1.3 M points per 10 frames."""

DEFAULT_THRESHOLDS_M = (0.02, 0.05, 0.10)

_AXIS_BITS = 21
_AXIS_OFFSET = 1 << (_AXIS_BITS - 1)
_MERGE_ROWS = 4_000_000
"""Voxel rows kept before merging (and twice the merged rows after): bounds memory on long
sequences without merging over and over."""


# -- voxel grids ---------------------------------------------------------------


class _VoxelGrid:
    """Accumulates points into voxels; ``centroids`` gives each occupied voxel's mean point.

    Sums and counts are kept per voxel, so adding a sequence frame by frame gives the same
    centroids as adding it at once, in memory bounded by the occupied voxels."""

    def __init__(self, voxel_m: float) -> None:
        if not (math.isfinite(voxel_m) and voxel_m > 0):
            raise ValueError(f"voxel_m must be a positive number, got {voxel_m!r}")
        self.voxel_m = voxel_m
        self._keys: list[np.ndarray] = []
        self._sums: list[np.ndarray] = []
        self._counts: list[np.ndarray] = []
        self._pending = 0
        self._merged = 0

    def add(self, points: np.ndarray) -> None:
        if len(points) == 0:
            return
        cells = np.floor(points / self.voxel_m).astype(np.int64) + _AXIS_OFFSET
        if cells.min() < 0 or cells.max() >= 1 << _AXIS_BITS:
            raise ValueError(
                f"points reach {np.abs(points).max():.0f} m, beyond the voxel grid's "
                f"{_AXIS_OFFSET * self.voxel_m:.0f} m at voxel_m={self.voxel_m}"
            )
        keys = (cells[:, 0] << (2 * _AXIS_BITS)) | (cells[:, 1] << _AXIS_BITS) | cells[:, 2]
        self._append(keys, points, np.ones(len(points), dtype=np.int64))
        if self._pending > max(_MERGE_ROWS, 2 * self._merged):
            self._merge()

    def _append(self, keys: np.ndarray, sums: np.ndarray, counts: np.ndarray) -> None:
        unique, inverse = np.unique(keys, return_inverse=True)
        size = len(unique)
        merged = np.stack([np.bincount(inverse, weights=sums[:, a], minlength=size) for a in range(3)], 1)
        self._keys.append(unique)
        self._sums.append(merged)
        self._counts.append(np.bincount(inverse, weights=counts, minlength=len(unique)).astype(np.int64))
        self._pending += len(unique)

    def _merge(self) -> None:
        if len(self._keys) <= 1:
            return
        keys, sums = np.concatenate(self._keys), np.concatenate(self._sums)
        counts = np.concatenate(self._counts)
        self._keys, self._sums, self._counts, self._pending = [], [], [], 0
        self._append(keys, sums, counts)
        self._merged = self._pending

    def centroids(self) -> np.ndarray:
        self._merge()
        if not self._keys:
            return np.zeros((0, 3))
        return self._sums[0] / self._counts[0][:, None]


def voxel_downsample(points: np.ndarray, voxel_m: float = VOXEL_M) -> np.ndarray:
    """One point per occupied voxel of a grid of ``voxel_m``: the mean of its points (which,
    unlike the voxel's centre, stays on a sampled surface). Sorted by voxel."""
    grid = _VoxelGrid(voxel_m)
    grid.add(_as_points(points, "points"))
    return grid.centroids()


def _as_points(points: Any, name: str) -> np.ndarray:
    array = np.asarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{name} must be an (N, 3) array, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} holds non-finite coordinates")
    return array


# -- the reference -------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class InstanceCloud:
    """A moving instance's surface over all frames, in the world frame."""

    instance_id: int
    class_name: str
    points_m: np.ndarray

    @property
    def label(self) -> str:
        """``"person 6"``: the class and the instance id of ``gt/instances``."""
        return f"{self.class_name} {self.instance_id}"


@dataclass(frozen=True, eq=False)
class ReferenceClouds:
    """The ground truth a map is scored against, in the world (ground-truth) frame.

    ``static_m``: the static world's surface; ``moving``: each moving instance's surface over
    all frames, by instance id. The k-d trees are built once, on first use, so one reference
    scores many maps."""

    static_m: np.ndarray
    moving: tuple[InstanceCloud, ...] = ()
    voxel_m: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "static_m", _as_points(self.static_m, "static_m"))
        if len(self.static_m) == 0:
            raise ValueError("the static reference holds no point")
        ids = [c.instance_id for c in self.moving]
        if len(set(ids)) != len(ids):
            raise ValueError(f"instance ids repeat in the moving clouds: {ids}")
        for cloud in self.moving:
            object.__setattr__(cloud, "points_m", _as_points(cloud.points_m, f"cloud of {cloud.label}"))

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(c.label for c in self.moving)

    @cached_property
    def static_tree(self) -> cKDTree:
        return cKDTree(self.static_m)

    @cached_property
    def moving_trees(self) -> tuple[cKDTree | None, ...]:
        return tuple(cKDTree(c.points_m) if len(c.points_m) else None for c in self.moving)


def reference_clouds(sequence: Sequence, voxel_m: float = VOXEL_M, every: int = 1) -> ReferenceClouds:
    """The static world's cloud and each moving instance's cloud of a generated sequence.

    Every ``every``-th frame's noise-free depth is back-projected through the true pose where
    the sensor gave a reading; a pixel goes to the static cloud if its instance never moves in
    the sequence (id 0 included), else to its instance's cloud. Each cloud is downsampled to
    one point per ``voxel_m`` voxel (the mean of its points)."""
    if every < 1:
        raise ValueError(f"every must be >= 1, got {every}")
    objects = sequence.objects()
    classes = {o.instance_id: o.class_name for frame in objects for o in frame}
    moving_ids = sorted({o.instance_id for frame in objects for o in frame if o.moving})
    rays = _pixel_rays(sequence)
    static = _VoxelGrid(voxel_m)
    grids = {i: _VoxelGrid(voxel_m) for i in moving_ids}
    for index in range(0, len(sequence), every):
        depth = sequence.clean_depth_m(index)
        valid = (depth > 0) & (sequence.depth_m(index) > 0) & np.isfinite(depth)
        ids = sequence.instances(index)[valid]
        points = _to_world(rays[valid] * depth[valid][:, None], sequence.world_from_camera(index))
        on_moving = np.isin(ids, moving_ids)
        static.add(points[~on_moving])
        for instance_id in np.unique(ids[on_moving]):
            grids[int(instance_id)].add(points[ids == instance_id])
    clouds = tuple(InstanceCloud(i, classes[i], grids[i].centroids()) for i in moving_ids)
    return ReferenceClouds(static.centroids(), tuple(c for c in clouds if len(c.points_m)), voxel_m)


def _pixel_rays(sequence: Sequence) -> np.ndarray:
    """(H, W, 3): each pixel's ray (x/z, y/z, 1) in the optical frame."""
    k = sequence.intrinsics
    v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)
    pixels = k.undistort(np.stack([u.ravel(), v.ravel()], 1)).reshape(k.height, k.width, 2)
    rays = np.ones((k.height, k.width, 3))
    rays[..., 0] = (pixels[..., 0] - k.cx) / k.fx
    rays[..., 1] = (pixels[..., 1] - k.cy) / k.fy
    return rays


def _to_world(points: np.ndarray, world_from_camera: np.ndarray) -> np.ndarray:
    return points @ world_from_camera[:3, :3].T + world_from_camera[:3, 3]


# -- distances -----------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class MapDistances:
    """Nearest-neighbour distances between a map (after its transform) and a reference;
    ``inf`` beyond the bound they were computed to."""

    to_static_m: np.ndarray
    """(N,): each map point to the static reference."""
    static_to_map_m: np.ndarray
    """(R,): each static reference point to the map."""
    to_moving_m: np.ndarray
    """(N, I): each map point to each moving instance's cloud (``reference.moving`` order)."""
    labels: tuple[str, ...]


def map_distances(
    points: np.ndarray,
    reference: ReferenceClouds,
    transform: Similarity | None = None,
    max_distance_m: float = math.inf,
) -> MapDistances:
    """The distances ``map_metrics`` counts from, each exact up to ``max_distance_m``.

    ``transform`` takes the map into the ground-truth frame (``x -> scale R x + t``: the
    trajectory's ATE alignment from ``alignment.align``); it is applied first."""
    cloud = _as_points(points, "points")
    if transform is not None:
        cloud = transform.scale * cloud @ np.asarray(transform.rotation).T + np.asarray(transform.translation)
    bound = max_distance_m * (1 + 1e-9) + 1e-12 if math.isfinite(max_distance_m) else math.inf
    # Each distinct point once: a k-d tree cannot split equal points, so coincident map
    # points (one point written per keyframe that saw it) made one leaf that every reference
    # point was compared with, point by point (500,000 of them took 65 s). A point's
    # distances are its copies' too, bit for bit.
    distinct, copies = _distinct_rows(cloud)
    to_static = _nearest(reference.static_tree, distinct, bound)[copies]
    if len(cloud):
        static_to_map = _nearest(cKDTree(distinct), reference.static_m, bound)
    else:
        static_to_map = np.full(len(reference.static_m), math.inf)
    to_moving = np.full((len(cloud), len(reference.moving)), math.inf)
    for column, tree in enumerate(reference.moving_trees):
        if tree is not None:
            to_moving[:, column] = _nearest(tree, distinct, bound)[copies]
    return MapDistances(to_static, static_to_map, to_moving, reference.labels)


def _distinct_rows(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of ``points`` and, for each row, the index of its distinct row.

    Rows are told apart by a hash of their bits, sorted as one integer: sorting the rows
    themselves (``np.unique(axis=0)``) took 5 s for a million points, as long as the scoring.
    Should two rows share a hash, the rows themselves are sorted after all."""
    bits = np.ascontiguousarray(points).view(np.uint64)
    key = bits[:, 0] * np.uint64(0x9E3779B97F4A7C15) ^ bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F) ^ bits[:, 2]
    _, first, copies = np.unique(key, return_index=True, return_inverse=True)
    distinct = points[first]
    if not np.array_equal(distinct[copies.reshape(-1)], points):
        distinct, copies = np.unique(points, axis=0, return_inverse=True)
    return distinct, copies.reshape(-1)


def _nearest(tree: cKDTree, points: np.ndarray, bound: float) -> np.ndarray:
    if len(points) == 0:
        return np.zeros(0)
    distances, _ = tree.query(points, k=1, distance_upper_bound=bound, workers=-1)
    return np.asarray(distances, dtype=np.float64)


# -- the metrics ---------------------------------------------------------------


@dataclass(frozen=True)
class ThresholdScores:
    """A map's scores at one distance threshold ("within t": distance <= t).

    Shares of map points are NaN for an empty map; completeness and F-score are 0 then."""

    threshold_m: float
    accuracy: float
    """Share of map points within t of the static reference (precision)."""
    accuracy_mean_m: float
    """Mean distance to the static reference of those points (NaN when there are none)."""
    completeness: float
    """Share of the static reference within t of the map (recall)."""
    f_score: float
    """2 accuracy completeness / (accuracy + completeness), 0 when both are 0."""
    ghost_fraction: float
    """Share of map points with no static surface within t and within t of a moving instance."""
    ghosts: dict[str, int]
    """Ghost points per moving instance label (``"person 6"``), each given to its nearest
    instance; every moving instance of the reference is listed, 0 included."""
    neither_fraction: float
    """Share of map points neither static nor ghost: noise and outliers."""


@dataclass(frozen=True)
class MapMetrics:
    """A map's scores against a reference, one ``ThresholdScores`` per threshold."""

    map_points: int
    reference_points: int
    scores: tuple[ThresholdScores, ...]

    def at(self, threshold_m: float) -> ThresholdScores:
        for score in self.scores:
            if math.isclose(score.threshold_m, threshold_m, rel_tol=1e-9, abs_tol=1e-12):
                return score
        raise KeyError(f"no threshold {threshold_m} m (have {[s.threshold_m for s in self.scores]})")

    def to_json(self) -> dict[str, Any]:
        return {
            "map_points": self.map_points,
            "reference_points": self.reference_points,
            "scores": [{**vars(s), "ghosts": dict(s.ghosts)} for s in self.scores],
        }


def map_metrics(
    points: np.ndarray,
    reference: ReferenceClouds,
    thresholds: SequenceOf[float] = DEFAULT_THRESHOLDS_M,
    transform: Similarity | None = None,
) -> MapMetrics:
    """Accuracy, completeness, F-score and ghosts of a map at each threshold (metres).

    ``points``: the map, (N, 3), in the frame of the estimated trajectory; ``transform``: the
    trajectory's alignment onto the ground truth (``alignment.align``'s Similarity), applied to
    the points first; None when the map is already in the ground-truth frame. Accuracy,
    completeness and F-score are Tanks and Temples' precision, recall and F (Knapitsch et al.,
    ACM TOG 2017) and ETH3D's accuracy, completeness and F1 (Schöps et al., CVPR 2017), scored
    against the static world only, so ghosts lower accuracy; see the module docstring."""
    thresholds = tuple(float(t) for t in thresholds)
    if not thresholds or not all(math.isfinite(t) and t > 0 for t in thresholds):
        raise ValueError(f"thresholds must be positive distances in metres, got {thresholds}")
    if len(set(thresholds)) != len(thresholds):
        raise ValueError(f"thresholds repeat: {thresholds}")
    d = map_distances(points, reference, transform, max_distance_m=max(thresholds))
    n = len(d.to_static_m)
    nearest_moving = d.to_moving_m.min(axis=1) if d.to_moving_m.shape[1] else np.full(n, math.inf)
    owner = d.to_moving_m.argmin(axis=1) if d.to_moving_m.shape[1] else np.zeros(n, dtype=np.int64)
    scores = []
    for t in thresholds:
        static = d.to_static_m <= t
        ghost = ~static & (nearest_moving <= t)
        accuracy = _share(static, n)
        completeness = float(np.mean(d.static_to_map_m <= t))
        counts = np.bincount(owner[ghost], minlength=len(d.labels))
        scores.append(
            ThresholdScores(
                threshold_m=t,
                accuracy=accuracy,
                accuracy_mean_m=float(d.to_static_m[static].mean()) if static.any() else math.nan,
                completeness=completeness,
                f_score=f_score(accuracy if n else 0.0, completeness),
                ghost_fraction=_share(ghost, n),
                ghosts={label: int(c) for label, c in zip(d.labels, counts, strict=True)},
                neither_fraction=_share(~static & ~ghost, n),
            )
        )
    return MapMetrics(n, len(reference.static_m), tuple(scores))


def f_score(accuracy: float, completeness: float) -> float:
    """Harmonic mean of accuracy (precision) and completeness (recall); 0 when both are 0."""
    total = accuracy + completeness
    return 2.0 * accuracy * completeness / total if total > 0 else 0.0


def _share(mask: np.ndarray, n: int) -> float:
    return float(np.count_nonzero(mask)) / n if n else math.nan
