"""Exact optical flow: every pixel moved by the true camera motion and its own body's motion."""

from __future__ import annotations

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.core.jit import compiled
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
    through = _through(world_from_cam0, world_from_cam1, body_motion)
    # Every pixel through the static world's transform (body 0: most of a frame, with scalar
    # coefficients), then the others' through their bodies'. Each element sees the same
    # products and sums in the same order as one gathered 3x4 per pixel, so the flow is the
    # same to the bit (tests/test_flow_per_body.py), in 18-26 ms a 640x480 frame where
    # gathering for every pixel took 42-52 ms (5-20 % of the pixels moving).
    cam1 = np.empty((len(x), 3))
    world = through[0, :3]
    for r in range(3):
        cam1[:, r] = world[r, 0] * x + world[r, 1] * y + world[r, 2] * z + world[r, 3]
    others = np.flatnonzero(bodies != 0)
    if len(others):
        t = through[bodies[others], :3]
        xo, yo, zo = x[others, None], y[others, None], z[others, None]
        cam1[others] = t[:, :, 0] * xo + t[:, :, 1] * yo + t[:, :, 2] * zo + t[:, :, 3]
    u1 = k.fx * cam1[:, 0] / cam1[:, 2] + k.cx
    v1 = k.fy * cam1[:, 1] / cam1[:, 2] + k.cy
    return np.stack([u1 - u, v1 - v], axis=-1)


def _through(world_from_cam0: np.ndarray, world_from_cam1: np.ndarray, body_motion: np.ndarray) -> np.ndarray:
    """Camera 1 from camera 0 through each body's motion: one 4x4 per body, not per pixel."""
    return product(product(rigid_inverse(world_from_cam1), body_motion), world_from_cam0)


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
    if compiled():  # one pass over the pixels, the same bits (sim/kernels.py): 2 ms, not 25
        from depotbench.sim import kernels

        through = _through(world_from_cam0, world_from_cam1, body_motion)
        k = intrinsics
        return kernels.flow_image(depth_m, body_ids, k.fx, k.fy, k.cx, k.cy, np.ascontiguousarray(through))
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
