"""A camera trajectory's motion statistics, as the TUM RGB-D benchmark lists them per sequence.

TUM's dataset page gives, for every sequence, its duration, the camera's path length,
and its mean translational and angular speed. The speeds are means over every pose of
the motion over the following second (``SPEED_WINDOW_S``): the distance to, and the angle
of the relative rotation to, the first pose at least 1 s later, over the time between.
This reproduces TUM's figures from its own ground truth (fr1/xyz 0.244 m/s and 8.92 deg/s,
fr2/desk 0.193 m/s and 6.34 deg/s, to within 0.5 %; tests/test_camera_motion.py), where
speeds over consecutive 100 Hz motion-capture steps come out 25-100 % higher (the capture's
noise). The path length is the sum of consecutive steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depotbench.sim.tum_files import read_pose_file
from scipy.spatial.transform import Rotation

SPEED_WINDOW_S = 1.0
"""The span TUM's mean speeds are taken over (see the module's docstring)."""
WINDOW_TOLERANCE_S = 1e-6
"""A pose this close to a window's end counts as reaching it (frame times i / fps carry
rounding: 30 frames at 30 fps may end 1e-16 s short of 1 s)."""


@dataclass(frozen=True)
class MotionStats:
    duration_s: float
    path_length_m: float
    mean_speed_mps: float
    mean_angular_speed_dps: float

    @classmethod
    def of_poses(cls, timestamps_s: np.ndarray, world_from_camera: np.ndarray) -> MotionStats:
        """Statistics of (N,) timestamps and (N, 4, 4) ``world_from_camera`` poses; the
        poses must span more than ``SPEED_WINDOW_S``. Repeated stamps (TUM's ground truth
        holds a few) add no step and start no window."""
        stamps = np.asarray(timestamps_s, dtype=np.float64)
        poses = np.asarray(world_from_camera, dtype=np.float64)
        if poses.shape != (len(stamps), 4, 4):
            raise ValueError("motion statistics need one 4x4 pose per timestamp")
        if np.any(np.diff(stamps) < 0):
            raise ValueError("motion statistics need timestamps in increasing order")
        keep = np.r_[True, np.diff(stamps) > 0]
        stamps, poses = stamps[keep], poses[keep]
        ends = np.searchsorted(stamps, stamps + SPEED_WINDOW_S - WINDOW_TOLERANCE_S)
        starts = np.flatnonzero(ends < len(stamps))
        if not len(starts):
            raise ValueError(f"motion statistics need poses spanning at least {SPEED_WINDOW_S:g} s")
        speed, angular = window_speeds(stamps, poses[:, :3, 3], poses[:, :3, :3], starts, ends[starts])
        steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
        return cls(
            duration_s=float(stamps[-1] - stamps[0]),
            path_length_m=float(steps.sum()),
            mean_speed_mps=speed,
            mean_angular_speed_dps=angular,
        )

    @classmethod
    def of_groundtruth(cls, path: Path) -> MotionStats:
        """Statistics of a TUM pose file (a sequence's ``groundtruth.txt``, or TUM's own)."""
        table = read_pose_file(Path(path), strict=False)
        poses = np.tile(np.eye(4), (len(table.timestamps_s), 1, 1))
        poses[:, :3, :3] = Rotation.from_quat(table.quats_xyzw).as_matrix()
        poses[:, :3, 3] = table.positions_m
        return cls.of_poses(table.timestamps_s, poses)


def window_speeds(
    stamps: np.ndarray, positions: np.ndarray, rotations: np.ndarray, starts: np.ndarray, ends: np.ndarray
) -> tuple[float, float]:
    """Mean translational (m/s) and angular (deg/s) speed from each start pose to its end pose."""
    dt = stamps[ends] - stamps[starts]
    distance = np.linalg.norm(positions[ends] - positions[starts], axis=1)
    relative = np.einsum("nji,njk->nik", rotations[starts], rotations[ends])
    angles = relative_angles_rad(relative)
    return float(np.mean(distance / dt)), math.degrees(float(np.mean(angles / dt)))


def relative_angles_rad(rotations: np.ndarray) -> np.ndarray:
    """Rotation angle of each (..., 3, 3) rotation matrix, from its trace (clipped: a
    matrix a rounding error off orthonormal may give a cosine just past +-1)."""
    trace = np.trace(rotations, axis1=-2, axis2=-1)
    return np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))


TUM_MOTION_SOURCE = (
    "TUM RGB-D benchmark, dataset list (Sturm et al., IROS 2012), "
    "https://cvg.cit.tum.de/data/datasets/rgbd-dataset/download"
)
"""Where ``TUM_MOTION``'s figures are published: the per-sequence table of the dataset page."""

TUM_MOTION: dict[str, MotionStats] = {
    "walking_static": MotionStats(24.83, 0.282, 0.012, 1.388),
    "walking_xyz": MotionStats(28.83, 5.791, 0.208, 5.490),
    "walking_rpy": MotionStats(30.61, 2.698, 0.091, 20.903),
    "walking_halfsphere": MotionStats(35.81, 7.686, 0.221, 18.267),
    "sitting_static": MotionStats(23.63, 0.259, 0.011, 1.699),
    "sitting_xyz": MotionStats(42.50, 5.496, 0.132, 3.562),
    "sitting_halfsphere": MotionStats(37.15, 6.503, 0.180, 19.094),
}
"""TUM fr3's dynamic sequences (``rgbd_dataset_freiburg3_<name>``) as ``TUM_MOTION_SOURCE``
lists them: duration, path length, mean translational and mean angular speed."""
