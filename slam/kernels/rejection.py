"""Compiled tests of method 3 (``depotbench.slam.rejection``): each tracked point's distance to
its epipolar line and flow magnitude, and the 2-sigma / L_thr1-L_thr2 flow-outlier test.

Each is one pass over the points where the reference makes ~10 array operations; the
fundamental-matrix RANSAC before them stays in OpenCV.
"""

from __future__ import annotations

import math

import numpy as np
from depotbench.core.jit import jit


@jit
def epipolar_geometry(
    fundamental: np.ndarray, previous_px: np.ndarray, current_px: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(distance of each current point to the epipolar line F x_previous, flow magnitude);
    the distances are empty when ``fundamental`` is (RANSAC found no F)."""
    n = len(current_px)
    magnitude = np.empty(n)
    for i in range(n):
        dx, dy = current_px[i, 0] - previous_px[i, 0], current_px[i, 1] - previous_px[i, 1]
        magnitude[i] = math.sqrt(dx * dx + dy * dy)
    if fundamental.size == 0:
        return np.empty(0), magnitude
    distance = np.empty(n)
    f = fundamental
    for i in range(n):
        x, y = previous_px[i, 0], previous_px[i, 1]
        a = x * f[0, 0] + y * f[0, 1] + f[0, 2]
        b = x * f[1, 0] + y * f[1, 1] + f[1, 2]
        c = x * f[2, 0] + y * f[2, 1] + f[2, 2]
        distance[i] = abs(a * current_px[i, 0] + b * current_px[i, 1] + c) / max(math.hypot(a, b), 1e-12)
    return distance, magnitude


@jit
def flow_outliers(magnitude: np.ndarray, sigma_factor: float, l_thr1: float, l_thr2: float) -> np.ndarray:
    """Points whose flow magnitude is off the mean by more than ``sigma_factor`` standard
    deviations, or by more than ``l_thr1`` while the deviation is below ``l_thr2``."""
    n = len(magnitude)
    mean = magnitude.mean()
    spread = 0.0
    for i in range(n):
        spread += (magnitude[i] - mean) * (magnitude[i] - mean)
    std = math.sqrt(spread / n)
    out = np.empty(n, np.bool_)
    for i in range(n):
        deviation = abs(magnitude[i] - mean)
        out[i] = deviation > sigma_factor * std or (deviation > l_thr1 and std < l_thr2)
    return out
