"""A camera pose from 2D-3D matches: stereo observations, EPnP RANSAC, robust refinement.

Holds what tracking and relocalisation share once they have matches: the RGB-D frame's
observations of its keypoints (pixel, virtual right-image column from depth, pyramid-level
weight), the pose solver (ORB-SLAM's PnPsolver then Optimizer::PoseOptimization) and the
tracked result they hand to mapping. The rule: a pose from fewer than ``MIN_MATCHES`` (15)
inlier matches is not trusted, whichever way it was found.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam.config import TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.optimize import refine_pose

MIN_MATCHES = 15


@dataclass
class Tracked:
    """A frame's pose and the matches (keypoint, map point) it was found with."""

    world_from_camera: np.ndarray
    keypoints: np.ndarray
    point_ids: np.ndarray
    inliers: int


def observations(
    tc: TrackingConfig, features: FrameFeatures, keypoints: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(undistorted pixel, right-image column or NaN without depth, 1 / scale^level) per keypoint."""
    uv = features.undistorted_px[keypoints]
    ur = features.right_px(tc.baseline_fx)[keypoints]
    weight = 1.0 / tc.scale_factor ** features.octaves[keypoints]
    return uv, ur, weight


def solve_pose(
    tc: TrackingConfig,
    camera: Intrinsics,
    features: FrameFeatures,
    keypoints: np.ndarray,
    points_w: np.ndarray,
    guess_cw: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Robust pose from matches (keypoints, their map points' world positions):
    (camera_from_world, inlier mask) or None.

    With a guess (the motion model's prediction) and ``motion_model_ransac`` off, the
    refinement starts from the guess, as ORB-SLAM's TrackWithMotionModel does; PnP RANSAC
    runs when there is no guess, when that is on, or when refining from the guess keeps
    fewer than ``MIN_MATCHES`` inliers (ORB-SLAM then falls back to its reference keyframe).
    """
    if len(keypoints) < 6:
        return None
    bf = tc.baseline_fx
    uv, ur, weight = observations(tc, features, keypoints)
    from_guess = None
    if guess_cw is not None and not tc.motion_model_ransac:
        from_guess = refine_pose(guess_cw, points_w, uv, ur, weight, camera, bf)
        if from_guess[1].sum() >= MIN_MATCHES:
            return from_guess
    ok, rvec, tvec, _ = cv2.solvePnPRansac(
        points_w.astype(np.float64),
        uv,
        camera.matrix,
        None,
        iterationsCount=tc.ransac_iterations,
        reprojectionError=tc.ransac_reprojection_px,
        confidence=0.99,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok:
        if from_guess is not None or guess_cw is None:
            return from_guess
        return refine_pose(guess_cw, points_w, uv, ur, weight, camera, bf)
    pose_cw = np.eye(4)
    pose_cw[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose_cw[:3, 3] = tvec.ravel()
    return refine_pose(pose_cw, points_w, uv, ur, weight, camera, bf)
