"""Matching keypoints to map points (ORB-SLAM's ORBmatcher): by projection and by descriptor.

Holds how a frame's keypoints are paired with map points and nothing about when: search by
projection (a map point's projection, a radius, the pyramid levels it may appear at, the
Hamming distance, one-to-one, then rotation consistency) and the brute-force descriptor
match relocalisation uses. The rule of both: a pair counts only within ``match_max_hamming``
(100 bits of 256 by default, ORB-SLAM's TH_HIGH), and each keypoint and each point is used once.
Tracking, relocalisation and local mapping all match through here, so they agree on it.
"""

from __future__ import annotations

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam.config import TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.geometry import hamming, hamming_matrix, project, transform
from depotbench.slam.map import Map
from scipy.spatial import cKDTree

ROTATION_BINS = 30
"""Matches against the last frame keep the 3 most common keypoint-angle changes (ORB-SLAM)."""
NEIGHBOURS = 8
"""Keypoints within the search radius considered per projected map point (nearest first)."""

_EMPTY = np.zeros(0, int)


def consistent_rotation(delta_deg: np.ndarray) -> np.ndarray:
    """Mask of matches whose keypoint-angle change falls in the 3 most common of 30 bins
    (ORB-SLAM's rotation-consistency check; a bin needs 10 % of the largest one's count)."""
    bins = (np.mod(delta_deg, 360.0) / (360.0 / ROTATION_BINS)).astype(int) % ROTATION_BINS
    counts = np.bincount(bins, minlength=ROTATION_BINS)
    top = np.argsort(-counts, kind="stable")[:3]
    top = top[counts[top] >= 0.1 * counts[top[0]]]
    return np.isin(bins, top)


def octave_window(
    octaves: np.ndarray, forward_m: float, baseline_m: float, n_levels: int
) -> tuple[np.ndarray, np.ndarray]:
    """Pyramid levels where the last frame's points may be found (ORB-SLAM's
    SearchByProjection): after moving forward (``forward_m``, the motion model's z) by more
    than the baseline the camera sees them larger (at their level or a coarser one), after
    moving back smaller (at their level or a finer one), else within one level of theirs."""
    if forward_m > baseline_m:
        return octaves, np.full_like(octaves, n_levels)
    if -forward_m > baseline_m:
        return np.zeros_like(octaves), octaves
    return octaves - 1, octaves + 1


class Matcher:
    """Search by projection into one camera with one set of tracking settings; stateless."""

    def __init__(self, tc: TrackingConfig, camera: Intrinsics) -> None:
        self.tc = tc
        self.camera = camera

    def search_by_projection(
        self,
        map_: Map,
        point_ids: np.ndarray,
        camera_from_world: np.ndarray,
        features: FrameFeatures,
        usable: np.ndarray,
        radius: float | np.ndarray,
        exclude: np.ndarray | None = None,
        reference_angles: np.ndarray | None = None,
        octave_window: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Matches (keypoint indices, point ids) of map points projected near usable keypoints;
        also returns the ids that projected into the image (for visibility counts).

        ``radius`` is one value or one per point; ``octave_window`` (lowest, highest) per point
        limits the pyramid levels a match may come from, as ORB-SLAM's search does;
        ``reference_angles`` (per point) turn on the rotation-consistency check.
        """
        empty = (_EMPTY, _EMPTY, _EMPTY)
        angles = reference_angles
        per_point = {"radius": np.broadcast_to(np.asarray(radius, float), point_ids.shape)}
        if octave_window is not None:
            per_point["low"], per_point["high"] = octave_window
        if len(point_ids):
            alive = map_.alive[point_ids]
            point_ids = point_ids[alive]
            angles = None if angles is None else angles[alive]
            per_point = {k: v[alive] for k, v in per_point.items()}
        candidates = np.flatnonzero(usable)
        if exclude is not None:
            candidates = candidates[~exclude[candidates]]
        if len(point_ids) == 0 or len(candidates) == 0:
            return empty
        pc = transform(camera_from_world, map_.positions[point_ids])
        front = pc[:, 2] > self.tc.min_depth_m
        point_ids, pc = point_ids[front], pc[front]
        angles = None if angles is None else angles[front]
        per_point = {k: v[front] for k, v in per_point.items()}
        uv = project(self.camera, pc)
        inside = (
            (uv[:, 0] >= 0)
            & (uv[:, 0] < self.camera.width)
            & (uv[:, 1] >= 0)
            & (uv[:, 1] < self.camera.height)
        )
        point_ids, uv = point_ids[inside], uv[inside]
        angles = None if angles is None else angles[inside]
        per_point = {k: v[inside] for k, v in per_point.items()}
        if len(point_ids) == 0:
            return empty
        tree = cKDTree(features.undistorted_px[candidates])
        gap, nearest = tree.query(uv, k=NEIGHBOURS, distance_upper_bound=float(per_point["radius"].max()))
        found = (nearest < len(candidates)) & (gap <= per_point["radius"][:, None])
        pairs_point = np.nonzero(found)[0]
        if len(pairs_point) == 0:
            return (*empty[:2], point_ids)
        pairs_kp = candidates[nearest[found]]
        if octave_window is not None:
            level = features.octaves[pairs_kp]
            fits = (level >= per_point["low"][pairs_point]) & (level <= per_point["high"][pairs_point])
            pairs_point, pairs_kp = pairs_point[fits], pairs_kp[fits]
        distance = hamming(map_.descriptors[point_ids[pairs_point]], features.descriptors[pairs_kp])
        good = distance <= self.tc.match_max_hamming
        if not good.any():
            return (*empty[:2], point_ids)
        pairs_point, pairs_kp, distance = pairs_point[good], pairs_kp[good], distance[good]
        # Best keypoint per point, then best point per keypoint (one-to-one).
        order = np.lexsort((distance, pairs_point))
        first = np.r_[True, np.diff(pairs_point[order]) != 0]
        best = order[first]
        order = np.lexsort((distance[best], pairs_kp[best]))
        first = np.r_[True, np.diff(pairs_kp[best][order]) != 0]
        best = best[order[first]]
        if angles is not None and len(best):
            best = best[consistent_rotation(features.angles_deg[pairs_kp[best]] - angles[pairs_point[best]])]
        return pairs_kp[best], point_ids[pairs_point[best]], point_ids

    def search_by_descriptor(
        self, map_: Map, features: FrameFeatures, candidates: np.ndarray, point_ids: np.ndarray, ratio: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Matches (keypoint indices, point ids) of ``candidates`` against every one of
        ``point_ids`` by descriptor alone: the nearest within ``match_max_hamming`` and under
        ``ratio`` times the second nearest; one keypoint per point (the first found)."""
        distances = hamming_matrix(features.descriptors[candidates], map_.descriptors[point_ids])
        if distances.shape[1] < 2:
            return _EMPTY, _EMPTY
        two = np.partition(distances, 1, axis=1)[:, :2]
        best = np.argmin(distances, axis=1)
        good = (two[:, 0] <= self.tc.match_max_hamming) & (two[:, 0] < ratio * two[:, 1])
        kp, pid = candidates[good], point_ids[best[good]]
        _, unique = np.unique(pid, return_index=True)
        return kp[unique], pid[unique]
