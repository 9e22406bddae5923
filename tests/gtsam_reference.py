"""The same local bundle adjustment solved by GTSAM: the independent reference for ``depotbench.slam.bundle``.

GTSAM's stereo factor is exactly ORB-SLAM's RGB-D edge (u_left, u_right, v) and its
projection factor the edge of a keypoint without depth; the Huber kernel is applied
to each factor's whitened error. Fixed keyframes get a tight prior (GTSAM has no
hard equality short of a slow constrained elimination).
"""

from __future__ import annotations

import gtsam
import numpy as np
from depotbench.slam.bundle import BundleWindow
from depotbench.slam.geometry import invert

FIXED_POSE_SIGMA = 1e-9


def gtsam_bundle_adjust(window: BundleWindow, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    poses, free, points, camera, bf = window.poses, window.free, window.points, window.camera, window.bf
    obs_pose, obs_point, uv, ur, weight = (
        window.obs_pose,
        window.obs_point,
        window.uv,
        window.ur,
        window.weight,
    )
    calibration = gtsam.Cal3_S2Stereo(camera.fx, camera.fy, 0.0, camera.cx, camera.cy, bf / camera.fx)
    mono_calibration = gtsam.Cal3_S2(camera.fx, camera.fy, 0.0, camera.cx, camera.cy)
    huber = gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(7.815))
    fixed_noise = gtsam.noiseModel.Isotropic.Sigma(6, FIXED_POSE_SIGMA)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i, camera_from_world in enumerate(poses):
        world_from_camera = gtsam.Pose3(invert(camera_from_world))
        values.insert(gtsam.symbol("x", i), world_from_camera)
        if not free[i]:
            graph.add(gtsam.PriorFactorPose3(gtsam.symbol("x", i), world_from_camera, fixed_noise))
    for j, point in enumerate(points):
        values.insert(gtsam.symbol("l", j), point.astype(np.float64))
    for k in range(len(obs_pose)):
        stereo = bool(np.isfinite(ur[k]))
        base = gtsam.noiseModel.Isotropic.Sigma(3 if stereo else 2, 1.0 / weight[k])
        noise = gtsam.noiseModel.Robust.Create(huber, base)
        pose_key, point_key = gtsam.symbol("x", int(obs_pose[k])), gtsam.symbol("l", int(obs_point[k]))
        if stereo:
            measured = gtsam.StereoPoint2(uv[k, 0], ur[k], uv[k, 1])
            graph.add(gtsam.GenericStereoFactor3D(measured, noise, pose_key, point_key, calibration))
        else:
            graph.add(
                gtsam.GenericProjectionFactorCal3_S2(uv[k], noise, pose_key, point_key, mono_calibration)
            )
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    new_poses = np.array([invert(result.atPose3(gtsam.symbol("x", i)).matrix()) for i in range(len(poses))])
    new_points = np.array([result.atPoint3(gtsam.symbol("l", j)) for j in range(len(points))]).reshape(-1, 3)
    return new_poses, new_points
