"""Robust pose refinement and local bundle adjustment.

Both minimise ORB-SLAM's RGB-D reprojection error: (u, v) plus a virtual right
coordinate u_r = u - bf / z, weighted by the keypoint's pyramid level, under a
Huber loss. The pose-only refinement is a small Gauss-Newton on the analytic
Jacobian (6 unknowns; a solver call would cost more than the solve).

Local BA (``depotbench.slam.bundle``) minimises the same edges over a keyframe window.
``refine_pose`` runs the compiled kernel (``depotbench.slam.kernels.optimize``) or this module's
NumPy reference, ``refine_pose_numpy``, as ``DEPOTBENCH_KERNELS`` says.
"""

from __future__ import annotations

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam import kernels
from depotbench.slam.geometry import exp_se3

CHI2_STEREO = 7.815
"""95 % quantile of chi-square with 3 dof (ORB-SLAM's RGB-D outlier threshold)."""
CHI2_MONO = 5.991
GN_STEP_TOLERANCE = 1e-6
"""Gauss-Newton stops once a step moves the pose by less than 1 micrometre / microradian."""


def _residuals(
    points_c: np.ndarray,
    uv: np.ndarray,
    ur: np.ndarray,
    weight: np.ndarray,
    camera: Intrinsics,
    bf: float,
) -> np.ndarray:
    z = points_c[:, 2]
    safe_z = np.where(np.abs(z) < 1e-6, 1e-6, z)
    u = camera.fx * points_c[:, 0] / safe_z + camera.cx
    v = camera.fy * points_c[:, 1] / safe_z + camera.cy
    has_depth = np.isfinite(ur)
    r_right = np.where(has_depth, np.where(has_depth, ur, 0.0) - (u - bf / safe_z), 0.0)
    out = np.empty((len(points_c), 3))
    out[:, 0], out[:, 1], out[:, 2] = uv[:, 0] - u, uv[:, 1] - v, r_right
    return out * weight[:, None]


def is_inlier(
    points_c: np.ndarray,
    uv: np.ndarray,
    ur: np.ndarray,
    weight: np.ndarray,
    camera: Intrinsics,
    bf: float,
) -> np.ndarray:
    errors = np.sum(_residuals(points_c, uv, ur, weight, camera, bf) ** 2, axis=1)
    threshold = np.where(np.isfinite(ur), CHI2_STEREO, CHI2_MONO)
    return (errors < threshold) & (points_c[:, 2] > 0)


def _pose_jacobian(points_c: np.ndarray, camera: Intrinsics, bf: float, has_depth: np.ndarray) -> np.ndarray:
    """d(residual)/d(delta) (N, 3, 6) for a left perturbation exp(delta) of camera_from_world.

    delta = (rotation vector, translation); residual = observation - prediction. Written
    out per entry (d prediction / d point times d point / d delta = [-[p]x | I]) rather
    than as a batched matrix product: this runs in every Gauss-Newton step of tracking.
    """
    x, y, z_raw = points_c[:, 0], points_c[:, 1], points_c[:, 2]
    inv = 1.0 / np.maximum(z_raw, 1e-6)
    n = len(points_c)
    jac = np.empty((n, 3, 6))
    # u = fx x / z + cx: d/dp = (a0, 0, a2)
    a0, a2 = camera.fx * inv, -camera.fx * x * inv * inv
    jac[:, 0, 0], jac[:, 0, 1], jac[:, 0, 2] = -a2 * y, a2 * x - a0 * z_raw, a0 * y
    jac[:, 0, 3], jac[:, 0, 4], jac[:, 0, 5] = -a0, 0.0, -a2
    # v = fy y / z + cy: d/dp = (0, b1, b2)
    b1, b2 = camera.fy * inv, -camera.fy * y * inv * inv
    jac[:, 1, 0], jac[:, 1, 1], jac[:, 1, 2] = b1 * z_raw - b2 * y, b2 * x, -b1 * x
    jac[:, 1, 3], jac[:, 1, 4], jac[:, 1, 5] = 0.0, -b1, -b2
    # u_r = u - bf / z: d/dp = (a0, 0, a2 + bf / z^2); none without depth
    c2 = a2 + bf * inv * inv
    jac[:, 2, 0], jac[:, 2, 1], jac[:, 2, 2] = -c2 * y, c2 * x - a0 * z_raw, a0 * y
    jac[:, 2, 3], jac[:, 2, 4], jac[:, 2, 5] = -a0, 0.0, -c2
    jac[~has_depth, 2] = 0.0
    return jac


def refine_pose(
    camera_from_world: np.ndarray,
    points_w: np.ndarray,
    uv: np.ndarray,
    ur: np.ndarray,
    weight: np.ndarray,
    camera: Intrinsics,
    bf: float,
    rounds: int = 4,
    iterations: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """Pose-only optimisation with outlier rounds (``refine_pose_numpy``), compiled unless
    ``DEPOTBENCH_KERNELS=numpy``: (camera_from_world, inlier mask)."""
    if not kernels.compiled():
        return refine_pose_numpy(camera_from_world, points_w, uv, ur, weight, camera, bf, rounds, iterations)
    from depotbench.slam.kernels import optimize as compiled

    return compiled.refine_pose(
        np.ascontiguousarray(camera_from_world, np.float64),
        np.ascontiguousarray(points_w, np.float64),
        np.ascontiguousarray(uv, np.float64),
        np.ascontiguousarray(ur, np.float64),
        np.ascontiguousarray(weight, np.float64),
        float(camera.fx),
        float(camera.fy),
        float(camera.cx),
        float(camera.cy),
        float(bf),
        int(rounds),
        int(iterations),
        CHI2_STEREO,
        CHI2_MONO,
        GN_STEP_TOLERANCE,
    )


def refine_pose_numpy(
    camera_from_world: np.ndarray,
    points_w: np.ndarray,
    uv: np.ndarray,
    ur: np.ndarray,
    weight: np.ndarray,
    camera: Intrinsics,
    bf: float,
    rounds: int = 4,
    iterations: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """Pose-only optimisation with outlier rounds, as ORB-SLAM's PoseOptimization.

    Gauss-Newton on the analytic SE(3) Jacobian with Huber weights (IRLS, per
    observation as g2o weighs an edge); after each round observations over the
    chi-square threshold are set aside and the last round runs without Huber.
    """
    pose = camera_from_world.copy()
    has_depth = np.isfinite(ur)
    active = np.ones(len(points_w), dtype=bool)
    huber = np.sqrt(CHI2_STEREO)
    damping = 1e-9 * np.eye(6)
    for round_index in range(rounds):
        if active.sum() < 3:
            break
        pw, obs, right, w, depth = points_w[active], uv[active], ur[active], weight[active], has_depth[active]
        robust = round_index < rounds - 1
        for _ in range(iterations):
            pc = pw @ pose[:3, :3].T + pose[:3, 3]
            r = _residuals(pc, obs, right, w, camera, bf)
            jac = _pose_jacobian(pc, camera, bf, depth) * w[:, None, None]
            if robust:
                norm = np.sqrt(np.einsum("ij,ij->i", r, r))
                irls = np.where(norm > huber, huber / np.maximum(norm, 1e-12), 1.0)
                weighted = jac * irls[:, None, None]
            else:
                weighted = jac
            flat, flat_weighted = jac.reshape(-1, 6), weighted.reshape(-1, 6)
            hessian = flat_weighted.T @ flat + damping
            gradient = flat_weighted.T @ r.ravel()
            try:
                delta = -np.linalg.solve(hessian, gradient)
            except np.linalg.LinAlgError:
                break  # a degenerate start (e.g. a RANSAC pose with points behind it): no step
            if not np.isfinite(delta).all():
                break
            pose = exp_se3(delta) @ pose
            if np.linalg.norm(delta) < GN_STEP_TOLERANCE:
                break
        points_c = points_w @ pose[:3, :3].T + pose[:3, 3]
        active = is_inlier(points_c, uv, ur, weight, camera, bf)
    return pose, active
