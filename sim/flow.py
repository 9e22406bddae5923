"""Exact optical flow: every pixel moved by the true camera motion and its own body's motion."""

from __future__ import annotations

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.sim.products import product, rigid_inverse


def rigid_motions(pos0: np.ndarray, rot0: np.ndarray, pos1: np.ndarray, rot1: np.ndarray) -> np.ndarray:
    """Per body, the 4x4 world transform taking its points at t to t+1."""
    n = len(pos0)
    motion = np.tile(np.eye(4), (n, 1, 1))
    r = product(rot1, np.transpose(rot0, (0, 2, 1)))
    motion[:, :3, :3] = r
    motion[:, :3, 3] = pos1 - np.einsum("nij,nj->ni", r, pos0)
    return motion


def flow_at(
    u: np.ndarray,
    v: np.ndarray,
    z: np.ndarray,
    bodies: np.ndarray,
    intrinsics: Intrinsics,
    world_from_cam0: np.ndarray,
    world_from_cam1: np.ndarray,
    body_motion: np.ndarray,
) -> np.ndarray:
    """Flow (N, 2) of pixels (u, v) with depth z on the given bodies, from frame t to t+1."""
    k = intrinsics
    z = z.astype(np.float64)
    x, y = (u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z
    # Camera 1 from camera 0 through each body's motion: one 3x4 per body, not per pixel.
    through = product(product(rigid_inverse(world_from_cam1), body_motion), world_from_cam0)
    t = through[bodies, :3]
    cam1 = t[:, :, 0] * x[:, None] + t[:, :, 1] * y[:, None] + t[:, :, 2] * z[:, None] + t[:, :, 3]
    u1 = k.fx * cam1[:, 0] / cam1[:, 2] + k.cx
    v1 = k.fy * cam1[:, 1] / cam1[:, 2] + k.cy
    return np.stack([u1 - u, v1 - v], axis=-1)


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
    flow = flow_at(
        u.ravel(),
        v.ravel(),
        depth_m.ravel(),
        body_ids.ravel(),
        intrinsics,
        world_from_cam0,
        world_from_cam1,
        body_motion,
    )
    flow = flow.reshape(h, w, 2).astype(np.float32)
    flow[depth_m <= 0] = np.nan
    return flow
