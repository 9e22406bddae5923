"""Smooth closed walking paths, parametrised by arc length, and their seeded generation."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np
from depotbench.core.errors import ScenarioError
from depotbench.sim.layout import Rect, is_free, overlaps
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


class OpenPath:
    """A smoothed polyline from its first waypoint to its last, parametrised by arc
    length: one leg of an errand (``plan_errands``). Unlike ``Path`` it does not close,
    and it starts and ends exactly at its end points with the tangents of its first and
    last legs, so consecutive legs join where a person stopped."""

    def __init__(self, waypoints: np.ndarray, smoothing_m: float = 0.6) -> None:
        pts = np.asarray(waypoints, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2 or not np.isfinite(pts).all():
            raise ValueError("a path needs at least two finite (x, y) waypoints")
        step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        pts = np.vstack([pts[:1], pts[1:][step > 1e-9]])
        if len(pts) < 2:
            raise ValueError("a path needs two distinct waypoints")
        dense = [pts[0]]
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            n = max(1, math.ceil(_length(b - a) / SAMPLE_SPACING_M))
            dense += list(a + (b - a) * (np.arange(1, n + 1)[:, None] / n))
        dense_arr = np.array(dense)
        window = max(1, int(smoothing_m / SAMPLE_SPACING_M))
        if len(dense_arr) > 2 * window + 1:
            # Padded by point reflection through each end point: a centred mean there is
            # the end point itself, so the path keeps its ends (a moving mean, not
            # np.convolve, for the reason ``Path`` gives).
            head = 2 * dense_arr[0] - dense_arr[window:0:-1]
            tail = 2 * dense_arr[-1] - dense_arr[-2 : -window - 2 : -1]
            padded = np.vstack([head, dense_arr, tail])
            dense_arr = sliding_window_view(padded, 2 * window + 1, axis=0).mean(axis=-1)
        self._points = dense_arr
        self._arc = np.concatenate([[0.0], np.cumsum([_length(d) for d in np.diff(dense_arr, axis=0)])])
        self.length = float(self._arc[-1])

    def point(self, s: float | np.ndarray) -> np.ndarray:
        s = np.clip(s, 0.0, self.length)
        return np.stack([np.interp(s, self._arc, self._points[:, k]) for k in (0, 1)], axis=-1)

    def tangent(self, s: float | np.ndarray) -> np.ndarray:
        """Unit direction of travel; at and beyond an end, the end's own."""
        s = np.clip(s, 0.02, max(self.length - 0.02, 0.02))
        d = self.point(np.asarray(s) + 0.02) - self.point(np.asarray(s) - 0.02)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def heading(self, s: float | np.ndarray) -> np.ndarray:
        t = self.tangent(s)
        return np.arctan2(t[..., 1], t[..., 0])


ERRAND_MARGIN_M = 0.45
"""Clearance of a walking person's centre from furniture: half a shoulder width (0.23 m
for a 1.75 m adult) plus the swing of the arms and the path's smoothing of corners."""
SIT_FROM_M = (0.35, 0.15)
"""A person sits down from beside the seat, this far along the desk and back from it:
the desk leaves no room in front of a seat tucked 0.25 m behind its edge."""


def _route(
    a: np.ndarray,
    b: np.ndarray,
    corners: list[np.ndarray],
    obstacles: tuple[Rect, ...],
    bounds: Rect,
    seen: dict[tuple[float, ...], bool],
) -> list[np.ndarray]:
    """The shortest way from ``a`` to ``b`` over ``corners`` (a visibility graph round the
    desk) whose straight legs keep ``ERRAND_MARGIN_M`` from every obstacle; [a, b] when
    none is found. ``seen`` remembers the legs checked (corner to corner, mostly)."""
    nodes = [a, b, *corners]
    n = len(nodes)
    best = [math.inf] * n
    came: list[int | None] = [None] * n
    best[0] = 0.0
    todo = set(range(n))
    while todo:
        i = min(todo, key=lambda k: best[k])
        todo.discard(i)
        if i == 1 or best[i] == math.inf:
            break
        for j in todo:
            key = (*nodes[i], *nodes[j])
            if key not in seen:
                seen[key] = _segment_free(nodes[i], nodes[j], obstacles, ERRAND_MARGIN_M - 0.05, bounds)
            if seen[key]:
                d = best[i] + _length(nodes[j] - nodes[i])
                if d < best[j]:
                    best[j], came[j] = d, i
    if best[1] == math.inf:
        return [a, b]
    route, k = [], 1
    while k is not None:
        route.append(nodes[k])
        k = came[k]
    return route[::-1]


SIT_EVERY_S = 12.0
"""A walker goes to sit down at the latest this long after it last stood up: TUM's
walking sequences (24-36 s) each show both people sitting at the desk at least once."""
SIT_S = (3.0, 8.0)
"""How long a walker stays seated: 'a few seconds' in TUM's walking sequences."""
SHARES = (0.2, 0.12, 0.75)
"""Chances that a walker's next errand is to sit down, to leave the view; and that an
errand in view is between the camera and the desk rather than anywhere about the desk:
TUM's walkers are mostly in the middle of the picture, in front of the desk."""
TURN_MAX_DEG = 110.0
"""Sharpest turn at an errand's target: a smoothed U-turn would spin the person on the spot."""


@dataclass(frozen=True)
class Walk:
    """One stretch of walking without stopping, and how long the person then sits (0:
    the stretch runs past the end of the sequence)."""

    waypoints: np.ndarray
    speed_mps: float
    sit_s: float


def _draw_free(
    rng: np.random.Generator, region: Rect, obstacles: tuple[Rect, ...], bounds: Rect
) -> np.ndarray:
    for _ in range(200):
        p = np.array([rng.uniform(region[0], region[2]), rng.uniform(region[1], region[3])])
        if is_free(p, obstacles, ERRAND_MARGIN_M, bounds):
            return p
    raise ScenarioError(
        f"actors: no free floor for a tum_walk in region {region}; clear the desk's surroundings"
    )


def _turn_deg(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    u, v = b - a, c - b
    # Written out, not np.dot: a dot product goes through BLAS, whose kernels differ in
    # their last bits from one CPU type to another (see ``Path``).
    cos = (u[0] * v[0] + u[1] * v[1]) / max(_length(u) * _length(v), 1e-9)
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))


def _sharpest_turn(points: list[np.ndarray]) -> float:
    return max(
        (_turn_deg(a, b, c) for a, b, c in zip(points, points[1:], points[2:], strict=False)), default=0.0
    )


def _round_turns(points: list[np.ndarray], obstacles: tuple[Rect, ...], bounds: Rect) -> list[np.ndarray]:
    """``points`` with each turn sharper than ``TURN_MAX_DEG`` walked as a teardrop: out
    to one side and round, as a person turning back mid-stride does (a smoothed U-turn
    would flip the heading on the spot). Each loop is 0.7 m wide, on a side it fits."""
    out = [points[0]]
    for a, b, c in zip(points, points[1:], points[2:], strict=False):
        out.append(b)
        if _turn_deg(a, b, c) <= TURN_MAX_DEG:
            continue
        d_in = (b - a) / max(_length(b - a), 1e-9)
        d_out = c - b
        cross = d_in[0] * d_out[1] - d_in[1] * d_out[0]
        for side in (1.0, -1.0) if cross >= 0 else (-1.0, 1.0):
            perp = side * np.array([-d_in[1], d_in[0]])
            loop = [b + 0.7 * (0.7 * d_in + 0.7 * perp), b + 0.7 * 1.4 * perp]
            legs = zip([b, *loop], [*loop, c], strict=True)
            if all(_segment_free(p, q, obstacles, ERRAND_MARGIN_M - 0.1, bounds) for p, q in legs):
                out += loop
                break
    out.append(points[-1])
    return out


def plan_errands(
    rng: np.random.Generator,
    seat: tuple[float, float, float],
    desk: Rect,
    obstacles: tuple[Rect, ...],
    bounds: Rect,
    duration_s: float,
    speed_mps: float,
) -> list[Walk]:
    """A TUM walker's errands over ``duration_s`` (and 3 s beyond): walks across the view
    in front of and beside the desk, now and then out of the view at either side and back,
    and to ``seat`` (x, y, yaw_deg) to sit there for ``SIT_S`` seconds, sitting down from
    beside it (``SIT_FROM_M``).

    The desk's front edge faces the camera (-y), as in TUM's fr3 office: the view band
    spans the desk's width plus 1.1 m each side, from 1 m in front of it to 1.2 m past its
    front edge; out of view is 1.6-2.2 m beyond the desk's ends.
    """
    x0, y0, x1, y1 = desk
    cx = (x0 + x1) / 2
    # Errands stay within 3 m of the desk: farther furniture (racks along the walls) cannot
    # be in the way, and checking every leg against it was most of the planning time.
    obstacles = tuple(o for o in obstacles if overlaps(o, (x0 - 4.5, y0 - 3.5, x1 + 4.5, y1 + 4.5)))
    in_view = (x0 - 1.1, y0 - 1.0, x1 + 1.1, y0 + 1.2)
    in_front = (x0 - 0.6, y0 - 0.8, x1 + 0.6, y0 - ERRAND_MARGIN_M)
    corners = [
        np.array([x, y])
        for o in obstacles
        if overlaps(o, (x0 - 3.0, y0 - 2.0, x1 + 3.0, y1 + 3.0))
        for x in (o[0] - ERRAND_MARGIN_M - 0.05, o[2] + ERRAND_MARGIN_M + 0.05)
        for y in (o[1] - ERRAND_MARGIN_M - 0.05, o[3] + ERRAND_MARGIN_M + 0.05)
        if is_free(np.array([x, y]), obstacles, ERRAND_MARGIN_M, bounds)
    ]
    side = 1.0 if seat[0] >= cx else -1.0
    seat_xy = np.array(seat[:2])
    stand = seat_xy + np.array([side * SIT_FROM_M[0], SIT_FROM_M[1]])
    approach = stand.copy()
    while not is_free(approach, obstacles, ERRAND_MARGIN_M, bounds):
        approach[0] += side * 0.05
        if abs(approach[0] - seat_xy[0]) > 4.0:
            raise ScenarioError(f"actors: no free way to the seat at {seat_xy.tolist()} along the desk")
    walks: list[Walk] = []
    seen: dict[tuple[float, ...], bool] = {}
    here = _draw_free(rng, in_view, obstacles, bounds)
    points, t, since_sit, out = [here], 0.0, 0.0, False
    speed = speed_mps * float(rng.uniform(0.85, 1.15))
    while t < duration_s + 3.0:
        u = float(rng.uniform())
        if not out and len(points) > 2 and (since_sit >= SIT_EVERY_S or u < SHARES[0]):
            route = _route(here, approach, corners, obstacles, bounds, seen)
            leg = [*route, stand]
            points += leg[1:]
            sit_s = float(rng.uniform(*SIT_S))
            length = sum(_length(b - a) for a, b in zip(leg[:-1], leg[1:], strict=True))
            walks.append(Walk(np.array(_round_turns(points, obstacles, bounds)), speed, sit_s))
            t += length / speed + sit_s + 2.4
            since_sit, here = 0.0, stand
            points = [stand, approach]
            speed = speed_mps * float(rng.uniform(0.85, 1.15))
            continue
        leave = not out and u < SHARES[0] + SHARES[1]
        region = (
            (x1 + 1.6, y0 - 0.8, x1 + 2.2, y0 + 1.4)
            if leave and rng.uniform() < 0.5
            else (x0 - 2.2, y0 - 0.8, x0 - 1.6, y0 + 1.4)
            if leave
            else in_front
            if rng.uniform() < SHARES[2]
            else in_view
        )
        for _ in range(30):
            target = _draw_free(rng, region, obstacles, bounds)
            route = _route(points[-1], target, corners, obstacles, bounds, seen)
            if (
                _length(target - points[-1]) > 1.0
                and _sharpest_turn([*points[-2:], *route[1:]]) <= TURN_MAX_DEG
            ):
                break
        step = sum(_length(b - a) for a, b in zip(route[:-1], route[1:], strict=True))
        points += route[1:]
        t += step / speed
        since_sit += step / speed
        here, out = target, leave
    walks.append(Walk(np.array(_round_turns(points, obstacles, bounds)), speed, 0.0))
    return walks
