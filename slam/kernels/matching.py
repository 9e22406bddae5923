"""Compiled searches by projection: ``Matcher.search_by_projection`` and the pairing of
``Matcher.search_local_points``, each as one loop.

The reference builds a k-d tree of the usable keypoints per call, queries the 8 nearest within
the search radius of each projected map point, and pairs them by Hamming distance with two
lexsorts. Here the keypoints go into a grid of radius-sized cells and each point scans the
cells around it for its 8 nearest, its best keypoint and then each keypoint's best point,
with the reference's tie rules: the nearer keypoint wins an equal Hamming distance, the lower
point index an equal claim on a keypoint. The one order the reference leaves unspecified is
that of two keypoints at exactly the same distance (the k-d tree's); here the lower keypoint
index comes first.

``search_by_projection`` takes and returns what the method does, the matcher first
(``depotbench.slam.matcher.Matcher`` calls it when ``DEPOTBENCH_KERNELS`` says numba).
``local_pairs`` is the part of ``search_local_points`` after its in-view test: the same square
(Chebyshev) window of 32 nearest keypoints, level window, right-image check, 0.8 ratio test at
one level and one point per keypoint, with the same tie rules.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from depotbench.core.jit import jit
from depotbench.slam.geometry import POPCOUNT, project, transform

NEIGHBOURS = 8
"""As ``matcher.NEIGHBOURS``: keypoints within the radius considered per point, nearest first."""
LOCAL_NEIGHBOURS = 32
"""As ``matcher.LOCAL_NEIGHBOURS``: keypoints of the local search's square considered per point."""
LOCAL_RATIO = 0.8
"""As ``matcher.LOCAL_RATIO``: the ratio test of the local search, between matches at one level."""
ROTATION_BINS = 30
"""As ``matcher.ROTATION_BINS``: the 3 most common of 30 keypoint-angle changes are kept."""

_EMPTY = np.zeros(0, int)


@jit
def consistent_rotation(delta_deg: np.ndarray) -> np.ndarray:
    """``matcher.consistent_rotation``: matches in the 3 most common angle-change bins."""
    bins = (np.mod(delta_deg, 360.0) / (360.0 / ROTATION_BINS)).astype(np.int64) % ROTATION_BINS
    counts = np.zeros(ROTATION_BINS, np.int64)
    for b in bins:
        counts[b] += 1
    # the 3 largest counts, the lower bin first among equals (a stable sort's order)
    keep = np.zeros(ROTATION_BINS, np.bool_)
    largest = -1
    for _ in range(3):
        top = -1
        for b in range(ROTATION_BINS):
            if not keep[b] and (top < 0 or counts[b] > counts[top]):
                top = b
        if largest < 0:
            largest = counts[top]
        keep[top] = counts[top] >= 0.1 * largest
        if not keep[top]:
            break
    out = np.empty(len(bins), np.bool_)
    for i in range(len(bins)):
        out[i] = keep[bins[i]]
    return out


@jit
def _cell_size(radius: np.ndarray) -> float:
    """The motion model's grid cells, as wide as its smallest search radius (at least 4 px): a
    point scans the cells its own radius covers, where cells of the largest radius (up to
    30 x scale^7 = 107 px when the search widens) made each scan many times wider (0.19 ->
    0.14 ms a call). The local search and Fuse, with radii within ~4x, keep cells of theirs."""
    return max(radius.min(), 4.0)


@jit
def _grid(candidates_px: np.ndarray, cell: float) -> tuple[Any, ...]:
    """Keypoints by grid cell (counting sort; within a cell in candidate order): origin,
    size in cells, each cell's start in ``in_cell``, and ``in_cell``."""
    n_candidates = len(candidates_px)
    x0, y0 = candidates_px[:, 0].min(), candidates_px[:, 1].min()
    nx = int((candidates_px[:, 0].max() - x0) / cell) + 1
    ny = int((candidates_px[:, 1].max() - y0) / cell) + 1
    cell_of = np.empty(n_candidates, np.int64)
    start = np.zeros(nx * ny + 1, np.int64)
    for c in range(n_candidates):
        cx = min(int((candidates_px[c, 0] - x0) / cell), nx - 1)
        cy = min(int((candidates_px[c, 1] - y0) / cell), ny - 1)
        cell_of[c] = cy * nx + cx
        start[cell_of[c] + 1] += 1
    for k in range(nx * ny):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    in_cell = np.empty(n_candidates, np.int64)
    for c in range(n_candidates):
        in_cell[fill[cell_of[c]]] = c
        fill[cell_of[c]] += 1
    return x0, y0, nx, ny, start, in_cell


@jit
def _nearest(
    u: float,
    v: float,
    r: float,
    limit: float,
    chebyshev: bool,
    grid: tuple,
    candidates_px: np.ndarray,
    near: np.ndarray,
    near_distance: np.ndarray,
) -> int:
    """Fill ``near`` with the candidates nearest (u, v), at most ``len(near)``, from the grid
    cells within ``r`` of it: by Chebyshev distance or squared Euclidean distance, under
    ``limit``, in (distance, candidate index) order (``near_distance`` holds the distances).
    Returns how many."""
    x0, y0, nx, ny, start, in_cell, cell = grid
    size = len(near)
    gx0 = max(int(math.floor((u - r - x0) / cell)), 0)
    gx1 = min(int(math.floor((u + r - x0) / cell)), nx - 1)
    gy0 = max(int(math.floor((v - r - y0) / cell)), 0)
    gy1 = min(int(math.floor((v + r - y0) / cell)), ny - 1)
    count = 0
    for gy in range(gy0, gy1 + 1):
        for gx in range(gx0, gx1 + 1):
            k = gy * nx + gx
            for s in range(start[k], start[k + 1]):
                c = in_cell[s]
                dx, dy = candidates_px[c, 0] - u, candidates_px[c, 1] - v
                d = max(abs(dx), abs(dy)) if chebyshev else dx * dx + dy * dy
                if not d < limit:
                    continue
                j = count if count < size else size
                while j > 0 and (near_distance[j - 1] > d or (near_distance[j - 1] == d and near[j - 1] > c)):
                    if j < size:
                        near_distance[j], near[j] = near_distance[j - 1], near[j - 1]
                    j -= 1
                if j < size:
                    near_distance[j], near[j] = d, c
                    count = min(count + 1, size)
    return count


@jit
def _one_per_keypoint(best_kp: np.ndarray, best_distance: np.ndarray, n_keypoints: int) -> tuple:
    """Each keypoint keeps its closest point (the lower row among equals): (keypoints
    ascending, rows)."""
    claim = np.full(n_keypoints, -1, np.int64)
    for i in range(len(best_kp)):
        k = best_kp[i]
        if k >= 0 and (claim[k] < 0 or best_distance[i] < best_distance[claim[k]]):
            claim[k] = i
    n = 0
    for k in range(n_keypoints):
        if claim[k] >= 0:
            n += 1
    keypoints = np.empty(n, np.int64)
    rows = np.empty(n, np.int64)
    n = 0
    for k in range(n_keypoints):
        if claim[k] >= 0:
            keypoints[n], rows[n] = k, claim[k]
            n += 1
    return keypoints, rows


@jit
def pair(
    uv: np.ndarray,
    radius: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    candidates_px: np.ndarray,
    candidates: np.ndarray,
    octaves: np.ndarray,
    point_descriptors: np.ndarray,
    descriptors: np.ndarray,
    max_hamming: int,
    keypoint_angles: np.ndarray,
    point_angles: np.ndarray,
    point_right: np.ndarray,
    keypoint_right: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matches (keypoint indices ascending, point rows) of projected points ``uv``
    (M, 2) and the keypoints ``candidates`` at ``candidates_px``.

    ``low`` and ``high`` (per point, empty for none) bound the keypoint's pyramid level;
    ``point_angles`` (per point, empty for none) turn on the rotation check; ``point_right``
    (per point, empty for none) and ``keypoint_right`` (per keypoint, NaN where its depth is
    not positive: it passes) turn on the depth check: the right-image columns within the
    point's radius."""
    n_points = len(uv)
    r_max = radius.max()
    bound = r_max * r_max
    cell = _cell_size(radius)
    windowed = len(low) > 0
    depth_checked = len(point_right) > 0
    best_kp = np.full(n_points, -1, np.int64)
    best_distance = np.zeros(n_points, np.int64)
    grid = (*_grid(candidates_px, cell), cell)
    near = np.empty(NEIGHBOURS, np.int64)
    near_d2 = np.empty(NEIGHBOURS)
    for i in range(n_points):
        # the cells within this point's radius: nearer keypoints outside it are cut below
        count = _nearest(uv[i, 0], uv[i, 1], radius[i], bound, False, grid, candidates_px, near, near_d2)
        for j in range(count):
            if not math.sqrt(near_d2[j]) <= radius[i]:
                break
            keypoint = candidates[near[j]]
            if windowed and not (low[i] <= octaves[keypoint] <= high[i]):
                continue
            right = keypoint_right[keypoint]
            if depth_checked and not math.isnan(right) and not abs(right - point_right[i]) <= radius[i]:
                continue
            distance = 0
            for b in range(descriptors.shape[1]):
                distance += POPCOUNT[point_descriptors[i, b] ^ descriptors[keypoint, b]]
            if distance <= max_hamming and (best_kp[i] < 0 or distance < best_distance[i]):
                best_kp[i], best_distance[i] = keypoint, distance
    keypoints, rows = _one_per_keypoint(best_kp, best_distance, len(descriptors))
    n = len(keypoints)
    if len(point_angles) and n:
        keep = consistent_rotation(keypoint_angles[keypoints] - point_angles[rows])
        keypoints, rows = keypoints[keep], rows[keep]
    return keypoints, rows


def search_by_projection(
    matcher: Any,
    map_: Any,
    point_ids: np.ndarray,
    camera_from_world: np.ndarray,
    features: Any,
    usable: np.ndarray,
    radius: float | np.ndarray,
    exclude: np.ndarray | None = None,
    reference_angles: np.ndarray | None = None,
    octave_window: tuple[np.ndarray, np.ndarray] | None = None,
    depth_check: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``Matcher.search_by_projection`` (``matcher`` is its ``self``: its settings and camera)
    with the pairing compiled: the same matches in the same order, and the same ids that
    projected into the image. ``depth_check`` refuses a keypoint with depth whose right-image
    column (u - bf / depth) lies farther than the radius from the point's projected one."""
    tc, camera = matcher.tc, matcher.camera
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
    front = pc[:, 2] > tc.min_depth_m
    point_ids, pc = point_ids[front], pc[front]
    angles = None if angles is None else angles[front]
    per_point = {k: v[front] for k, v in per_point.items()}
    uv = project(camera, pc)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    point_ids, uv = point_ids[inside], uv[inside]
    angles = None if angles is None else angles[inside]
    per_point = {k: v[inside] for k, v in per_point.items()}
    if len(point_ids) == 0:
        return empty
    none = np.zeros(0, np.int64)
    point_right = keypoint_right = np.zeros(0)
    if depth_check:
        point_right = np.ascontiguousarray(uv[:, 0] - tc.baseline_fx / pc[inside, 2], np.float64)
        keypoint_right = features.right_px(tc.baseline_fx)
    keypoints, rows = pair(
        np.ascontiguousarray(uv, np.float64),
        np.ascontiguousarray(per_point["radius"], np.float64),
        np.ascontiguousarray(per_point["low"], np.int64) if octave_window is not None else none,
        np.ascontiguousarray(per_point["high"], np.int64) if octave_window is not None else none,
        np.ascontiguousarray(features.undistorted_px[candidates], np.float64),
        candidates.astype(np.int64),
        np.ascontiguousarray(features.octaves, np.int64),
        np.ascontiguousarray(map_.descriptors[point_ids]),
        np.ascontiguousarray(features.descriptors),
        int(tc.match_max_hamming),
        np.ascontiguousarray(features.angles_deg, np.float64),
        np.ascontiguousarray(angles, np.float64) if angles is not None else np.zeros(0),
        point_right,
        keypoint_right,
    )
    if len(keypoints) == 0:
        return (*empty[:2], point_ids)
    return keypoints, point_ids[rows], point_ids


@jit
def pair_local(
    uv: np.ndarray,
    radius: np.ndarray,
    level: np.ndarray,
    right: np.ndarray,
    candidates_px: np.ndarray,
    candidates: np.ndarray,
    octaves: np.ndarray,
    point_descriptors: np.ndarray,
    descriptors: np.ndarray,
    max_hamming: int,
    keypoint_right: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matches (keypoint indices ascending, point rows) of the local search.

    Per point: the ``LOCAL_NEIGHBOURS`` keypoints nearest its projection (Chebyshev distance
    under its radius, the lower candidate index first among equals), at its predicted level
    or one finer, whose right-image column (``keypoint_right``, NaN without depth: it
    passes) lies within the radius of the point's; the closest descriptor wins within
    ``max_hamming`` unless the second closest is at the same level and the best is not under
    0.8 times it; then each keypoint keeps its closest point (the lower row among equals)."""
    n_points = len(uv)
    cell = max(radius.max(), 1.0)
    grid = (*_grid(candidates_px, cell), cell)
    best_kp = np.full(n_points, -1, np.int64)
    best_distance = np.zeros(n_points, np.int64)
    near = np.empty(LOCAL_NEIGHBOURS, np.int64)
    near_gap = np.empty(LOCAL_NEIGHBOURS)
    for i in range(n_points):
        r = radius[i]
        count = _nearest(uv[i, 0], uv[i, 1], r, r, True, grid, candidates_px, near, near_gap)
        d1, d2, level1, level2, kp1 = -1, -1, -1, -1, -1
        for j in range(count):
            keypoint = candidates[near[j]]
            octave = octaves[keypoint]
            if not (level[i] - 1 <= octave <= level[i]):
                continue
            kr = keypoint_right[keypoint]
            if not math.isnan(kr) and not abs(right[i] - kr) <= r:
                continue
            distance = 0
            for b in range(descriptors.shape[1]):
                distance += POPCOUNT[point_descriptors[i, b] ^ descriptors[keypoint, b]]
            if kp1 < 0 or distance < d1:
                d2, level2 = d1, level1
                d1, level1, kp1 = distance, octave, keypoint
            elif d2 < 0 or distance < d2:
                d2, level2 = distance, octave
        if kp1 < 0 or d1 > max_hamming:
            continue
        if d2 >= 0 and level2 == level1 and d1 > LOCAL_RATIO * d2:
            continue
        best_kp[i], best_distance[i] = kp1, d1
    return _one_per_keypoint(best_kp, best_distance, len(descriptors))


def _window(
    uv: np.ndarray,
    radius: np.ndarray,
    level: np.ndarray,
    right: np.ndarray,
    features: Any,
    candidates: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """The arrays the local search and Fuse kernels take first, typed as they compile: the
    points' projections, radii, predicted levels and right columns, the candidates'
    positions and indices, every keypoint's level."""
    return (
        np.ascontiguousarray(uv, np.float64),
        np.ascontiguousarray(radius, np.float64),
        np.ascontiguousarray(level, np.int64),
        np.ascontiguousarray(right, np.float64),
        np.ascontiguousarray(features.undistorted_px[candidates], np.float64),
        candidates.astype(np.int64),
        np.ascontiguousarray(features.octaves, np.int64),
    )


def local_pairs(
    matcher: Any,
    map_: Any,
    point_ids: np.ndarray,
    uv: np.ndarray,
    radius: np.ndarray,
    level: np.ndarray,
    right: np.ndarray,
    features: Any,
    candidates: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``Matcher.search_local_points``' pairing compiled: (keypoints, rows of ``point_ids``),
    the same matches in the same order as the NumPy path. The arguments are what that method
    computed for the points in view: projections, radii, predicted levels, right columns."""
    tc = matcher.tc
    return pair_local(
        *_window(uv, radius, level, right, features, candidates),
        np.ascontiguousarray(map_.descriptors[point_ids]),
        np.ascontiguousarray(features.descriptors),
        int(tc.match_max_hamming),
        features.right_px(tc.baseline_fx),
    )


@jit
def pair_fuse(
    uv: np.ndarray,
    radius: np.ndarray,
    level: np.ndarray,
    right: np.ndarray,
    candidates_px: np.ndarray,
    candidates: np.ndarray,
    octaves: np.ndarray,
    keypoint_right: np.ndarray,
    inv_sigma2: np.ndarray,
    point_descriptors: np.ndarray,
    descriptors: np.ndarray,
    chi2_stereo: float,
    chi2_mono: float,
    max_hamming: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Fuse's pairs (point rows ascending, keypoints): per point, of the ``NEIGHBOURS`` keypoints
    nearest its projection (Chebyshev distance under its radius, the lower candidate index
    first among equals) at its predicted level or one finer whose reprojection error passes
    the chi-square gate (``keypoint_right`` NaN without depth: the (u, v) gate, else (u, v,
    u_r)), the one with the closest descriptor (the nearer among equals) within
    ``max_hamming``."""
    n_points = len(uv)
    cell = max(radius.max(), 1.0)
    grid = (*_grid(candidates_px, cell), cell)
    rows = np.empty(n_points, np.int64)
    keypoints = np.empty(n_points, np.int64)
    n = 0
    near = np.empty(NEIGHBOURS, np.int64)
    near_gap = np.empty(NEIGHBOURS)
    for i in range(n_points):
        u, v, r = uv[i, 0], uv[i, 1], radius[i]
        count = _nearest(u, v, r, r, True, grid, candidates_px, near, near_gap)
        best, best_distance = -1, 0
        for j in range(count):
            c = near[j]
            keypoint = candidates[c]
            octave = octaves[keypoint]
            if not (level[i] - 1 <= octave <= level[i]):
                continue
            dx, dy = candidates_px[c, 0] - u, candidates_px[c, 1] - v
            e2 = dx * dx + dy * dy
            kr = keypoint_right[keypoint]
            stereo = not math.isnan(kr)
            if stereo:
                e2 = e2 + (kr - right[i]) ** 2
            if not e2 * inv_sigma2[octave] <= (chi2_stereo if stereo else chi2_mono):
                continue
            distance = 0
            for b in range(descriptors.shape[1]):
                distance += POPCOUNT[point_descriptors[i, b] ^ descriptors[keypoint, b]]
            if best < 0 or distance < best_distance:
                best, best_distance = keypoint, distance
        if best >= 0 and best_distance <= max_hamming:
            rows[n], keypoints[n] = i, best
            n += 1
    return rows[:n], keypoints[:n]


def fuse_pairs(
    tc: Any,
    map_: Any,
    point_ids: np.ndarray,
    uv: np.ndarray,
    radius: np.ndarray,
    level: np.ndarray,
    right: np.ndarray,
    features: Any,
    candidates: np.ndarray,
    chi2: tuple[float, float],
    max_hamming: int,
) -> tuple[np.ndarray, np.ndarray]:
    """``matcher.fuse_candidates``' pairing compiled: (rows of ``point_ids``, keypoints), the
    same pairs in the same order as the NumPy path, from what it computed for the points in
    view (projections, radii, predicted levels, projected right columns)."""
    return pair_fuse(
        *_window(uv, radius, level, right, features, candidates),
        features.right_px(tc.baseline_fx),
        tc.scale_factor ** (-2.0 * np.arange(tc.n_levels)),
        np.ascontiguousarray(map_.descriptors[point_ids]),
        np.ascontiguousarray(features.descriptors),
        float(chi2[0]),
        float(chi2[1]),
        int(max_hamming),
    )


@jit
def pair_triangulation(
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
    """``matcher.triangulation_pairs`` as one loop over the pairs: the same pairs in the same
    order (ascending in 2), with its arithmetic term by term."""
    f = fundamental
    n1, n2 = len(px1), len(px2)
    best2 = np.full(n1, -1, np.int64)
    best_distance = np.zeros(n1, np.int64)
    for i in range(n1):
        u1, v1 = px1[i, 0], px1[i, 1]
        a = f[0, 0] * u1 + f[0, 1] * v1 + f[0, 2]
        b = f[1, 0] * u1 + f[1, 1] * v1 + f[1, 2]
        c = f[2, 0] * u1 + f[2, 1] * v1 + f[2, 2]
        den = a * a + b * b
        for j in range(n2):
            num = a * px2[j, 0] + b * px2[j, 1] + c
            if not num * num < chi2 * sigma2[j] * den:
                continue
            if no_depth1[i] and no_depth2[j] and near[j]:
                continue
            distance = 0
            for k in range(descriptors1.shape[1]):
                distance += POPCOUNT[descriptors1[i, k] ^ descriptors2[j, k]]
            if distance <= max_hamming and (best2[i] < 0 or distance < best_distance[i]):
                best2[i], best_distance[i] = j, distance
    cols, rows = _one_per_keypoint(best2, best_distance, n2)  # the lower row among equals
    return rows, cols


SORTED_MEDIAN_MAX = 24
"""``distinctive`` sorts a row of up to 24 distances (n^2 steps) and counts the others into a
histogram of the 257 possible distances (n + 257): at TUM's length a point is seen by up to
~200 keyframes, where sorting every row cost n^3 (14 of a walking sequence's 180 s)."""


_M1, _M2, _M4 = np.uint64(0x5555555555555555), np.uint64(0x3333333333333333), np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)
_S1, _S2, _S4, _S56 = np.uint64(1), np.uint64(2), np.uint64(4), np.uint64(56)
"""The bit counts of a 64-bit word in six steps (the compiler turns them into one popcount)."""


@jit
def _popcount(x: np.uint64) -> np.uint64:
    x = x - ((x >> _S1) & _M1)
    x = (x & _M2) + ((x >> _S2) & _M2)
    x = (x + (x >> _S4)) & _M4
    return (x * _H01) >> _S56


@jit
def _hamming_words(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty((a.shape[0], b.shape[0]), np.int32)
    for i in range(a.shape[0]):
        for j in range(b.shape[0]):
            total = np.uint64(0)
            for k in range(a.shape[1]):
                total += _popcount(a[i, k] ^ b[j, k])
            out[i, j] = np.int32(total)
    return out


def hamming_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``geometry.hamming_matrix``: all-pairs Hamming distances (len(a), len(b)), int32, of
    (N, 32) uint8 descriptors, each read as four 64-bit words. Relocalisation matches every
    keypoint against a candidate keyframe's points by descriptor alone (1,000 x 500 pairs):
    0.8 ms against NumPy's 40 (a lookup table over a 16 MB array of byte differences), the
    same integers."""
    words = a.shape[1] // 8
    return _hamming_words(
        np.ascontiguousarray(a).view(np.uint64).reshape(len(a), words),
        np.ascontiguousarray(b).view(np.uint64).reshape(len(b), words),
    )


@jit
def distinctive(values: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """``map.distinctive``: per point, the index within its descriptors (``values[starts[p]:
    starts[p] + counts[p]]``) of the one with the least lower-median Hamming distance to the
    others, the first on a tie; -1 below two descriptors. Integers: equal to NumPy's."""
    best = np.full(len(counts), -1)
    largest = 0
    for p in range(len(counts)):
        largest = max(largest, counts[p])
    distances = np.zeros((largest, largest), np.int64)
    row = np.empty(largest, np.int64)
    histogram = np.zeros(8 * values.shape[1] + 1, np.int64)  # a distance is 0..bits
    for p in range(len(counts)):
        n, first = counts[p], starts[p]
        if n < 2:
            continue
        for i in range(n):
            distances[i, i] = 0
            for j in range(i + 1, n):
                total = 0
                for b in range(values.shape[1]):
                    total += POPCOUNT[values[first + i, b] ^ values[first + j, b]]
                distances[i, j] = total
                distances[j, i] = total
        lowest = -1
        rank = (n - 1) // 2
        for i in range(n):
            if n <= SORTED_MEDIAN_MAX:
                for j in range(n):  # insertion sort in place
                    value = distances[i, j]
                    k = j
                    while k > 0 and row[k - 1] > value:
                        row[k] = row[k - 1]
                        k -= 1
                    row[k] = value
                median = row[rank]
            else:  # counted: the value whose cumulative count first passes the rank
                histogram[:] = 0
                for j in range(n):
                    histogram[distances[i, j]] += 1
                median, below = 0, histogram[0]
                while below <= rank:
                    median += 1
                    below += histogram[median]
            if lowest < 0 or median < lowest:
                lowest = median
                best[p] = i
    return best
