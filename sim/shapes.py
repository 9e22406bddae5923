"""Signed-distance shapes and their meshing: the bodies of people and animals.

A figure is a field built from a few primitives (ellipsoids, round cones) joined
by smooth unions, so shoulders, neck and hips blend as on a real body. It is
meshed with marching cubes (PyMCubes) into closed triangle meshes, one per rigid
part and material, which MuJoCo draws as ordinary mesh geoms: every pixel then
belongs to one rigid body, so masks and optical flow stay exact. Marching cubes
spends most triangles on flat stretches; quadric decimation (fast-simplification)
keeps a fifth of them where they shape the surface, which is what a CPU renderer
pays for in every pass (benchmarks/generation.py).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import fast_simplification
import mcubes
import numpy as np
import trimesh
from depotbench.sim.products import product

Field = Callable[[np.ndarray], np.ndarray]
"""Signed distance (negative inside) at points (N, 3)."""

KEEP_FACES = 0.2
"""Share of marching cubes' triangles a mesh keeps after decimation."""
FAR_KEEP_FACES = 0.08
"""Share of marching cubes' triangles a mesh's far version keeps. Its edges are about
1.6 times the near version's (the square root of 0.2 / 0.08); drawn beyond
``depotbench.sim.render.FAR_M`` (3 m), they are about as long on screen as the near version's at
2 m (benchmarks/render.py --far-from)."""
MIN_FACES = 48
"""Meshes with fewer triangles than this after decimation are kept whole."""
FAR = 1.0
"""What a shape reports at points it cannot reach (metres; only the sign matters there)."""


@dataclass(frozen=True)
class Shape:
    """A field with the box that holds its inside, so unions skip the far members."""

    field: Field
    lower: np.ndarray
    upper: np.ndarray

    def __call__(self, p: np.ndarray) -> np.ndarray:
        return self.field(p)

    def near(self, lower: np.ndarray, upper: np.ndarray, margin: float) -> bool:
        return bool(np.all(self.lower - margin <= upper) and np.all(lower <= self.upper + margin))


def _norm(v: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("ij,ij->i", v, v))


def ellipsoid(
    centre: tuple[float, ...] | np.ndarray,
    radii: tuple[float, ...] | np.ndarray,
    axes: np.ndarray | None = None,
) -> Shape:
    """An ellipsoid, its radii along the columns of ``axes`` (default: x, y, z).

    Quilez's bound: exact on the surface, close to the distance near it."""
    c, r = np.asarray(centre, float), np.asarray(radii, float)
    rotation = np.eye(3) if axes is None else np.asarray(axes, float)
    turned = axes is not None  # the identity's product is the points themselves

    def field(p: np.ndarray) -> np.ndarray:
        q = product(p - c, rotation) if turned else p - c
        k0 = _norm(q / r)
        k1 = np.maximum(_norm(q / (r * r)), 1e-12)
        return k0 * (k0 - 1.0) / k1

    half = product(np.abs(rotation), r)
    return Shape(field, c - half, c + half)


def round_cone(a: np.ndarray, b: np.ndarray, ra: float, rb: float) -> Shape:
    """A capsule whose radius goes from ``ra`` at ``a`` to ``rb`` at ``b`` (limbs)."""
    a, b = np.asarray(a, float), np.asarray(b, float)

    def field(p: np.ndarray) -> np.ndarray:
        ab = b - a
        pa = p - a
        t = np.clip(product(pa, ab) / max(ab @ ab, 1e-12), 0.0, 1.0)
        return _norm(pa - t[:, None] * ab) - (ra + (rb - ra) * t)

    r = max(ra, rb)
    return Shape(field, np.minimum(a, b) - r, np.maximum(a, b) + r)


def segment_distance(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> np.ndarray:
    ab = np.asarray(b, float) - np.asarray(a, float)
    pa = p - a
    t = np.clip(product(pa, ab) / max(ab @ ab, 1e-12), 0.0, 1.0)
    return _norm(pa - t[:, None] * ab)


def cut(shape: Shape, region: Field) -> Shape:
    """The part of ``shape`` where ``region`` is negative."""
    return Shape(lambda p: np.maximum(shape(p), region(p)), shape.lower, shape.upper)


_last = threading.local()
"""Per thread: the last points ``_bounds`` was asked about, and their box."""


def _bounds(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box of points ``p``. Nested unions ask it of the same points again and again:
    computing it once took a tenth off building a crowd's figures (same meshes). Only
    read-only points (``Grid``'s) are remembered: others could change in place."""
    last = getattr(_last, "bounds", None)
    if last is not None and last[0] is p:
        return last[1]
    bounds = p.min(axis=0), p.max(axis=0)
    if not p.flags.writeable:
        _last.bounds = (p, bounds)
    return bounds


def smooth_union(shapes: list[Shape], k: float) -> Shape:
    """Polynomial smooth minimum: surfaces closer than ``k`` blend into one. Members
    more than ``k`` from the points asked cannot change the surface and are skipped."""

    def field(p: np.ndarray) -> np.ndarray:
        lower, upper = _bounds(p)
        d = None
        for shape in shapes:
            if not shape.near(lower, upper, k):
                continue
            e = shape(p)
            if d is None:
                d = e
                continue
            h = np.maximum(k - np.abs(d - e), 0.0) / k
            d = np.minimum(d, e) - h * h * k / 4.0
        return np.full(len(p), FAR) if d is None else d

    return Shape(field, np.min([s.lower for s in shapes], axis=0), np.max([s.upper for s in shapes], axis=0))


def union(shapes: list[Shape]) -> Shape:
    return smooth_union(shapes, 1e-9)


@dataclass(frozen=True)
class Mesh:
    """A closed triangle mesh: vertices (V, 3) float, faces (F, 3) int, counter-clockwise."""

    vertices: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True)
class Grid:
    """Sample points of a box, padded by two cells so that surfaces inside it close."""

    lower: np.ndarray
    step: float
    shape: tuple[int, int, int]
    points: np.ndarray

    @staticmethod
    def around(lower: np.ndarray, upper: np.ndarray, step: float) -> Grid:
        lower = np.asarray(lower, float) - 2 * step
        upper = np.asarray(upper, float) + 2 * step
        counts = np.maximum(np.ceil((upper - lower) / step).astype(int) + 1, 2)
        axes = [lower[i] + step * np.arange(counts[i]) for i in range(3)]
        points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        points.flags.writeable = False  # fixed: fields may keep what they learnt of them (_bounds)
        return Grid(lower, step, (int(counts[0]), int(counts[1]), int(counts[2])), points)

    def mesh(self, values: np.ndarray) -> Mesh | None:
        """The zero surface of signed distances sampled at ``points``; None if nothing is inside."""
        values = values.reshape(self.shape).copy()
        values[[0, -1]] = values[:, [0, -1]] = values[:, :, [0, -1]] = self.step  # closed at the box
        if (values < 0).sum() < 8:
            return None
        vertices, faces = mcubes.marching_cubes(-values, 0.0)
        if len(faces) == 0:
            return None
        vertices = self.lower + vertices * self.step
        faces = faces.astype(np.int32)
        a, b, c = (vertices[faces[:, i]] for i in range(3))
        if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() < 0:  # outward normals, positive volume
            faces = faces[:, ::-1].copy()
        return decimate(Mesh(vertices.astype(np.float64), faces))


AGGRESSIVENESS = (7, 5, 3)
"""fast-simplification's ``agg`` values tried in turn, gentler each time, until the mesh
stays closed: its default, 7, alone opens about one mesh in 18 of the figures', and an
open mesh is drawn whole, undecimated, in every render pass."""


def decimate(mesh: Mesh, keep: float | None = None) -> Mesh:
    """The mesh with about ``keep`` of its triangles (quadric error collapses), at the
    first aggressiveness that leaves it closed; failing that, with twice as many (a
    handle, as a curled pig tail has, can close up below that); the mesh itself where
    that would leave it tiny or where every try opens it. ``keep`` defaults to
    ``KEEP_FACES`` as it is when called (benchmarks/render.py varies it)."""
    target = int(len(mesh.faces) * (KEEP_FACES if keep is None else keep))
    if target < MIN_FACES:
        return mesh
    for count in (target, 2 * target):
        for agg in AGGRESSIVENESS:
            vertices, faces = fast_simplification.simplify(
                mesh.vertices, mesh.faces, target_count=count, agg=agg
            )
            if trimesh.Trimesh(vertices, faces, process=False).is_watertight:
                return Mesh(vertices.astype(np.float64), faces.astype(np.int32))
    return mesh


def far_version(mesh: Mesh) -> Mesh | None:
    """``mesh`` (kept at ``KEEP_FACES``) cut down to ``FAR_KEEP_FACES``; None where that
    leaves nothing to gain (a small piece, or one decimation would open)."""
    far = decimate(mesh, FAR_KEEP_FACES / KEEP_FACES)
    return None if far is mesh else far


def mesh_field(field: Field, lower: np.ndarray, upper: np.ndarray, step: float) -> Mesh | None:
    """The zero surface of ``field`` inside the box [lower, upper], sampled every ``step``."""
    grid = Grid.around(lower, upper, step)
    return grid.mesh(field(grid.points))
