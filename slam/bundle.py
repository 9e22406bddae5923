"""Local bundle adjustment: Levenberg-Marquardt on the reduced camera system.

The cost is ORB-SLAM's RGB-D edge, the one ``depotbench.slam.optimize`` refines poses on:
(u, v) plus the virtual right coordinate u_r = u - bf / z, whitened by the
keypoint's pyramid level (sigma = scale_factor^octave), a 2-D edge where a
keypoint had no depth, under a Huber kernel (k^2 = 7.815) applied to each
observation's whitened error as g2o and GTSAM do.

Why not a factor-graph library: GTSAM (kept as the reference in
``tests/test_slam.py``) reaches the same cost, but its Python binding builds one
factor per observation in a Python loop, which cost as much as its solve; a
keyframe window has a handful of free poses and a few thousand observations,
so the whole problem fits in a few array operations. Points are eliminated by
the Schur complement (3x3 blocks, inverted all at once), the reduced system of
the free poses is dense (6 x free poses, 6 x the covisibility window's free keyframes). Fixed
keyframes are held exactly, as ORB-SLAM fixes them (``setFixed``). The damping
and stopping rules follow GTSAM's Levenberg-Marquardt defaults.

``_Problem`` is the NumPy reference; ``_CompiledProblem`` evaluates the same cost,
linearisation and step with ``depotbench.slam.kernels.optimize``, and ``bundle_adjust`` runs
one Levenberg-Marquardt loop on whichever ``DEPOTBENCH_KERNELS`` selects.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam import kernels
from depotbench.slam.geometry import exp_se3
from depotbench.slam.optimize import is_inlier
from scipy import linalg, sparse

HUBER_K = float(np.sqrt(7.815))
"""Huber threshold on an observation's whitened error (ORB-SLAM's RGB-D chi-square at 95 %)."""
LAMBDA_INITIAL, LAMBDA_FACTOR, LAMBDA_MAX = 1e-5, 10.0, 1e5
"""GTSAM's LevenbergMarquardtParams defaults."""
RELATIVE_TOLERANCE = ABSOLUTE_TOLERANCE = 1e-5
"""Stop when an iteration lowers the cost by less than this, relatively or absolutely."""
MIN_DEPTH = 1e-6


@dataclass(frozen=True, eq=False)
class BundleWindow:
    """A local bundle adjustment problem: keyframe poses, map points, who sees what.

    ``poses`` are camera_from_world (K, 4, 4), ``free`` says which may move, ``points``
    (P, 3) are all free. Observation k is keypoint ``uv[k]`` (with virtual right
    coordinate ``ur[k]``, NaN without depth, and whitening ``weight[k]``) of point
    ``obs_point[k]`` in keyframe ``obs_pose[k]``; ``bf`` is the baseline times fx."""

    poses: np.ndarray
    free: np.ndarray
    points: np.ndarray
    obs_pose: np.ndarray
    obs_point: np.ndarray
    uv: np.ndarray
    ur: np.ndarray
    weight: np.ndarray
    camera: Intrinsics
    bf: float


def solve_reduced(reduced: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
    """The reduced camera system's solution by Cholesky on its upper triangle (LAPACK's
    potrf, as GTSAM and g2o's Cholesky solvers factor it): the damped system is symmetric
    positive definite, and a factorisation that finds it is not (a near-singular window)
    refuses the step, so the damping grows. Half the work of LU: 18 against 36 ms at 200
    free keyframes (1,200 wide, one core). None where it is not positive definite (a step
    that is not finite is the caller's to refuse)."""
    if not len(rhs):
        return np.zeros(0)
    try:
        factor = linalg.cho_factor(reduced, lower=False, overwrite_a=True, check_finite=False)
    except linalg.LinAlgError:
        return None
    return linalg.cho_solve(factor, rhs, check_finite=False)


class _Problem:
    """Observations of points by keyframes; evaluates the cost and its linearisation."""

    def __init__(self, window: BundleWindow) -> None:
        free, obs_pose, obs_point, ur = window.free, window.obs_pose, window.obs_point, window.ur
        n_points = len(window.points)
        uv, camera, bf = window.uv, window.camera, window.bf
        self.camera, self.bf, self.weight = camera, bf, window.weight
        self.obs_pose, self.obs_point = obs_pose, obs_point
        self.stereo = np.isfinite(ur)
        self.measured = np.c_[uv, np.where(self.stereo, ur, 0.0)]
        slot = np.full(len(free), -1)
        slot[free] = np.arange(int(free.sum()))
        self.n_free, self.n_points = int(free.sum()), n_points
        self.obs_slot = slot[obs_pose]
        n = len(obs_pose)
        # Sums over observations as sparse products: by point, and by free pose.
        self.by_point = sparse.csr_matrix((np.ones(n), (obs_point, np.arange(n))), shape=(n_points, n))
        on_free = self.obs_slot >= 0
        self.on_free = np.flatnonzero(on_free)
        self.by_pose = sparse.csr_matrix(
            (np.ones(len(self.on_free)), (self.obs_slot[on_free], np.arange(len(self.on_free)))),
            shape=(self.n_free, len(self.on_free)),
        )

    def _camera_points(self, poses: np.ndarray, points: np.ndarray) -> np.ndarray:
        rotation, translation = poses[self.obs_pose, :3, :3], poses[self.obs_pose, :3, 3]
        return np.matmul(rotation, points[self.obs_point][:, :, None])[:, :, 0] + translation

    def _whitened(self, pc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whitened residuals (N, 3) and which observations are in front of their camera."""
        cam = self.camera
        front = pc[:, 2] > MIN_DEPTH
        z = np.where(front, pc[:, 2], 1.0)
        u = cam.fx * pc[:, 0] / z + cam.cx
        v = cam.fy * pc[:, 1] / z + cam.cy
        r = self.measured - np.c_[u, v, u - self.bf / z]
        r[~self.stereo, 2] = 0.0
        r[~front] = 0.0
        return r * self.weight[:, None], front

    def cost(self, poses: np.ndarray, points: np.ndarray) -> float:
        r, front = self._whitened(self._camera_points(poses, points))
        error = np.sqrt(np.einsum("ij,ij->i", r, r))
        huber = np.where(error <= HUBER_K, 0.5 * error**2, HUBER_K * error - 0.5 * HUBER_K**2)
        # Behind a camera: GTSAM's stereo factor reports a constant error of 2 fx per coordinate.
        behind = 0.5 * (2 * self.camera.fx) ** 2 * 3 * np.count_nonzero(~front)
        return float(huber.sum() + behind)

    def linearise(self, poses: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, ...]:
        """Huber-weighted normal-equation blocks: U (free poses), V (points), W (per observation
        on a free pose), and the gradients of both."""
        pc = self._camera_points(poses, points)
        r, front = self._whitened(pc)
        error = np.sqrt(np.einsum("ij,ij->i", r, r))
        robust = np.where(error > HUBER_K, HUBER_K / np.maximum(error, 1e-12), 1.0) * front
        cam, n = self.camera, len(pc)
        x, y = pc[:, 0], pc[:, 1]
        z = np.where(front, pc[:, 2], 1.0)
        inv = 1.0 / z
        # d(prediction)/d(camera point); residual = measured - prediction.
        d = np.zeros((n, 3, 3))
        d[:, 0, 0], d[:, 0, 2] = cam.fx * inv, -cam.fx * x * inv**2
        d[:, 1, 1], d[:, 1, 2] = cam.fy * inv, -cam.fy * y * inv**2
        d[:, 2, 0], d[:, 2, 2] = d[:, 0, 0], d[:, 0, 2] + self.bf * inv**2
        d[~self.stereo, 2] = 0.0
        d *= self.weight[:, None, None]
        # Per observation, the Jacobian of its residual in (pose delta, point): a left
        # perturbation (rotation, translation) of camera_from_world moves p_c by
        # [-[p_c]x | I] delta, so d r / d delta = [D [p_c]x | -D]; d r / d p_world = -D R.
        jac = np.empty((n, 3, 9))
        jac[:, :, 0] = pc[:, 2, None] * d[:, :, 1] - y[:, None] * d[:, :, 2]
        jac[:, :, 1] = x[:, None] * d[:, :, 2] - pc[:, 2, None] * d[:, :, 0]
        jac[:, :, 2] = y[:, None] * d[:, :, 0] - x[:, None] * d[:, :, 1]
        jac[:, :, 3:6] = -d
        jac[:, :, 6:] = -np.matmul(d, poses[self.obs_pose, :3, :3])
        weighted = np.swapaxes(jac, 1, 2) * robust[:, None, None]
        hessian = np.matmul(weighted, jac)  # (n, 9, 9): [[U, W], [W^T, V]] of each observation
        gradient = np.matmul(weighted, r[:, :, None])[:, :, 0]
        v_blocks = self.by_point @ hessian[:, 6:, 6:].reshape(n, 9)
        g_point = self.by_point @ gradient[:, 6:]
        free = self.on_free
        u_blocks = self.by_pose @ hessian[free, :6, :6].reshape(-1, 36)
        g_pose = self.by_pose @ gradient[free, :6]
        w_blocks = hessian[free, :6, 6:]
        return u_blocks.reshape(-1, 6, 6), g_pose, v_blocks.reshape(-1, 3, 3), g_point, w_blocks

    def step(self, linear: tuple[np.ndarray, ...], damping: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The damped Gauss-Newton step (free poses (F, 6), points (P, 3)); None if singular."""
        u_blocks, g_pose, v_blocks, g_point, w_blocks = linear
        v_inverse = np.linalg.inv(v_blocks + damping * np.eye(3))
        if not np.isfinite(v_inverse).all():
            return None
        # W as a dense (points, 6 x free poses, 3) array: a window has few free poses. A
        # keyframe's second sighting of a point adds to its first (never in a map).
        w = np.zeros((self.n_points, self.n_free, 6, 3))
        np.add.at(w, (self.obs_point[self.on_free], self.obs_slot[self.on_free]), w_blocks)
        w = w.reshape(self.n_points, 6 * self.n_free, 3)
        wv = np.matmul(w, v_inverse)
        reduced = np.zeros((6 * self.n_free, 6 * self.n_free))
        for k, block in enumerate(u_blocks):
            reduced[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] = block
        reduced += damping * np.eye(6 * self.n_free)
        reduced -= (
            np.swapaxes(wv, 0, 1).reshape(6 * self.n_free, -1)
            @ np.swapaxes(w, 0, 1).reshape(6 * self.n_free, -1).T
        )
        rhs = -g_pose.ravel() + np.matmul(wv, g_point[:, :, None]).sum(axis=0)[:, 0]
        pose_step = solve_reduced(reduced, rhs)
        if pose_step is None:
            return None
        point_rhs = -g_point - np.matmul(np.swapaxes(w, 1, 2), pose_step[:, None])[:, :, 0]
        point_step = np.matmul(v_inverse, point_rhs[:, :, None])[:, :, 0]
        if not (np.isfinite(pose_step).all() and np.isfinite(point_step).all()):
            return None
        return pose_step.reshape(-1, 6), point_step


class _CompiledProblem:
    """``_Problem``'s interface on the compiled kernels: the same observations, cost,
    linearisation (the same five blocks) and damped step."""

    def __init__(self, window: BundleWindow) -> None:
        from depotbench.slam.kernels import optimize as compiled

        self.kernels = compiled
        camera = window.camera
        self.camera_numbers = (float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy))
        self.bf = float(window.bf)
        self.obs_pose = np.ascontiguousarray(window.obs_pose, np.int64)
        self.obs_point = np.ascontiguousarray(window.obs_point, np.int64)
        self.stereo = np.isfinite(window.ur)
        right = np.where(self.stereo, window.ur, 0.0)
        self.measured = np.ascontiguousarray(np.c_[window.uv, right], np.float64)
        self.weight = np.ascontiguousarray(window.weight, np.float64)
        slot = np.full(len(window.free), -1, np.int64)
        slot[window.free] = np.arange(int(window.free.sum()))
        self.n_free = int(window.free.sum())
        self.obs_slot = slot[self.obs_pose]
        on_free = np.flatnonzero(self.obs_slot >= 0)
        # Rows of W (observations on free poses) grouped by point, each point's in the order
        # of their slots (``kernels.optimize.reduce`` writes S's upper triangle from it).
        by_point = np.lexsort((self.obs_slot[on_free], self.obs_point[on_free]))
        self.point_obs = by_point.astype(np.int64)
        self.point_start = np.searchsorted(
            self.obs_point[on_free][by_point], np.arange(len(window.points) + 1)
        ).astype(np.int64)
        self.free_slot = self.obs_slot[on_free]

    def _camera_points(self, poses: np.ndarray, points: np.ndarray) -> np.ndarray:
        return self.kernels.camera_points(poses, points, self.obs_pose, self.obs_point)

    def cost(self, poses: np.ndarray, points: np.ndarray) -> float:
        return float(
            self.kernels.cost(
                poses,
                points,
                self.obs_pose,
                self.obs_point,
                self.measured,
                self.stereo,
                self.weight,
                *self.camera_numbers,
                self.bf,
                HUBER_K,
                MIN_DEPTH,
            )
        )

    def linearise(self, poses: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, ...]:
        return self.kernels.linearise(
            poses,
            points,
            self.obs_pose,
            self.obs_point,
            self.obs_slot,
            self.measured,
            self.stereo,
            self.weight,
            *self.camera_numbers,
            self.bf,
            HUBER_K,
            MIN_DEPTH,
            self.n_free,
            len(self.free_slot),
        )

    def step(self, linear: tuple[np.ndarray, ...], damping: float) -> tuple[np.ndarray, np.ndarray] | None:
        grouping = (self.point_start, self.point_obs, self.free_slot)
        invertible, reduced, rhs, v_inverse = self.kernels.reduce(*linear, float(damping), *grouping)
        if not invertible:
            return None
        pose_step = solve_reduced(reduced, rhs)
        if pose_step is None:
            return None
        pose_step = pose_step.reshape(-1, 6)
        _, _, _, g_point, w_blocks = linear
        point_step = self.kernels.back_substitute(pose_step, g_point, w_blocks, v_inverse, *grouping)
        if not (np.isfinite(pose_step).all() and np.isfinite(point_step).all()):
            return None
        return pose_step, point_step


def iteration_limit(iterations: int) -> int:
    """The iterations an adjustment asked for ``iterations`` may run: at least one."""
    return max(1, iterations)


class LevenbergMarquardt:
    """One window's Levenberg-Marquardt, an outer iteration at a time: a mapper that can be
    interrupted (``depotbench.slam.mapping_clock``) stops it between iterations, as g2o checks
    ORB-SLAM3's abort flag before each."""

    def __init__(self, window: BundleWindow) -> None:
        self.window = window
        self.problem = _CompiledProblem(window) if kernels.compiled() else _Problem(window)
        self.poses, self.points = window.poses.copy(), window.points.astype(np.float64).copy()
        self.free_index = np.flatnonzero(window.free)
        self.cost = self.problem.cost(self.poses, self.points)
        self.damping = LAMBDA_INITIAL
        self.iterations = 0
        self.stopped = False
        """No step lowered the cost, or the last one lowered it by less than the tolerances."""

    def iterate(self) -> bool:
        """One linearisation and its damped steps until one lowers the cost; False once the
        adjustment has stopped (this iteration or an earlier one)."""
        if self.stopped:
            return False
        self.iterations += 1
        problem, poses, points = self.problem, self.poses, self.points
        linear = problem.linearise(poses, points)
        while self.damping <= LAMBDA_MAX:
            step = problem.step(linear, self.damping)
            if step is not None:
                trial_poses = poses.copy()
                for slot, index in enumerate(self.free_index):
                    trial_poses[index] = exp_se3(step[0][slot]) @ poses[index]
                trial_points = points + step[1]
                trial_cost = problem.cost(trial_poses, trial_points)
                if trial_cost <= self.cost:
                    break
            self.damping *= LAMBDA_FACTOR
        else:
            self.stopped = True
            return False
        decrease = self.cost - trial_cost
        self.poses, self.points, self.cost = trial_poses, trial_points, trial_cost
        self.damping /= LAMBDA_FACTOR
        if decrease < ABSOLUTE_TOLERANCE or decrease < RELATIVE_TOLERANCE * (trial_cost + decrease):
            self.stopped = True
            return False
        return True

    def run(self, iterations: int) -> LevenbergMarquardt:
        """Iterate until the adjustment stops or has run ``iteration_limit(iterations)``."""
        while self.iterations < iteration_limit(iterations) and self.iterate():
            pass
        return self

    def result(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Poses, points, the observations' inlier mask (ORB-SLAM's chi-square test at the
        result) and the cost."""
        window = self.window
        pc = self.problem._camera_points(self.poses, self.points)
        inlier = is_inlier(pc, window.uv, window.ur, window.weight, window.camera, window.bf)
        return self.poses, self.points, inlier, self.cost


def bundle_adjust(window: BundleWindow, iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Optimise the window's free poses and every point for at most ``iterations`` (at least
    one) iterations.

    Returns new poses, new points, the inlier mask of the observations (ORB-SLAM's
    chi-square test at the result) and the final cost.
    """
    return LevenbergMarquardt(window).run(iterations).result()
