"""Compiled per-pixel loops of the generator: exact flow and the sensor model's arithmetic.

With the ``tum`` profile every frame needs each pixel's exact flow (blur, rolling shutter and
the depth delay follow it) and a dozen whole-image array operations of the sensor model; in
NumPy each pass allocates and walks 0.3-0.9 million values, 70 ms of a 110 ms frame at
640x480 (walking_xyz, one thread). Each loop here does one pass instead.

Each kernel performs its NumPy reference's operations on the same types in the same order
(no ``fastmath``: ``core.jit``), so a sequence's bytes do not depend on the path
(``tests/test_sim_kernels.py`` holds them to the bit). The random draws stay in NumPy, in the
reference's order, and are passed in: the streams are the sequence's, not the kernels'.
"""

from __future__ import annotations

import functools

import numpy as np
from depotbench.core.jit import jit, warmed


@jit
def flow_image(
    depth: np.ndarray,
    bodies: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    through: np.ndarray,
) -> np.ndarray:
    """``sim.flow.exact_flow``: each pixel's flow (H, W, 2, float32) through its body's
    camera-1-from-camera-0 transform ``through[body]``; NaN where depth is not positive."""
    height, width = depth.shape
    flow = np.empty((height, width, 2), np.float32)
    for row in range(height):
        v = float(row)
        for col in range(width):
            d = depth[row, col]
            if d <= 0:
                flow[row, col, 0] = np.nan
                flow[row, col, 1] = np.nan
                continue
            u = float(col)
            z = float(d)
            x = (u - cx) / fx * z
            y = (v - cy) / fy * z
            t = through[bodies[row, col]]
            x1 = t[0, 0] * x + t[0, 1] * y + t[0, 2] * z + t[0, 3]
            y1 = t[1, 0] * x + t[1, 1] * y + t[1, 2] * z + t[1, 3]
            z1 = t[2, 0] * x + t[2, 1] * y + t[2, 2] * z + t[2, 3]
            flow[row, col, 0] = np.float32(fx * x1 / z1 + cx - u)
            flow[row, col, 1] = np.float32(fy * y1 / z1 + cy - v)
    return flow


@jit
def _finite(value: np.float32) -> np.float32:
    """``np.nan_to_num`` of one float32: NaN to 0, infinities to the largest finite values."""
    if np.isnan(value):
        return np.float32(0.0)
    if np.isinf(value):
        big = np.float32(3.4028234663852886e38)
        return big if value > 0 else -big
    return value


@jit
def blur_shifts(flow: np.ndarray, delays: np.ndarray, exposure_frames: np.float32) -> tuple:
    """The blur's two inputs from the exact flow: each pixel's exposure middle as a sample
    position (column and row less its row's rolling-shutter shift, ``flow * delay``) and its
    motion during the exposure (``flow * exposure_frames``); all float32 as in ``SensorModel``."""
    height, width = flow.shape[:2]
    u = np.empty((height, width), np.float32)
    v = np.empty((height, width), np.float32)
    du = np.empty((height, width), np.float32)
    dv = np.empty((height, width), np.float32)
    for row in range(height):
        delay = delays[row]
        for col in range(width):
            fu, fv = _finite(flow[row, col, 0]), _finite(flow[row, col, 1])
            u[row, col] = np.float32(col) - fu * delay
            v[row, col] = np.float32(row) - fv * delay
            du[row, col] = fu * exposure_frames
            dv[row, col] = fv * exposure_frames
    return u, v, du, dv


@jit
def blur_sample(
    u: np.ndarray,
    v: np.ndarray,
    du: np.ndarray,
    dv: np.ndarray,
    a: np.float32,
    map_u: np.ndarray,
    map_v: np.ndarray,
) -> None:
    """One blur sample's remap coordinates, ``u + a * du`` and ``v + a * dv``, into the buffers."""
    height, width = u.shape
    for row in range(height):
        for col in range(width):
            map_u[row, col] = u[row, col] + a * du[row, col]
            map_v[row, col] = v[row, col] + a * dv[row, col]


@jit
def finish_rgb(
    image: np.ndarray,
    divisor: np.float32,
    gain: np.float32,
    balance: np.ndarray,
    noise: np.ndarray,
    sigma: np.float32,
) -> np.ndarray:
    """The exposed image in uint8: ``image / divisor`` (the blur's sample count; 1 is exact),
    times the exposure ``gain`` and each channel's white ``balance``, plus ``noise * sigma``,
    rounded half to even and clipped to 0-255. A gain or balance of 1 and a sigma of 0 are
    skipped, as the reference skips them (``noise`` may then be empty)."""
    height, width, channels = image.shape
    out = np.empty((height, width, channels), np.uint8)
    scale = gain != np.float32(1.0)
    balanced = balance.size > 0
    noisy = noise.size > 0
    for row in range(height):
        for col in range(width):
            for ch in range(channels):
                value = image[row, col, ch] / divisor
                if scale:
                    value = value * gain
                if balanced:
                    value = value * balance[ch]
                if noisy:
                    value = value + noise[row, col, ch] * sigma
                value = np.rint(value)
                out[row, col, ch] = np.uint8(min(max(value, np.float32(0.0)), np.float32(255.0)))
    return out


@jit
def kinect_depth(
    depth: np.ndarray,
    noise: np.ndarray,
    quantise: bool,
    focal_baseline: float,
    step: float,
    near: np.float32,
    far: np.float32,
    dropped: np.ndarray,
) -> np.ndarray:
    """``SensorModel.depth`` after the delay's shift: Kinect v1 axial noise
    (``noise * kinect_sigma(z)``; ``noise`` empty for none), disparity quantisation, no
    reading outside [near, far] or where ``dropped`` (edge dropout; empty for none), float32."""
    height, width = depth.shape
    out = np.empty((height, width), np.float32)
    noisy = noise.size > 0
    edges = dropped.size > 0
    for row in range(height):
        for col in range(width):
            d = depth[row, col]
            z = float(d)
            valid = z > 0 and d >= near and d <= far
            if edges and dropped[row, col]:
                valid = False
            if not valid:
                out[row, col] = np.float32(0.0)
                continue
            if noisy:
                offset = z - 0.4
                z = z + noise[row, col] * (0.0012 + 0.0019 * (offset * offset))
            if quantise:
                disparity = np.rint(focal_baseline / max(z, 1e-6) / step) * step
                z = focal_baseline / max(disparity, step)
            out[row, col] = np.float32(z)
    return out


def warm_up() -> None:
    """Every kernel on tiny inputs of the types ``generate`` passes (compiled, or loaded from
    Numba's cache)."""
    depth = np.ones((2, 2), np.float32)
    flow = flow_image(depth, np.zeros((2, 2), np.int64), 1.0, 1.0, 0.5, 0.5, np.eye(4)[None])
    u, v, du, dv = blur_shifts(flow, np.zeros(2, np.float32), np.float32(0.3))
    blur_sample(u, v, du, dv, np.float32(0.5), np.empty_like(u), np.empty_like(v))
    image, empty = np.zeros((2, 2, 3), np.float32), np.empty((0, 0, 0), np.float32)
    finish_rgb(image, np.float32(1), np.float32(1), np.empty(0, np.float32), empty, np.float32(0))
    kinect_depth(
        depth, np.empty((0, 0)), True, 43.5, 0.125, np.float32(0.4), np.float32(8), np.empty((0, 0), bool)
    )


@functools.cache
def ready() -> float:
    """``warm_up`` once per process, before the first frame (2-3 s to compile on a 2-core
    machine, announced past ``core.jit.ANNOUNCE_AFTER_S``; 0.1 s to load); its seconds."""
    return warmed("the generator's kernels", warm_up, compile_s=(2, 4))
