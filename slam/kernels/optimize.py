"""Compiled pose refinement and local bundle adjustment (``depotbench.slam.optimize`` and
``depotbench.slam.bundle``), with pose refinement's small dense solve.

Pose refinement: each Gauss-Newton step accumulates the 6x6 normal equations point by point
(residual, analytic Jacobian, Huber weight) instead of building (N, 3, 6) arrays; the rounds,
the outlier tests and the stopping rule are the reference's, line for line. The reference
runs ~12 steps per call and ~15 NumPy operations per step, ~10 us each whatever N.

Local bundle adjustment: the reference builds (N, 9, 9) per-observation blocks, sums them with
sparse products and forms the reduced camera system through a dense (points, 6 x free
poses, 3) array; here each observation adds its blocks where they belong and each point adds
W V^-1 W^T for the pairs of free keyframes that see it. The 3x3 point blocks are inverted in
closed form (the reference calls LAPACK per point).

Pose refinement's 6x6 solve is Gaussian elimination with partial pivoting in LAPACK's
unblocked order (the largest pivot in the column, the first of equals): ``numpy.linalg.solve``
compiled by Numba cost ~5 s of compile time in each kernel calling it. Local BA's reduced
system (6 x up to ~200 free keyframes at TUM's length) is solved by LAPACK's Cholesky
between two kernels (``depotbench.slam.bundle``).
Every kernel that calls another lives in this file: Numba's cache checks only the file of the
kernel it loads, so a callee edited in another file would go on running from its callers'
caches.
"""

from __future__ import annotations

import math

import numpy as np
from depotbench.core.jit import jit

EPSILON = 2.220446049250313e-16
"""DBL_EPSILON: below it OpenCV's Rodrigues returns the identity."""


# -- the dense solve -------------------------------------------------------------------------


@jit
def solve(matrix: np.ndarray, rhs: np.ndarray) -> tuple[bool, np.ndarray]:
    """(solved, x) with ``matrix @ x = rhs``; not solved where a pivot is exactly zero or the
    input is not finite (where NumPy raises ``LinAlgError`` or returns NaN)."""
    n = len(rhs)
    a = matrix.copy()
    x = rhs.copy()
    if not (np.isfinite(a).all() and np.isfinite(x).all()):
        return False, x
    for k in range(n):
        pivot = k
        for i in range(k + 1, n):
            if abs(a[i, k]) > abs(a[pivot, k]):
                pivot = i
        if a[pivot, k] == 0.0:
            return False, x
        if pivot != k:
            for j in range(n):
                a[k, j], a[pivot, j] = a[pivot, j], a[k, j]
            x[k], x[pivot] = x[pivot], x[k]
        inverse = 1.0 / a[k, k]
        for i in range(k + 1, n):
            factor = a[i, k] * inverse
            a[i, k] = factor
            for j in range(k + 1, n):
                a[i, j] -= factor * a[k, j]
            x[i] -= factor * x[k]
    for k in range(n - 1, -1, -1):
        total = x[k]
        for j in range(k + 1, n):
            total -= a[k, j] * x[j]
        x[k] = total / a[k, k]
    return bool(np.isfinite(x).all()), x


# -- pose refinement ------------------------------------------------------------------------


@jit
def rodrigues(rotvec: np.ndarray) -> np.ndarray:
    """The rotation matrix of a rotation vector, by OpenCV's formula (``cv2.Rodrigues``)."""
    out = np.eye(3)
    theta = math.sqrt(rotvec[0] * rotvec[0] + rotvec[1] * rotvec[1] + rotvec[2] * rotvec[2])
    if theta < EPSILON:
        return out
    c, s = math.cos(theta), math.sin(theta)
    c1 = 1.0 - c
    inverse = 1.0 / theta
    x, y, z = rotvec[0] * inverse, rotvec[1] * inverse, rotvec[2] * inverse
    # c I + c1 r r^T + s [r]x, each entry summed in OpenCV's order
    out[0, 0], out[0, 1], out[0, 2] = c + c1 * (x * x), c1 * (x * y) - s * z, c1 * (x * z) + s * y
    out[1, 0], out[1, 1], out[1, 2] = c1 * (x * y) + s * z, c + c1 * (y * y), c1 * (y * z) - s * x
    out[2, 0], out[2, 1], out[2, 2] = c1 * (x * z) - s * y, c1 * (y * z) + s * x, c + c1 * (z * z)
    return out


@jit
def exp_se3_left(delta: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """``exp_se3(delta) @ pose`` for a 4x4 rigid ``pose``."""
    rot = rodrigues(delta[:3])
    out = np.zeros((4, 4))
    for i in range(3):
        for j in range(4):
            out[i, j] = rot[i, 0] * pose[0, j] + rot[i, 1] * pose[1, j] + rot[i, 2] * pose[2, j]
        out[i, 3] += delta[3 + i]
    out[3, 3] = 1.0
    return out


@jit
def _residual(
    pose: np.ndarray,
    point: np.ndarray,
    uv: np.ndarray,
    ur: float,
    weight: float,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    bf: float,
    out: np.ndarray,
) -> float:
    """The whitened residual of one observation and the point in the camera, into ``out``
    (6,); returns the camera z."""
    x = pose[0, 0] * point[0] + pose[0, 1] * point[1] + pose[0, 2] * point[2] + pose[0, 3]
    y = pose[1, 0] * point[0] + pose[1, 1] * point[1] + pose[1, 2] * point[2] + pose[1, 3]
    z = pose[2, 0] * point[0] + pose[2, 1] * point[1] + pose[2, 2] * point[2] + pose[2, 3]
    safe_z = 1e-6 if abs(z) < 1e-6 else z
    u = fx * x / safe_z + cx
    v = fy * y / safe_z + cy
    out[0] = (uv[0] - u) * weight
    out[1] = (uv[1] - v) * weight
    out[2] = (ur - (u - bf / safe_z)) * weight if math.isfinite(ur) else 0.0
    out[3], out[4], out[5] = x, y, z
    return z


@jit
def inliers(
    pose: np.ndarray,
    points_w: np.ndarray,
    uv: np.ndarray,
    ur: np.ndarray,
    weight: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    bf: float,
    chi2_stereo: float,
    chi2_mono: float,
) -> np.ndarray:
    """``optimize.is_inlier`` of the points seen from ``pose``."""
    n = len(points_w)
    out = np.zeros(n, np.bool_)
    r = np.empty(6)
    for i in range(n):
        z = _residual(pose, points_w[i], uv[i], ur[i], weight[i], fx, fy, cx, cy, bf, r)
        error = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
        threshold = chi2_stereo if math.isfinite(ur[i]) else chi2_mono
        out[i] = error < threshold and z > 0
    return out


@jit
def refine_pose(
    camera_from_world: np.ndarray,
    points_w: np.ndarray,
    uv: np.ndarray,
    ur: np.ndarray,
    weight: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    bf: float,
    rounds: int,
    iterations: int,
    chi2_stereo: float,
    chi2_mono: float,
    step_tolerance: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``optimize.refine_pose_numpy`` with the camera as numbers and its constants passed in."""
    pose = camera_from_world.copy()
    n = len(points_w)
    active = np.ones(n, np.bool_)
    huber = math.sqrt(chi2_stereo)
    r = np.empty(6)
    jac = np.empty((3, 6))
    for round_index in range(rounds):
        if active.sum() < 3:
            break
        robust = round_index < rounds - 1
        for _ in range(iterations):
            hessian = np.zeros((6, 6))
            gradient = np.zeros(6)
            for i in range(n):
                if not active[i]:
                    continue
                w = weight[i]
                _residual(pose, points_w[i], uv[i], ur[i], w, fx, fy, cx, cy, bf, r)
                x, y, z_raw = r[3], r[4], r[5]
                inv = 1.0 / max(z_raw, 1e-6)
                a0, a2 = fx * inv, -fx * x * inv * inv
                jac[0, 0], jac[0, 1], jac[0, 2] = -a2 * y, a2 * x - a0 * z_raw, a0 * y
                jac[0, 3], jac[0, 4], jac[0, 5] = -a0, 0.0, -a2
                b1, b2 = fy * inv, -fy * y * inv * inv
                jac[1, 0], jac[1, 1], jac[1, 2] = b1 * z_raw - b2 * y, b2 * x, -b1 * x
                jac[1, 3], jac[1, 4], jac[1, 5] = 0.0, -b1, -b2
                rows = 2  # without depth the u_r row is zero (and so is its residual)
                if math.isfinite(ur[i]):
                    rows = 3
                    c2 = a2 + bf * inv * inv
                    jac[2, 0], jac[2, 1], jac[2, 2] = -c2 * y, c2 * x - a0 * z_raw, a0 * y
                    jac[2, 3], jac[2, 4], jac[2, 5] = -a0, 0.0, -c2
                irls = 1.0
                if robust:
                    norm = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
                    if norm > huber:
                        irls = huber / max(norm, 1e-12)
                # the upper triangle of (J w irls)^T (J w), mirrored below
                for k in range(rows):
                    for a in range(6):
                        ja = jac[k, a] * w * irls
                        gradient[a] += ja * r[k]
                        for b in range(a, 6):
                            hessian[a, b] += ja * (jac[k, b] * w)
            for a in range(6):
                hessian[a, a] += 1e-9
                for b in range(a):
                    hessian[a, b] = hessian[b, a]
            solved, step = solve(hessian, gradient)
            if not solved:
                break  # a degenerate start (e.g. a RANSAC pose with points behind it): no step
            delta = -step
            pose = exp_se3_left(delta, pose)
            if math.sqrt(np.sum(delta * delta)) < step_tolerance:
                break
        active = inliers(pose, points_w, uv, ur, weight, fx, fy, cx, cy, bf, chi2_stereo, chi2_mono)
    return pose, active


# -- local bundle adjustment ----------------------------------------------------------------


@jit
def _camera_point(pose: np.ndarray, point: np.ndarray, out: np.ndarray) -> None:
    for i in range(3):
        out[i] = pose[i, 0] * point[0] + pose[i, 1] * point[1] + pose[i, 2] * point[2] + pose[i, 3]


@jit
def camera_points(
    poses: np.ndarray, points: np.ndarray, obs_pose: np.ndarray, obs_point: np.ndarray
) -> np.ndarray:
    """Each observation's point in its keyframe's camera (N, 3)."""
    out = np.empty((len(obs_pose), 3))
    for k in range(len(obs_pose)):
        _camera_point(poses[obs_pose[k]], points[obs_point[k]], out[k])
    return out


@jit
def _whitened(
    pc: np.ndarray,
    measured: np.ndarray,
    stereo: bool,
    weight: float,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    bf: float,
    out: np.ndarray,
) -> None:
    """The whitened residual (3,) of an observation in front of its camera."""
    z = pc[2]
    u = fx * pc[0] / z + cx
    v = fy * pc[1] / z + cy
    out[0] = (measured[0] - u) * weight
    out[1] = (measured[1] - v) * weight
    out[2] = (measured[2] - (u - bf / z)) * weight if stereo else 0.0


@jit
def cost(
    poses: np.ndarray,
    points: np.ndarray,
    obs_pose: np.ndarray,
    obs_point: np.ndarray,
    measured: np.ndarray,
    stereo: np.ndarray,
    weight: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    bf: float,
    huber_k: float,
    min_depth: float,
) -> float:
    """``_Problem.cost``: the Huber cost, plus GTSAM's constant for observations behind their camera."""
    total = 0.0
    behind = 0
    pc = np.empty(3)
    r = np.empty(3)
    for k in range(len(obs_pose)):
        _camera_point(poses[obs_pose[k]], points[obs_point[k]], pc)
        if not pc[2] > min_depth:
            behind += 1
            continue
        _whitened(pc, measured[k], stereo[k], weight[k], fx, fy, cx, cy, bf, r)
        error = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        if error <= huber_k:
            total += 0.5 * (error * error)
        else:
            total += huber_k * error - 0.5 * (huber_k * huber_k)
    return total + 0.5 * (2 * fx) ** 2 * 3 * behind


@jit
def linearise(
    poses: np.ndarray,
    points: np.ndarray,
    obs_pose: np.ndarray,
    obs_point: np.ndarray,
    obs_slot: np.ndarray,
    measured: np.ndarray,
    stereo: np.ndarray,
    weight: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    bf: float,
    huber_k: float,
    min_depth: float,
    n_free: int,
    n_on_free: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``_Problem.linearise``: U (F, 6, 6), its gradient (F, 6), V (P, 3, 3), its gradient
    (P, 3) and W (observations on free poses, 6, 3), Huber-weighted."""
    n_points = len(points)
    u_blocks = np.zeros((n_free, 6, 6))
    g_pose = np.zeros((n_free, 6))
    v_blocks = np.zeros((n_points, 3, 3))
    g_point = np.zeros((n_points, 3))
    w_blocks = np.zeros((n_on_free, 6, 3))
    pc = np.empty(3)
    r = np.empty(3)
    d = np.empty((3, 3))
    jac = np.empty((3, 9))
    hessian = np.empty((9, 9))
    gradient = np.empty(9)
    on_free = -1
    for k in range(len(obs_pose)):
        slot = obs_slot[k]
        if slot >= 0:
            on_free += 1
        pose = poses[obs_pose[k]]
        _camera_point(pose, points[obs_point[k]], pc)
        if not pc[2] > min_depth:
            continue  # the reference weighs it by 0: nothing to add
        _whitened(pc, measured[k], stereo[k], weight[k], fx, fy, cx, cy, bf, r)
        error = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        robust = huber_k / max(error, 1e-12) if error > huber_k else 1.0
        x, y, z = pc[0], pc[1], pc[2]
        inv = 1.0 / z
        w = weight[k]
        d[:] = 0.0
        d[0, 0], d[0, 2] = fx * inv, -fx * x * (inv * inv)
        d[1, 1], d[1, 2] = fy * inv, -fy * y * (inv * inv)
        if stereo[k]:
            d[2, 0], d[2, 2] = d[0, 0], d[0, 2] + bf * (inv * inv)
        for i in range(3):
            for j in range(3):
                d[i, j] *= w
        for i in range(3):
            jac[i, 0] = z * d[i, 1] - y * d[i, 2]
            jac[i, 1] = x * d[i, 2] - z * d[i, 0]
            jac[i, 2] = y * d[i, 0] - x * d[i, 1]
            for j in range(3):
                jac[i, 3 + j] = -d[i, j]
                jac[i, 6 + j] = -(d[i, 0] * pose[0, j] + d[i, 1] * pose[1, j] + d[i, 2] * pose[2, j])
        # J^T robust J, its upper triangle read for both halves (the reference's two halves
        # differ by rounding). Each entry is summed over the three rows in one expression, in
        # the reference's order from 0.0: 1.65x sooner than accumulating entry by entry (1.75
        # against 2.9 ms a call on walking_xyz's local BAs), the same bytes.
        r0, r1, r2 = r[0], r[1], r[2]
        for a in range(9):
            ja0, ja1, ja2 = jac[0, a] * robust, jac[1, a] * robust, jac[2, a] * robust
            gradient[a] = ((0.0 + ja0 * r0) + ja1 * r1) + ja2 * r2
            for b in range(a, 9):
                hessian[a, b] = ((0.0 + ja0 * jac[0, b]) + ja1 * jac[1, b]) + ja2 * jac[2, b]
        point = obs_point[k]
        for a in range(3):
            g_point[point, a] += gradient[6 + a]
            for b in range(3):
                v_blocks[point, a, b] += hessian[6 + min(a, b), 6 + max(a, b)]
        if slot >= 0:
            for a in range(6):
                g_pose[slot, a] += gradient[a]
                for b in range(6):
                    u_blocks[slot, a, b] += hessian[min(a, b), max(a, b)]
                for b in range(3):
                    w_blocks[on_free, a, b] = hessian[a, 6 + b]
    return u_blocks, g_pose, v_blocks, g_point, w_blocks


@jit
def _inverse3(m: np.ndarray, out: np.ndarray) -> None:
    """The inverse of a 3x3 matrix by its adjugate (inf or NaN entries where it is singular)."""
    c00 = m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]
    c01 = m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2]
    c02 = m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]
    det = m[0, 0] * c00 + m[0, 1] * c01 + m[0, 2] * c02
    inv = 1.0 / det
    out[0, 0] = c00 * inv
    out[1, 0] = c01 * inv
    out[2, 0] = c02 * inv
    out[0, 1] = (m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2]) * inv
    out[1, 1] = (m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0]) * inv
    out[2, 1] = (m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1]) * inv
    out[0, 2] = (m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]) * inv
    out[1, 2] = (m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]) * inv
    out[2, 2] = (m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]) * inv


LANES_FROM_PAIRS = 4
"""``reduce`` sums a window's pairs in 36 lanes where its points' observations are in more
than this many pairs each on average (measured crossover: 3.8-4.3)."""


@jit
def _pairs_in_place(
    reduced: np.ndarray,
    rhs_sum: np.ndarray,
    v_inverse: np.ndarray,
    g_point: np.ndarray,
    w_blocks: np.ndarray,
    point_start: np.ndarray,
    point_obs: np.ndarray,
    obs_slot: np.ndarray,
) -> None:
    """-W V^-1 W^T into ``reduced``'s upper triangle and W V^-1 g into ``rhs_sum``, each pair
    of a point's observations written where it lands (small windows)."""
    n_points = len(v_inverse)
    # One point's observations at a time, gathered into small contiguous buffers (its W rows,
    # W V^-1 and slots), which its pair loop then reads k times each: reduce 1.5x sooner on
    # walking_xyz's local BAs (5.5 against 8.3 ms a call).
    most = 0
    for p in range(n_points):
        most = max(most, point_start[p + 1] - point_start[p])
    wv = np.empty((most, 6, 3))
    w_point = np.empty((most, 3, 6))
    slots = np.empty(most, np.int64)
    for p in range(n_points):
        first, k = point_start[p], point_start[p + 1] - point_start[p]
        vi, g = v_inverse[p], g_point[p]
        for i in range(k):
            row = point_obs[first + i]
            slots[i] = obs_slot[row]
            base = 6 * slots[i]
            for a in range(6):
                w0, w1, w2 = w_blocks[row, a, 0], w_blocks[row, a, 1], w_blocks[row, a, 2]
                w_point[i, 0, a], w_point[i, 1, a], w_point[i, 2, a] = w0, w1, w2
                t0 = w0 * vi[0, 0] + w1 * vi[1, 0] + w2 * vi[2, 0]
                t1 = w0 * vi[0, 1] + w1 * vi[1, 1] + w2 * vi[2, 1]
                t2 = w0 * vi[0, 2] + w1 * vi[1, 2] + w2 * vi[2, 2]
                wv[i, a, 0], wv[i, a, 1], wv[i, a, 2] = t0, t1, t2
                rhs_sum[base + a] += t0 * g[0] + t1 * g[1] + t2 * g[2]
        # -W V^-1 W^T over the pairs of free keyframes seeing the point. The observations
        # come in slot order (``point_obs``) and a keyframe sees a point once, so pair
        # (i, j > i) is block (slot i, slot j) above the diagonal and (i, i) the diagonal
        # block's upper triangle: half the scattered writes of the full matrix, no mirror, no copy. W is
        # read transposed (3 x 6), so each block row is six adjacent lanes.
        for i in range(k):
            x = wv[i]
            row0 = 6 * slots[i]
            for a in range(6):
                for b in range(a, 6):
                    reduced[row0 + a, row0 + b] -= (
                        x[a, 0] * w_point[i, 0, b] + x[a, 1] * w_point[i, 1, b] + x[a, 2] * w_point[i, 2, b]
                    )
            for j in range(i + 1, k):
                col0 = 6 * slots[j]
                y = w_point[j]
                if col0 == row0:  # seen twice by one keyframe (never in a map): both products
                    z, w = wv[j], w_point[i]
                    for a in range(6):
                        for b in range(a, 6):
                            reduced[row0 + a, row0 + b] -= (
                                x[a, 0] * y[0, b] + x[a, 1] * y[1, b] + x[a, 2] * y[2, b]
                            ) + (z[a, 0] * w[0, b] + z[a, 1] * w[1, b] + z[a, 2] * w[2, b])
                    continue
                for a in range(6):
                    x0, x1, x2 = x[a, 0], x[a, 1], x[a, 2]
                    for b in range(6):
                        reduced[row0 + a, col0 + b] -= x0 * y[0, b] + x1 * y[1, b] + x2 * y[2, b]


@jit
def _pairs_in_lanes(
    reduced: np.ndarray,
    rhs_sum: np.ndarray,
    v_inverse: np.ndarray,
    g_point: np.ndarray,
    w_blocks: np.ndarray,
    point_start: np.ndarray,
    point_obs: np.ndarray,
    obs_slot: np.ndarray,
) -> None:
    """What ``_pairs_in_place`` adds, each 6x6 block summed as 36 lanes (large windows)."""
    n_points = len(v_inverse)
    n_free = len(reduced) // 6
    # -W V^-1 W^T, summed point by point into S's 6x6 blocks. Each block is kept as 36
    # adjacent numbers (``blocks``, copied into S at the end) and each observation's factors
    # are spread over those 36 lanes once (``xs``: row a of W V^-1 at lanes 6a..6a+5, ``ys``:
    # column b of W^T at lanes b, b+6, ...), so a pair of observations is one loop of 36
    # independent lanes that the compiler vectorises: element (a, b) gets exactly the scalar
    # loop's sum in the same order, the same bytes (9.4 against 13.0 ms a ``reduce`` over 39
    # local BAs of a TUM-length walking_xyz, 5-152 free keyframes).
    blocks = np.zeros((n_free * n_free, 36))
    # The gathering below repeats ``_pairs_in_place``'s arithmetic, writing the lanes' layout
    # in the same pass: a helper shared by both cost 8-13 % of ``reduce`` (measured).
    most = 0
    for p in range(n_points):
        most = max(most, point_start[p + 1] - point_start[p])
    xs = np.empty((most, 3, 36))
    ys = np.empty((most, 3, 36))
    slots = np.empty(most, np.int64)
    for p in range(n_points):
        first, k = point_start[p], point_start[p + 1] - point_start[p]
        vi, g = v_inverse[p], g_point[p]
        for i in range(k):
            row = point_obs[first + i]
            slots[i] = obs_slot[row]
            base = 6 * slots[i]
            for a in range(6):
                w0, w1, w2 = w_blocks[row, a, 0], w_blocks[row, a, 1], w_blocks[row, a, 2]
                t0 = w0 * vi[0, 0] + w1 * vi[1, 0] + w2 * vi[2, 0]
                t1 = w0 * vi[0, 1] + w1 * vi[1, 1] + w2 * vi[2, 1]
                t2 = w0 * vi[0, 2] + w1 * vi[1, 2] + w2 * vi[2, 2]
                rhs_sum[base + a] += t0 * g[0] + t1 * g[1] + t2 * g[2]
                for b in range(6):
                    xs[i, 0, 6 * a + b], xs[i, 1, 6 * a + b], xs[i, 2, 6 * a + b] = t0, t1, t2
                    ys[i, 0, 6 * b + a], ys[i, 1, 6 * b + a], ys[i, 2, 6 * b + a] = w0, w1, w2
        # The observations come in slot order and a keyframe sees a point once, so pair
        # (i, j >= i) is block (slot i, slot j) on or above the diagonal; only the diagonal
        # blocks' upper triangles are copied into S.
        for i in range(k):
            q0 = slots[i] * n_free
            for j in range(i, k):
                q = q0 + slots[j]
                if j > i and slots[j] == slots[i]:  # seen twice by one keyframe (never in a map)
                    for e in range(36):
                        blocks[q, e] -= (
                            xs[i, 0, e] * ys[j, 0, e] + xs[i, 1, e] * ys[j, 1, e] + xs[i, 2, e] * ys[j, 2, e]
                        ) + (
                            xs[j, 0, e] * ys[i, 0, e] + xs[j, 1, e] * ys[i, 1, e] + xs[j, 2, e] * ys[i, 2, e]
                        )
                    continue
                for e in range(36):
                    blocks[q, e] -= (
                        xs[i, 0, e] * ys[j, 0, e] + xs[i, 1, e] * ys[j, 1, e] + xs[i, 2, e] * ys[j, 2, e]
                    )
    for s in range(n_free):
        block = blocks[s * n_free + s]
        for a in range(6):
            for b in range(a, 6):
                reduced[6 * s + a, 6 * s + b] = block[6 * a + b]
        for t in range(s + 1, n_free):
            block = blocks[s * n_free + t]
            for a in range(6):
                for b in range(6):
                    reduced[6 * s + a, 6 * t + b] = block[6 * a + b]


@jit
def reduce(
    u_blocks: np.ndarray,
    g_pose: np.ndarray,
    v_blocks: np.ndarray,
    g_point: np.ndarray,
    w_blocks: np.ndarray,
    damping: float,
    point_start: np.ndarray,
    point_obs: np.ndarray,
    obs_slot: np.ndarray,
) -> tuple[bool, np.ndarray, np.ndarray, np.ndarray]:
    """The damped reduced camera system of ``_Problem.step``: (the points' blocks invertible,
    S (6F, 6F) in its upper triangle (the lower one is left at zero: the Cholesky solve in
    ``depotbench.slam.bundle`` reads only the upper), its right-hand side, the damped V^-1
    (P, 3, 3)).

    The free observations of point p are ``point_obs[point_start[p]:point_start[p + 1]]``
    (rows of ``w_blocks``) in the order of their free slots ``obs_slot``."""
    n_free = len(u_blocks)
    n_points = len(v_blocks)
    size = 6 * n_free
    reduced = np.zeros((size, size))
    rhs = np.empty(size)
    v_inverse = np.empty((n_points, 3, 3))
    damped = np.empty((3, 3))
    for p in range(n_points):
        for a in range(3):
            for b in range(3):
                damped[a, b] = v_blocks[p, a, b] + (damping if a == b else 0.0)
        _inverse3(damped, v_inverse[p])
        if not np.isfinite(v_inverse[p]).all():
            return False, reduced, rhs, v_inverse
    rhs_sum = np.zeros(size)
    # Both orders of work give the same sums in the same order, so the same bytes; which is
    # sooner depends on how many pairs each observation is in: the 36 lanes pay for their
    # layout (216 numbers an observation) from about 4 pairs an observation on (walking_xyz
    # at TUM's length: 5-15, 0.74-0.93x the time; 150-frame clips and a sweep's 40-frame
    # ones: 1.3-4.7, 0.96-1.5x).
    pairs = 0
    for p in range(n_points):
        k = point_start[p + 1] - point_start[p]
        pairs += k * (k + 1) // 2
    if pairs > LANES_FROM_PAIRS * point_start[n_points]:
        _pairs_in_lanes(reduced, rhs_sum, v_inverse, g_point, w_blocks, point_start, point_obs, obs_slot)
    else:
        _pairs_in_place(reduced, rhs_sum, v_inverse, g_point, w_blocks, point_start, point_obs, obs_slot)
    for k in range(n_free):
        for a in range(6):
            for b in range(a, 6):
                reduced[6 * k + a, 6 * k + b] += u_blocks[k, a, b]
    for a in range(size):
        reduced[a, a] += damping
        rhs[a] = -g_pose[a // 6, a % 6] + rhs_sum[a]
    return True, reduced, rhs, v_inverse


@jit
def back_substitute(
    pose_step: np.ndarray,
    g_point: np.ndarray,
    w_blocks: np.ndarray,
    v_inverse: np.ndarray,
    point_start: np.ndarray,
    point_obs: np.ndarray,
    obs_slot: np.ndarray,
) -> np.ndarray:
    """The points' step (P, 3) given the free poses' (F, 6): V^-1 (-g_p - W_p^T pose step)."""
    n_points = len(v_inverse)
    point_step = np.empty((n_points, 3))
    point_rhs = np.empty(3)
    for p in range(n_points):
        for b in range(3):
            point_rhs[b] = -g_point[p, b]
        for i in range(point_start[p], point_start[p + 1]):
            row = point_obs[i]
            slot = obs_slot[row]
            for b in range(3):
                total = 0.0
                for a in range(6):
                    total += w_blocks[row, a, b] * pose_step[slot, a]
                point_rhs[b] -= total
        vi = v_inverse[p]
        for a in range(3):
            point_step[p, a] = vi[a, 0] * point_rhs[0] + vi[a, 1] * point_rhs[1] + vi[a, 2] * point_rhs[2]
    return point_step
