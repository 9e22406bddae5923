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
from depotbench.slam import kernels
from depotbench.slam.config import TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.geometry import hamming, hamming_matrix, invert, project, transform
from depotbench.slam.map import Map
from scipy.spatial import cKDTree

ROTATION_BINS = 30
"""Matches against the last frame keep the 3 most common keypoint-angle changes (ORB-SLAM)."""
NEIGHBOURS = 8
"""Keypoints within the search radius considered per projected map point (nearest first)."""

LOCAL_NEIGHBOURS = 32
"""Keypoints in the search square considered per local-map point, nearest first (ORB-SLAM
scans all of them): 32 hold every one of the square in 99.4 % of searches, 16 in 93 %
(measured on walking_static seed 1 and walking_xyz seed 3)."""
VIEWING_COS_LIMIT = 0.5
"""Frame::isInFrustum's viewingCosLimit: a point is in view only within 60 degrees of its normal."""
REFERENCE_RATIO = 0.7
"""TrackReferenceKeyFrame's ORBmatcher(0.7, true): nearest under 0.7 times the second nearest."""
LOCAL_RATIO = 0.8
"""SearchLocalPoints' ORBmatcher(0.8): a best match no better than 0.8 times the second best
at the same level is ambiguous."""

_EMPTY = np.zeros(0, int)


def consistent_rotation(delta_deg: np.ndarray) -> np.ndarray:
    """Mask of matches whose keypoint-angle change falls in the 3 most common of 30 bins
    (ORB-SLAM's rotation-consistency check; a bin needs 10 % of the largest one's count)."""
    bins = (np.mod(delta_deg, 360.0) / (360.0 / ROTATION_BINS)).astype(int) % ROTATION_BINS
    counts = np.bincount(bins, minlength=ROTATION_BINS)
    top = np.argsort(-counts, kind="stable")[:3]
    top = top[counts[top] >= 0.1 * counts[top[0]]]
    return np.isin(bins, top)


def nearest_keypoints(
    keypoints_px: np.ndarray, uv: np.ndarray, k: int, bound: float, p: float
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` keypoints nearest each projection in ``uv`` within ``bound`` (distance of
    Minkowski order ``p``: 2 a circle, inf a square), nearest first: (distances, indices into
    ``keypoints_px``; inf and ``len(keypoints_px)`` where fewer are in reach). Keypoints at one
    distance (one corner at two pyramid levels) go lower index first, as the compiled searches
    take them; the k-d tree's own order of equals is unspecified, so it is asked for 2k."""
    gap, nearest = cKDTree(keypoints_px).query(uv, k=2 * k, p=p, distance_upper_bound=bound)
    order = np.lexsort((nearest, gap), axis=-1)[:, :k]
    return np.take_along_axis(gap, order, 1), np.take_along_axis(nearest, order, 1)


def square_pairs(
    features: FrameFeatures,
    candidates: np.ndarray,
    uv: np.ndarray,
    radius: np.ndarray,
    level: np.ndarray,
    k: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(point rows, keypoints, their levels) of the local-map search and Fuse: of each point's
    ``k`` nearest ``candidates``, those inside the square of its ``radius`` around its
    projection (GetFeaturesInArea) at its predicted ``level`` or one finer, nearest first."""
    gap, nearest = nearest_keypoints(features.undistorted_px[candidates], uv, k, float(radius.max()), np.inf)
    rows, cols = np.nonzero((nearest < len(candidates)) & (gap < radius[:, None]))
    kps = candidates[nearest[rows, cols]]
    kp_level = features.octaves[kps]
    fits = (kp_level >= level[rows] - 1) & (kp_level <= level[rows])
    return rows[fits], kps[fits], kp_level[fits]


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
        depth_check: bool = False,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Matches (keypoint indices, point ids) of map points projected near usable keypoints;
        also returns the ids that projected into the image (for visibility counts).

        ``radius`` is one value or one per point; ``octave_window`` (lowest, highest) per point
        limits the pyramid levels a match may come from, as ORB-SLAM's search does;
        ``reference_angles`` (per point) turn on the rotation-consistency check;
        ``depth_check`` refuses a keypoint with depth whose right-image column (u - bf / depth)
        lies farther than the radius from the point's projected one (ORB-SLAM's
        SearchByProjection against the last frame: at 2 m a 10 % depth error moves it 2 px).
        """
        if kernels.compiled():
            from depotbench.slam.kernels import matching

            return matching.search_by_projection(
                self,
                map_,
                point_ids,
                camera_from_world,
                features,
                usable,
                radius,
                exclude,
                reference_angles,
                octave_window,
                depth_check,
            )
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
        right = uv[:, 0] - self.tc.baseline_fx / pc[inside, 2]
        if len(point_ids) == 0:
            return empty
        gap, nearest = nearest_keypoints(
            features.undistorted_px[candidates], uv, NEIGHBOURS, float(per_point["radius"].max()), 2
        )
        found = (nearest < len(candidates)) & (gap <= per_point["radius"][:, None])
        pairs_point = np.nonzero(found)[0]
        if len(pairs_point) == 0:
            return (*empty[:2], point_ids)
        pairs_kp = candidates[nearest[found]]
        if octave_window is not None:
            level = features.octaves[pairs_kp]
            fits = (level >= per_point["low"][pairs_point]) & (level <= per_point["high"][pairs_point])
            pairs_point, pairs_kp = pairs_point[fits], pairs_kp[fits]
        if depth_check:
            kp_right = features.right_px(self.tc.baseline_fx)[pairs_kp]
            near = np.abs(kp_right - right[pairs_point]) <= per_point["radius"][pairs_point]
            fits = np.isnan(kp_right) | near
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

    def search_local_points(
        self,
        map_: Map,
        point_ids: np.ndarray,
        camera_from_world: np.ndarray,
        features: FrameFeatures,
        usable: np.ndarray,
        exclude: np.ndarray,
        th: float,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """ORB-SLAM's SearchLocalPoints: (keypoints, point ids) matched, and the ids in view.

        A point is in view (Frame::isInFrustum) when it projects in front of the camera into
        the image, within its distance range (0.8 min .. 1.2 max), seen less than 60 degrees
        off its normal. Its level is predicted from the distance (``predict_level``); it is
        searched for in a square of th x (2.5 px within 3.6 degrees of its normal, else 4 px)
        x scale^level around its projection (RGB-D: th = 3), among keypoints at that level or
        one finer whose depth puts them within the same distance of its projected right-image
        column. The closest descriptor wins within TH_HIGH (100), unless the second closest is
        at the same level and the best is not under 0.8 times it. Each keypoint keeps its
        closest point."""
        tc, camera = self.tc, self.camera
        empty = (_EMPTY, _EMPTY, _EMPTY)
        point_ids = point_ids[map_.alive[point_ids]]
        if not len(point_ids):
            return empty
        point_ids, pc, uv, distance, view_cos = points_in_view(map_, point_ids, camera_from_world, camera)
        candidates = np.flatnonzero(usable & ~exclude)
        if not len(point_ids) or not len(candidates):
            return (*empty[:2], point_ids)
        level = predict_level(map_.max_distance[point_ids], distance, tc.scale_factor, tc.n_levels)
        radius = th * np.where(view_cos > 0.998, 2.5, 4.0) * tc.scale_factor**level
        right = uv[:, 0] - tc.baseline_fx / pc[:, 2]
        if kernels.compiled():
            from depotbench.slam.kernels import matching

            args = (point_ids, uv, radius, level, right, features, candidates)
            kps, rows = matching.local_pairs(self, map_, *args)
            return kps, point_ids[rows], point_ids
        rows, kps, kp_level = square_pairs(features, candidates, uv, radius, level, LOCAL_NEIGHBOURS)
        kp_right = features.right_px(tc.baseline_fx)[kps]
        fits = np.isnan(kp_right) | (np.abs(right[rows] - kp_right) <= radius[rows])
        rows, kps, kp_level = rows[fits], kps[fits], kp_level[fits]
        if not len(rows):
            return (*empty[:2], point_ids)
        dist = hamming(map_.descriptors[point_ids[rows]], features.descriptors[kps])
        order = np.lexsort((dist, rows))
        rows, kps, kp_level, dist = rows[order], kps[order], kp_level[order], dist[order]
        first = np.r_[True, np.diff(rows) != 0]
        best = np.flatnonzero(first)
        has_second = np.r_[best[1:], len(rows)] - best > 1
        second = np.where(has_second, best + 1, best)
        ambiguous = (
            has_second & (kp_level[second] == kp_level[best]) & (dist[best] > LOCAL_RATIO * dist[second])
        )
        best = best[(dist[best] <= self.tc.match_max_hamming) & ~ambiguous]
        # One point per keypoint: the closest descriptor.
        order = np.lexsort((dist[best], kps[best]))
        best = best[order[np.r_[True, np.diff(kps[best][order]) != 0]]] if len(best) else best
        return kps[best], point_ids[rows[best]], point_ids

    def search_keyframe(
        self,
        map_: Map,
        keyframe_point_ids: np.ndarray,
        keyframe_angles: np.ndarray,
        features: FrameFeatures,
        usable: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """ORB-SLAM's SearchByBoW(keyframe, frame) as TrackReferenceKeyFrame runs it
        (ORBmatcher(0.7, true)), without the vocabulary: each usable keypoint's closest point
        of the keyframe, within TH_LOW (50) and under 0.7 times the second closest, one
        keypoint per point, then the rotation-consistency check against the keyframe's
        keypoint angles. Returns (keypoints, point ids)."""
        candidates = np.flatnonzero(usable)
        alive = map_.alive[keyframe_point_ids]
        point_ids, angles = keyframe_point_ids[alive], keyframe_angles[alive]
        if len(point_ids) < 2 or not len(candidates):
            return _EMPTY, _EMPTY
        distances = _hamming_matrix(features.descriptors[candidates], map_.descriptors[point_ids])
        two = np.partition(distances, 1, axis=1)[:, :2]
        best = np.argmin(distances, axis=1)
        good = (two[:, 0] <= TH_LOW) & (two[:, 0] < REFERENCE_RATIO * two[:, 1])
        kp, slot, dist = candidates[good], best[good], two[good, 0]
        order = np.lexsort((dist, slot))
        first = order[np.r_[True, np.diff(slot[order]) != 0]] if len(order) else order
        kp, slot = kp[first], slot[first]
        if len(kp):
            keep = consistent_rotation(features.angles_deg[kp] - angles[slot])
            kp, slot = kp[keep], slot[keep]
        return kp, point_ids[slot]

    def search_by_descriptor(
        self, map_: Map, features: FrameFeatures, candidates: np.ndarray, point_ids: np.ndarray, ratio: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Matches (keypoint indices, point ids) of ``candidates`` against every one of
        ``point_ids`` by descriptor alone: the nearest within ``match_max_hamming`` and under
        ``ratio`` times the second nearest; one keypoint per point (the first found)."""
        distances = _hamming_matrix(features.descriptors[candidates], map_.descriptors[point_ids])
        if distances.shape[1] < 2:
            return _EMPTY, _EMPTY
        two = np.partition(distances, 1, axis=1)[:, :2]
        best = np.argmin(distances, axis=1)
        good = (two[:, 0] <= self.tc.match_max_hamming) & (two[:, 0] < ratio * two[:, 1])
        kp, pid = candidates[good], point_ids[best[good]]
        _, unique = np.unique(pid, return_index=True)
        return kp[unique], pid[unique]


def _hamming_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``hamming_matrix`` on the path ``DEPOTBENCH_KERNELS`` picks (compiled: 50x sooner)."""
    if kernels.compiled():
        from depotbench.slam.kernels import matching

        return matching.hamming_matrix(a, b)
    return hamming_matrix(a, b)


TH_LOW = 50
"""ORB-SLAM's TH_LOW: the largest descriptor distance of a fusion or a triangulation match."""
FUSE_RADIUS = 3.0
"""ORB-SLAM's Fuse searches th = 3 px times the predicted level's scale around a projection."""
CHI2_FUSE_STEREO, CHI2_FUSE_MONO = 7.8, 5.99
"""Fuse's reprojection gates on (u, v, u_r) and on (u, v), in units of the level's sigma^2."""
EPIPOLAR_CHI2 = 3.84
"""SearchForTriangulation keeps a pair within sqrt(3.84) sigma of its epipolar line (1 dof, 95 %)."""


def predict_level(
    max_distance: np.ndarray, distance: np.ndarray, scale_factor: float, n_levels: int
) -> np.ndarray:
    """ORB-SLAM's MapPoint::PredictScale: the pyramid level a point at ``distance`` should be
    detected at, ceil(log_scale(max_distance / distance)), within [0, n_levels - 1]."""
    ratio = max_distance / np.maximum(distance, 1e-12)
    level = np.ceil(np.log(np.maximum(ratio, 1e-12)) / np.log(scale_factor))
    return np.clip(level, 0, n_levels - 1).astype(int)


def points_in_view(
    map_: Map, point_ids: np.ndarray, camera_from_world: np.ndarray, camera: Intrinsics
) -> tuple[np.ndarray, ...]:
    """Frame::isInFrustum, which the local-map search and Fuse share: the points that project
    in front of the camera into the image, within their distance range (0.8 min .. 1.2 max),
    seen less than 60 degrees off their normal. Returns (point ids, camera-frame positions,
    projections, distances, viewing cosines) of those."""
    pw = map_.positions[point_ids]
    pc = transform(camera_from_world, pw)
    front = pc[:, 2] > 0
    point_ids, pw, pc = point_ids[front], pw[front], pc[front]
    uv = project(camera, pc)
    offset = pw - invert(camera_from_world)[:3, 3]
    distance = np.linalg.norm(offset, axis=1)
    view_cos = np.einsum("ij,ij->i", offset, map_.normals[point_ids]) / np.maximum(distance, 1e-12)
    in_view = (
        (uv[:, 0] >= 0)
        & (uv[:, 0] < camera.width)
        & (uv[:, 1] >= 0)
        & (uv[:, 1] < camera.height)
        & (distance >= 0.8 * map_.min_distance[point_ids])
        & (distance <= 1.2 * map_.max_distance[point_ids])
        & (view_cos >= VIEWING_COS_LIMIT)
    )
    return point_ids[in_view], pc[in_view], uv[in_view], distance[in_view], view_cos[in_view]


def fuse_candidates(
    tc: TrackingConfig,
    camera: Intrinsics,
    map_: Map,
    point_ids: np.ndarray,
    camera_from_world: np.ndarray,
    features: FrameFeatures,
    usable: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM's ORBmatcher::Fuse without the map changes: for each map point the keypoint it
    would be fused with, (point ids, keypoints). A point qualifies when it projects in front of
    the camera into the image, within its distance range (0.8 min .. 1.2 max), seen less than
    60 degrees off its normal; the keypoint lies within 3 px times the predicted level's scale
    (a square, as GetFeaturesInArea), at the predicted level or one finer, with a
    reprojection error under chi-square 7.8 with depth (5.99 without) in sigma units, and the
    descriptor closest to the point's within TH_LOW (50)."""
    empty = (_EMPTY, _EMPTY)
    point_ids = point_ids[map_.alive[point_ids]]
    candidates = np.flatnonzero(usable)
    if not len(point_ids) or not len(candidates):
        return empty
    point_ids, pc, uv, distance, _ = points_in_view(map_, point_ids, camera_from_world, camera)
    if not len(point_ids):
        return empty
    level = predict_level(map_.max_distance[point_ids], distance, tc.scale_factor, tc.n_levels)
    radius = FUSE_RADIUS * tc.scale_factor**level
    right = uv[:, 0] - tc.baseline_fx / pc[:, 2]
    if kernels.compiled():
        from depotbench.slam.kernels import matching

        args = (point_ids, uv, radius, level, right, features, candidates)
        rows, kps = matching.fuse_pairs(tc, map_, *args, (CHI2_FUSE_STEREO, CHI2_FUSE_MONO), TH_LOW)
        return point_ids[rows], kps
    rows, kps, kp_level = square_pairs(features, candidates, uv, radius, level, NEIGHBOURS)
    err = features.undistorted_px[kps] - uv[rows]
    e2 = np.einsum("ij,ij->i", err, err)
    ur_measured = features.right_px(tc.baseline_fx)[kps]
    stereo = ~np.isnan(ur_measured)
    e2 = e2 + np.where(stereo, (ur_measured - right[rows]) ** 2, 0.0)
    inv_sigma2 = tc.scale_factor ** (-2.0 * kp_level)
    good = e2 * inv_sigma2 <= np.where(stereo, CHI2_FUSE_STEREO, CHI2_FUSE_MONO)
    rows, kps = rows[good], kps[good]
    if not len(rows):
        return empty
    dist = hamming(map_.descriptors[point_ids[rows]], features.descriptors[kps])
    order = np.lexsort((dist, rows))
    first = order[np.r_[True, np.diff(rows[order]) != 0]]
    first = first[dist[first] <= TH_LOW]
    return point_ids[rows[first]], kps[first]


def search_for_triangulation(
    tc: TrackingConfig,
    camera: Intrinsics,
    features1: FrameFeatures,
    free1: np.ndarray,
    pose1_cw: np.ndarray,
    features2: FrameFeatures,
    free2: np.ndarray,
    pose2_cw: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM's SearchForTriangulation without a vocabulary: pairs (keypoints of 1, of 2)
    among keypoints with no map point (``free1``, ``free2``) whose descriptors are within
    TH_LOW (50) and whose keypoint in 2 lies within sqrt(3.84) sigma of its epipolar line;
    where neither has depth, a keypoint in 2 closer than 10 px x scale to the epipole is
    refused. Each keypoint pairs once: the closest descriptor of 1's candidates, then of 2's.
    (ORB-SLAM first narrows the candidates to one vocabulary node; here every keypoint is
    a candidate and the epipolar test does the narrowing.)"""
    idx1, idx2 = np.flatnonzero(free1), np.flatnonzero(free2)
    if not len(idx1) or not len(idx2):
        return _EMPTY, _EMPTY
    k_inv = np.linalg.inv(camera.matrix)
    r21 = pose2_cw[:3, :3] @ pose1_cw[:3, :3].T
    t21 = pose2_cw[:3, 3] - r21 @ pose1_cw[:3, 3]
    skew = np.array([[0, -t21[2], t21[1]], [t21[2], 0, -t21[0]], [-t21[1], t21[0], 0]])
    fundamental = k_inv.T @ skew @ r21 @ k_inv  # x2^T F x1 = 0
    px1, px2 = features1.undistorted_px[idx1], features2.undistorted_px[idx2]
    sigma2 = tc.scale_factor ** (2.0 * features2.octaves[idx2])
    # The epipole in image 2 (camera 1's centre seen from 2); behind camera 2 it tests nothing.
    center1 = -pose1_cw[:3, :3].T @ pose1_cw[:3, 3]
    epipole_c = pose2_cw[:3, :3] @ center1 + pose2_cw[:3, 3]
    near = np.zeros(len(idx2), bool)
    if epipole_c[2] > 1e-9:
        epipole = camera.matrix[:2, :2] @ (epipole_c[:2] / epipole_c[2]) + camera.matrix[:2, 2]
        near = np.sum((px2 - epipole) ** 2, axis=1) < 100 * tc.scale_factor ** features2.octaves[idx2]
    args = (
        fundamental,
        np.ascontiguousarray(px1),
        np.ascontiguousarray(px2),
        sigma2,
        near,
        features1.depth_m[idx1] <= 0,
        features2.depth_m[idx2] <= 0,
        np.ascontiguousarray(features1.descriptors[idx1]),
        np.ascontiguousarray(features2.descriptors[idx2]),
        EPIPOLAR_CHI2,
        TH_LOW,
    )
    if kernels.compiled():
        from depotbench.slam.kernels import matching

        rows, cols = matching.pair_triangulation(*args)
    else:
        rows, cols = triangulation_pairs(*args)
    return idx1[rows], idx2[cols]


def triangulation_pairs(
    fundamental: np.ndarray,
    px1: np.ndarray,
    px2: np.ndarray,
    sigma2: np.ndarray,
    near: np.ndarray,
    no_depth1: np.ndarray,
    no_depth2: np.ndarray,
    descriptors1: np.ndarray,
    descriptors2: np.ndarray,
    chi2: float,
    max_hamming: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The pairing of ``search_for_triangulation`` (rows of 1, rows of 2; ascending in 2): a pair
    lies within ``chi2`` sigma^2 of its epipolar line, is not ``near`` the epipole in 2 where
    neither keypoint has depth, and its descriptors are within ``max_hamming``; each keypoint
    of 1 takes its closest descriptor (the lower row of 2 among equals), then each of 2 keeps
    the closest of those (the lower row of 1). The line and distance are written term by term
    (no matrix product, whose summation order BLAS chooses) so the compiled kernel's
    arithmetic is the same to the bit."""
    f = fundamental
    u1, v1 = px1[:, 0, None], px1[:, 1, None]
    a = f[0, 0] * u1 + f[0, 1] * v1 + f[0, 2]
    b = f[1, 0] * u1 + f[1, 1] * v1 + f[1, 2]
    c = f[2, 0] * u1 + f[2, 1] * v1 + f[2, 2]
    num = a * px2[None, :, 0] + b * px2[None, :, 1] + c
    den = a * a + b * b
    close = num * num < chi2 * sigma2[None, :] * den
    close &= ~(no_depth1[:, None] & no_depth2[None, :] & near[None, :])
    rows, cols = np.nonzero(close)
    if not len(rows):
        return _EMPTY, _EMPTY
    dist = hamming(descriptors1[rows], descriptors2[cols])
    good = dist <= max_hamming
    rows, cols, dist = rows[good], cols[good], dist[good]
    order = np.lexsort((dist, rows))
    best = order[np.r_[True, np.diff(rows[order]) != 0]] if len(order) else order
    order = np.lexsort((dist[best], cols[best]))
    best = best[order[np.r_[True, np.diff(cols[best][order]) != 0]]] if len(order) else best
    return rows[best], cols[best]
