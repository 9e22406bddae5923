"""Smooth closed walking paths, parametrised by arc length, and their seeded generation."""

from __future__ import annotations

import bisect
import math

import numpy as np
from depotbench.core.errors import ScenarioError
from depotbench.sim.layout import Rect, is_free
from numpy.lib.stride_tricks import sliding_window_view

SAMPLE_SPACING_M = 0.05


class Path:
    """A closed, smoothed loop through waypoints; ``point(s)`` wraps around."""

    def __init__(self, waypoints: np.ndarray, smoothing_m: float = 0.8) -> None:
        pts = np.asarray(waypoints, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2 or not np.isfinite(pts).all():
            raise ValueError("a path needs at least two finite (x, y) waypoints")
        # A waypoint repeated in a row adds a leg of length zero: drop it.
        step = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1)
        pts = pts[step > 1e-9]
        if len(pts) < 2:
            raise ValueError("a path needs two distinct waypoints")
        loop = np.vstack([pts, pts[:1]])
        dense = [loop[0]]
        for a, b in zip(loop[:-1], loop[1:], strict=True):
            n = max(1, math.ceil(_length(b - a) / SAMPLE_SPACING_M))
            dense += list(a + (b - a) * (np.arange(1, n + 1)[:, None] / n))
        dense_arr = np.array(dense[:-1])
        window = max(1, int(smoothing_m / SAMPLE_SPACING_M))
        if len(dense_arr) > 2 * window + 1:
            # A moving mean, not np.convolve: convolve sums through BLAS (ddot), whose
            # kernels OpenBLAS picks by CPU, so the walkers' paths differed in their last
            # bits from one CPU type to another (tests/test_sim.py); a reduction's
            # summation order is numpy's own.
            padded = np.vstack([dense_arr[-window:], dense_arr, dense_arr[:window]])
            dense_arr = sliding_window_view(padded, 2 * window + 1, axis=0).mean(axis=-1)
        closed = np.vstack([dense_arr, dense_arr[:1]])
        self._points = closed
        self._arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
        self.length = float(self._arc[-1])
        self._arc_list = self._arc.tolist()
        self._xy_lists = (closed[:, 0].tolist(), closed[:, 1].tolist())

    def point(self, s: float | np.ndarray) -> np.ndarray:
        if np.ndim(s) == 0:
            return np.array(self._point_at(float(s)))
        s = np.mod(s, self.length)
        return np.stack([np.interp(s, self._arc, self._points[:, k]) for k in (0, 1)], axis=-1)

    def tangent(self, s: float | np.ndarray) -> np.ndarray:
        if np.ndim(s) == 0:
            (x1, y1), (x0, y0) = self._point_at(float(s) + 0.02), self._point_at(float(s) - 0.02)
            dx, dy = x1 - x0, y1 - y0
            norm = math.sqrt(dx * dx + dy * dy)
            return np.array([dx / norm, dy / norm])
        d = self.point(np.asarray(s) + 0.02) - self.point(np.asarray(s) - 0.02)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def _point_at(self, s: float) -> tuple[float, float]:
        """``point`` of one arc length with Python floats: a walker's pose asks for dozens a
        frame, and numpy's per-call overhead was most of their cost. The same arithmetic as
        np.interp's (and np.mod's, np.linalg.norm's in ``tangent``), so the same bits
        (tests/test_sim.py checks them against numpy)."""
        s %= self.length
        arc = self._arc_list
        j = bisect.bisect_right(arc, s) - 1
        if j >= len(arc) - 1:
            return self._xy_lists[0][-1], self._xy_lists[1][-1]
        if arc[j] == s:
            return self._xy_lists[0][j], self._xy_lists[1][j]
        out = []
        for fp in self._xy_lists:
            slope = (fp[j + 1] - fp[j]) / (arc[j + 1] - arc[j])
            value = slope * (s - arc[j]) + fp[j]
            if math.isnan(value):  # as np.interp: from the other end, then the flat value
                value = slope * (s - arc[j + 1]) + fp[j + 1]
                if math.isnan(value) and fp[j] == fp[j + 1]:
                    value = fp[j]
            out.append(value)
        return out[0], out[1]

    def heading(self, s: float | np.ndarray) -> np.ndarray:
        t = self.tangent(s)
        return np.arctan2(t[..., 1], t[..., 0])


def _length(d: np.ndarray) -> float:
    """A 2-vector's length as np.linalg.norm gives it (the same bits on 800,000 vectors),
    without its trip through BLAS, whose kernels differ from one CPU type to another."""
    return math.sqrt(d[0] * d[0] + d[1] * d[1])


def _segment_free(
    a: np.ndarray, b: np.ndarray, obstacles: tuple[Rect, ...], margin: float, bounds: Rect
) -> bool:
    n = max(2, int(_length(b - a) / 0.1))
    return all(is_free(a + (b - a) * k / n, obstacles, margin, bounds) for k in range(n + 1))


def plan_loop(
    rng: np.random.Generator,
    region: Rect,
    obstacles: tuple[Rect, ...],
    bounds: Rect,
    n_points: int,
    margin: float = 0.45,
    tries: int = 400,
) -> np.ndarray:
    """Waypoints of a loop inside ``region`` whose legs keep ``margin`` from every obstacle.

    Points are ordered by angle about their centroid, so the loop does not cross itself
    and, with a region in front of the camera, crosses the camera's view.
    """
    for _ in range(tries):
        pts = []
        for _ in range(40 * n_points):
            p = np.array([rng.uniform(region[0], region[2]), rng.uniform(region[1], region[3])])
            if is_free(p, obstacles, margin, bounds):
                pts.append(p)
            if len(pts) == n_points:
                break
        if len(pts) < n_points:
            continue
        arr = np.array(pts)
        centre = arr.mean(axis=0)
        arr = arr[np.argsort(np.arctan2(arr[:, 1] - centre[1], arr[:, 0] - centre[0]))]
        if min(np.linalg.norm(np.roll(arr, -1, axis=0) - arr, axis=1)) < 0.8:
            continue
        if all(
            _segment_free(a, b, obstacles, margin, bounds)
            for a, b in zip(arr, np.roll(arr, -1, axis=0), strict=True)
        ):
            return arr
    raise ScenarioError(
        f"actors: could not place a free walking loop in region {region} after {tries} tries; "
        "lower layout.props or give the actor waypoints"
    )
