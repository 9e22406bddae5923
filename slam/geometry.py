"""Small geometry: poses, projection, Hamming distances."""

from __future__ import annotations

import cv2
import numpy as np
from depotbench.core.camera import Intrinsics

POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


def invert(pose: np.ndarray) -> np.ndarray:
    inv = np.eye(4)
    inv[:3, :3] = pose[:3, :3].T
    inv[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return inv


def orthonormalize(pose: np.ndarray) -> np.ndarray:
    """The pose with its rotation projected back onto SO(3) (nearest rotation, by SVD).

    Composing poses accumulates rounding, and ``invert`` transposes the rotation: on a
    slightly non-orthogonal rotation the constant-velocity model (velocity = last^-1 @ current,
    next = current @ velocity) multiplies that error by 1 + sqrt(2) per frame, so a pose
    chain that is not re-anchored degenerates within ~40 frames unless it is re-projected.
    """
    u, _, vt = np.linalg.svd(pose[:3, :3])
    rotation = u @ vt
    if np.linalg.det(rotation) < 0:
        rotation = u @ np.diag([1.0, 1.0, -1.0]) @ vt
    out = pose.copy()
    out[:3, :3] = rotation
    out[3] = (0.0, 0.0, 0.0, 1.0)
    return out


def constant_velocity(previous: np.ndarray, current: np.ndarray) -> np.ndarray:
    """The motion from ``previous`` to ``current`` (world_from_camera poses), in the camera frame:
    ``current @ velocity`` predicts the next pose."""
    return orthonormalize(invert(previous) @ current)


def exp_se3(delta: np.ndarray) -> np.ndarray:
    """A small pose increment (rotation vector, translation) as a 4x4 matrix."""
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(np.asarray(delta[:3], np.float64))[0]
    pose[:3, 3] = delta[3:]
    return pose


def transform(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ pose[:3, :3].T + pose[:3, 3]


def project(camera: Intrinsics, points_c: np.ndarray) -> np.ndarray:
    """Pixel coordinates (N, 2) of camera-frame points (z > 0 assumed)."""
    z = points_c[:, 2]
    return np.stack(
        [camera.fx * points_c[:, 0] / z + camera.cx, camera.fy * points_c[:, 1] / z + camera.cy],
        axis=1,
    )


def backproject(camera: Intrinsics, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
    return np.stack(
        [(uv[:, 0] - camera.cx) / camera.fx * z, (uv[:, 1] - camera.cy) / camera.fy * z, z], axis=1
    )


def hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distance of two (N, 32) uint8 descriptor arrays."""
    return POPCOUNT[np.bitwise_xor(a, b)].sum(axis=1, dtype=np.int32)


def hamming_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """All-pairs Hamming distances (len(a), len(b))."""
    return POPCOUNT[np.bitwise_xor(a[:, None, :], b[None, :, :])].sum(axis=2, dtype=np.int32)
