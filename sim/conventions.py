"""The one place that converts camera conventions.

OpenCV/TUM optical frame: x right, y down, z forward. MuJoCo (OpenGL) camera
frame: x right, y up, looking along -z. ``R_gl = R_cv @ GL_FROM_CV``.
"""

from __future__ import annotations

import numpy as np
from depotbench.sim.products import product
from scipy.spatial.transform import Rotation

GL_FROM_CV = np.diag([1.0, -1.0, -1.0])
"""Right-multiplying a rotation by this flips between the optical and the OpenGL camera axes."""


def gl_from_cv_rotation(world_from_cv: np.ndarray) -> np.ndarray:
    return product(world_from_cv, GL_FROM_CV)


def cv_from_gl_rotation(world_from_gl: np.ndarray) -> np.ndarray:
    return product(world_from_gl, GL_FROM_CV)


UP_PARALLEL_TOLERANCE = 1e-6
"""|sin| of the angle between view and up below which ``look_at`` takes world +y as up."""


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """``world_from_camera`` (4x4, optical frame) of a camera at ``eye`` looking at ``target``.

    The image's up points along ``up`` (world +z by default). A camera looking straight
    along ``up`` (a top-down view) has no such direction; its image's up is then world +y,
    the direction the default camera faces.
    """
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=float)
    z = np.asarray(target, dtype=float) - np.asarray(eye, dtype=float)
    length = np.linalg.norm(z)
    if not length > 0:
        raise ValueError(f"look_at: the target {target} is the eye {eye}")
    z = z / length
    x = np.cross(z, up)
    if np.linalg.norm(x) < UP_PARALLEL_TOLERANCE * np.linalg.norm(up):
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, z], axis=1)
    pose[:3, 3] = eye
    return pose


def quat_wxyz(rotation: np.ndarray) -> np.ndarray:
    """MuJoCo's quaternion order (w, x, y, z) of rotation matrices (..., 3, 3)."""
    xyzw = Rotation.from_matrix(rotation).as_quat(canonical=True)
    return np.roll(xyzw, 1, axis=-1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.cross for two 3-vectors, by the same products (so the same bits) without its
    axis handling, which cost 3 ms a frame across the actors' poses."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def frame_along(direction: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """Rotation whose z axis is ``direction`` and whose x axis leans to ``forward``."""
    z = direction / np.linalg.norm(direction)
    x = forward - np.dot(forward, z) * z
    norm = np.linalg.norm(x)
    if norm < 1e-6:
        x = _cross(z, (0.0, 0.0, 1.0)) if abs(z[2]) < 0.9 else _cross(z, (0.0, 1.0, 0.0))
        norm = np.linalg.norm(x)
    x = x / norm
    return np.array([x, _cross(z, x), z]).T
