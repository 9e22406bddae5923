"""Exact optical flow: every pixel moved by the true camera motion and its own body's motion."""

from __future__ import annotations

import numpy as np

from sim.camera import Intrinsics


def rigid_motions(
    pos0: np.ndarray, rot0: np.ndarray, pos1: np.ndarray, rot1: np.ndarray
) -> np.ndarray:
    """Per body, the 4x4 world transform taking its points at t to t+1."""
    n = len(pos0)
    motion = np.tile(np.eye(4), (n, 1, 1))
    r = rot1 @ np.transpose(rot0, (0, 2, 1))
    motion[:, :3, :3] = r
    motion[:, :3, 3] = pos1 - np.einsum("nij,nj->ni", r, pos0)
    return motion


def exact_flow(
    depth_m: np.ndarray,
    body_ids: np.ndarray,
    intrinsics: Intrinsics,
    world_from_cam0: np.ndarray,
    world_from_cam1: np.ndarray,
    body_motion: np.ndarray,
) -> np.ndarray:
    """Flow (H, W, 2) in pixels from frame t to t+1; NaN where depth is missing.

    ``body_ids`` gives each pixel's MuJoCo body (0 = static world);
    ``body_motion`` is ``rigid_motions`` of all bodies.
    """
    h, w = depth_m.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = depth_m.astype(np.float64)
    x = (u - intrinsics.cx) / intrinsics.fx * z
    y = (v - intrinsics.cy) / intrinsics.fy * z
    cam_points = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    world = cam_points @ world_from_cam0[:3, :3].T + world_from_cam0[:3, 3]
    m = body_motion[body_ids.ravel()]
    moved = np.einsum("nij,nj->ni", m[:, :3, :3], world) + m[:, :3, 3]
    cam1 = (moved - world_from_cam1[:3, 3]) @ world_from_cam1[:3, :3]
    u1 = intrinsics.fx * cam1[:, 0] / cam1[:, 2] + intrinsics.cx
    v1 = intrinsics.fy * cam1[:, 1] / cam1[:, 2] + intrinsics.cy
    flow = np.stack([u1.reshape(h, w) - u, v1.reshape(h, w) - v], axis=-1).astype(np.float32)
    flow[z <= 0] = np.nan
    return flow
