"""The depot hall: walls, racks with goods, floor props and a work desk, placed from a seed.

Pure geometry (no MuJoCo): ``plan_layout`` returns boxes with material names and
the 2D footprints that walking actors must avoid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from depotbench.sim.draws import pick
from depotbench.sim.spec import LayoutSpec

Vec3 = tuple[float, float, float]
Rect = tuple[float, float, float, float]  # x0, y0, x1, y1

CENTRAL_AREA: Rect = (-3.0, -2.4, 3.0, 3.2)
"""Kept free of floor props: where actors walk in front of the camera."""
DESK_CENTRE = (0.0, 1.6)
DESK_HALF = (0.8, 0.4)
SEAT_AREA: Rect = (-0.75, 1.95, 0.8, 2.6)
"""Behind the desk, where seated people sit."""
CHAIR_HALF_M = 0.45
"""Half the side of the square a chair takes on the floor."""


@dataclass(frozen=True)
class Piece:
    """A box or cylinder (half sizes; a cylinder's are radius, radius, half height)."""

    center: Vec3
    half_size: Vec3
    material: str
    yaw_deg: float = 0.0
    shape: str = "box"
    axes: tuple[Vec3, Vec3, Vec3] | None = None
    """Explicit local x, y, z axes in the world (walls: the textured face is local z)."""


@dataclass(frozen=True)
class StaticObject:
    """A never-moving object that carries an instance id (class priors need its class)."""

    class_name: str
    prior: str
    pieces: tuple[Piece, ...]


@dataclass(frozen=True)
class Layout:
    size: tuple[float, float]
    height: float
    world: tuple[Piece, ...]
    objects: tuple[StaticObject, ...]
    obstacles: tuple[Rect, ...]
    seats: tuple[tuple[float, float, float], ...]
    """(x, y, yaw_deg) where seated people sit, facing the desk."""
    lights: tuple[Vec3, ...]


def _footprint(center: Vec3, half: Vec3, yaw_deg: float, margin: float = 0.0) -> Rect:
    c, s = abs(math.cos(math.radians(yaw_deg))), abs(math.sin(math.radians(yaw_deg)))
    hx, hy = half[0] * c + half[1] * s + margin, half[0] * s + half[1] * c + margin
    return (center[0] - hx, center[1] - hy, center[0] + hx, center[1] + hy)


def overlaps(a: Rect, b: Rect) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _goods(
    rng: np.random.Generator,
    x0: float,
    x1: float,
    y: float,
    depth: float,
    z: float,
    max_h: float,
    along_x: bool,
    cx: float,
) -> list[Piece]:
    """Fill one shelf level with boxes, crates and sacks."""
    pieces = []
    pos = x0 + 0.05
    while pos < x1 - 0.25:
        w = float(rng.uniform(0.25, 0.6))
        if pos + w > x1:
            break
        h = float(rng.uniform(0.2, max_h))
        d = float(rng.uniform(0.35, depth))
        kind = pick(rng, ("cardboard", "crate", "sack"), p=(0.5, 0.3, 0.2))
        material = f"{kind}{int(rng.integers(0, 4))}"
        if rng.uniform() < 0.85:
            u = pos + w / 2
            centre = (u, y, z + h / 2) if along_x else (cx, u, z + h / 2)
            half = (w / 2, d / 2, h / 2) if along_x else (d / 2, w / 2, h / 2)
            pieces.append(Piece(centre, half, material, float(rng.normal(0, 3))))
        pos += w + float(rng.uniform(0.02, 0.12))
    return pieces


def _rack(rng: np.random.Generator, start: float, length: float, fixed: float, along_x: bool) -> list[Piece]:
    """A pallet rack unit: uprights, beams, shelves, goods."""
    depth, levels, height = 0.9, 4, 2.9
    pieces: list[Piece] = []

    def at(u: float, v: float, z: float) -> Vec3:
        return (u, v, z) if along_x else (v, u, z)

    def half(hu: float, hv: float, hz: float) -> Vec3:
        return (hu, hv, hz) if along_x else (hv, hu, hz)

    for u in (start + 0.04, start + length - 0.04):
        for v in (fixed - depth / 2, fixed + depth / 2):
            pieces.append(Piece(at(u, v, height / 2), half(0.04, 0.04, height / 2), "metal_blue"))
    for k in range(levels):
        z = 0.12 + k * (height - 0.2) / levels
        for v in (fixed - depth / 2, fixed + depth / 2):
            pieces.append(Piece(at(start + length / 2, v, z), half(length / 2, 0.03, 0.05), "metal_orange"))
        pieces.append(
            Piece(
                at(start + length / 2, fixed, z + 0.06),
                half(length / 2 - 0.05, depth / 2, 0.01),
                f"wood{int(rng.integers(0, 2))}",
            )
        )
        pieces += _goods(
            rng, start + 0.08, start + length - 0.08, fixed, depth, z + 0.07, 0.5, along_x, fixed
        )
    return pieces


def _desk(rng: np.random.Generator, x: float, y: float) -> tuple[list[StaticObject], Rect]:
    top_z, (hx, hy) = 0.75, DESK_HALF
    desk = [Piece((x, y, top_z - 0.02), (hx, hy, 0.02), "wood2")]
    for sx in (-1, 1):
        for sy in (-1, 1):
            desk.append(
                Piece(
                    (x + sx * (hx - 0.05), y + sy * (hy - 0.05), (top_z - 0.04) / 2),
                    (0.03, 0.03, (top_z - 0.04) / 2),
                    "metal_grey",
                )
            )
    objects = [StaticObject("desk", "potential", tuple(desk))]
    z = top_z
    objects.append(
        StaticObject(
            "laptop",
            "potential",
            (
                Piece((x - 0.6, y - 0.05, z + 0.01), (0.15, 0.11, 0.01), "metal_grey"),
                Piece((x - 0.6, y + 0.06, z + 0.11), (0.15, 0.01, 0.1), "screen0", 0.0),
            ),
        )
    )
    objects.append(
        StaticObject(
            "tv",
            "potential",
            (
                Piece((x + 0.02, y + 0.25, z + 0.3), (0.2, 0.02, 0.14), "screen1"),
                Piece((x + 0.02, y + 0.27, z + 0.08), (0.03, 0.03, 0.08), "metal_grey"),
            ),
        )
    )
    for k in range(int(rng.integers(1, 3))):
        cx, cy = x + float(rng.uniform(-0.1, 0.6)), y + float(rng.uniform(-0.3, -0.1))
        objects.append(
            StaticObject(
                "cup",
                "potential",
                (Piece((cx, cy, z + 0.05), (0.04, 0.04, 0.05), f"cardboard{k}", shape="cylinder"),),
            )
        )
    books = []
    for k in range(int(rng.integers(2, 4))):
        books.append(
            Piece(
                (x + 0.65, y - 0.1, z + 0.02 + 0.04 * k),
                (0.1, 0.14, 0.02),
                f"crate{k % 4}",
                float(rng.normal(0, 10)),
            )
        )
    objects.append(StaticObject("book", "potential", tuple(books)))
    return objects, (x - hx, y - hy, x + hx, y + hy)


@dataclass(frozen=True)
class _RackUnit:
    start: float
    length: float
    fixed: float
    along_x: bool

    @property
    def footprint(self) -> Rect:
        a, b = (self.start, self.fixed - 0.5), (self.start + self.length, self.fixed + 0.5)
        return (a[0], a[1], b[0], b[1]) if self.along_x else (a[1], a[0], b[1], b[0])


def _rack_units(spec: LayoutSpec) -> list[_RackUnit]:
    """Where the rack units stand: rows along the walls, a function of the layout spec alone."""
    sx, sy = spec.hall_size_m[0] / 2, spec.hall_size_m[1] / 2
    rows = [(True, sy - 0.6), (False, -sx + 0.6), (False, sx - 0.6), (True, sy - 2.4)]
    units = []
    for along_x, fixed in rows[: spec.rack_rows]:
        span = 2 * (sx if along_x else sy) - 2.0
        unit = min(2.6, span / max(1, spec.racks_per_row))
        start0 = -unit * spec.racks_per_row / 2
        for k in range(spec.racks_per_row):
            start = start0 + k * unit
            if not along_x and start + unit > sy - 1.2:
                continue
            units.append(_RackUnit(start, unit, fixed, along_x))
    return units


def fixed_footprints(spec: LayoutSpec) -> list[tuple[str, Rect]]:
    """The floor areas that racks, the desk and its seats take, whatever the seed."""
    found = [("a rack", unit.footprint) for unit in _rack_units(spec)]
    if spec.desk:
        x, y = DESK_CENTRE
        found.append(("the desk", (x - DESK_HALF[0], y - DESK_HALF[1], x + DESK_HALF[0], y + DESK_HALF[1])))
        found.append(("the desk's seats", SEAT_AREA))
    return found


def plan_layout(spec: LayoutSpec, rng: np.random.Generator, keep_out: tuple[Rect, ...] = ()) -> Layout:
    """Walls, racks along the walls, floor props outside the central area, and a desk.

    Floor props also stay out of ``keep_out`` (the chairs' footprints).
    """
    sx, sy = spec.hall_size_m[0] / 2, spec.hall_size_m[1] / 2
    h = spec.hall_height_m
    world: list[Piece] = [
        Piece((0.0, 0.0, -0.05), (sx, sy, 0.05), "floor"),
        Piece((0.0, 0.0, h + 0.05), (sx, sy, 0.05), "ceiling"),
        Piece(
            (0.0, sy + 0.05, h / 2),
            (sx, h / 2, 0.05),
            "wall0",
            axes=((1, 0, 0), (0, 0, 1), (0, -1, 0)),
        ),
        Piece(
            (0.0, -sy - 0.05, h / 2),
            (sx, h / 2, 0.05),
            "wall1",
            axes=((-1, 0, 0), (0, 0, 1), (0, 1, 0)),
        ),
        Piece(
            (sx + 0.05, 0.0, h / 2),
            (sy, h / 2, 0.05),
            "wall2",
            axes=((0, -1, 0), (0, 0, 1), (-1, 0, 0)),
        ),
        Piece(
            (-sx - 0.05, 0.0, h / 2),
            (sy, h / 2, 0.05),
            "wall1",
            axes=((0, 1, 0), (0, 0, 1), (1, 0, 0)),
        ),
    ]
    obstacles: list[Rect] = []
    for unit in _rack_units(spec):
        world += _rack(rng, unit.start, unit.length - 0.1, unit.fixed, unit.along_x)
        obstacles.append(unit.footprint)
    objects: list[StaticObject] = []
    seats: tuple[tuple[float, float, float], ...] = ()
    if spec.desk:
        desk_objects, desk_rect = _desk(rng, *DESK_CENTRE)
        objects += desk_objects
        obstacles.append(desk_rect)
        # Turned 30 degrees towards each other, as two people talking sit: the camera
        # sees them in a 3/4 view (YOLOX-nano found people squarely facing it across the
        # desk in 0.57 of frames, turned ones in 0.86; benchmarks/recognition.py).
        seats = ((-0.4, 2.25, -60.0), (0.45, 2.25, -120.0))
        obstacles.append(SEAT_AREA)
    placed = 0
    for _ in range(200 * max(1, spec.floor_props)):
        if placed >= spec.floor_props:
            break
        centre = (float(rng.uniform(-sx + 1.2, sx - 1.2)), float(rng.uniform(-sy + 1.0, sy - 1.2)))
        yaw = float(rng.uniform(0, 90))
        rect = _footprint((*centre, 0.0), (0.6, 0.5, 0.0), yaw, margin=0.25)
        if overlaps(rect, CENTRAL_AREA) or any(overlaps(rect, o) for o in (*obstacles, *keep_out)):
            continue
        world.append(Piece((*centre, 0.07), (0.6, 0.5, 0.07), "wood1", yaw))
        z = 0.14
        for _ in range(int(rng.integers(1, 4))):
            hz = float(rng.uniform(0.15, 0.35))
            kind = pick(rng, ("crate", "sack", "cardboard"))
            world.append(
                Piece(
                    (*centre, z + hz),
                    (float(rng.uniform(0.35, 0.55)), float(rng.uniform(0.3, 0.45)), hz),
                    f"{kind}{int(rng.integers(0, 4))}",
                    yaw + float(rng.normal(0, 4)),
                )
            )
            z += 2 * hz
        obstacles.append(rect)
        placed += 1
    lights = tuple((x, y, h - 0.1) for x in (-sx / 2, sx / 2) for y in (-sy / 2, sy / 2))
    for lx, ly, lz in lights:
        world.append(Piece((lx, ly, lz + 0.05), (0.6, 0.15, 0.03), "lamp"))
    return Layout((2 * sx, 2 * sy), h, tuple(world), tuple(objects), tuple(obstacles), seats, lights)


def is_free(point: np.ndarray, obstacles: tuple[Rect, ...], margin: float, bounds: Rect) -> bool:
    x, y = float(point[0]), float(point[1])
    if not (bounds[0] + margin <= x <= bounds[2] - margin and bounds[1] + margin <= y <= bounds[3] - margin):
        return False
    return not any(o[0] - margin < x < o[2] + margin and o[1] - margin < y < o[3] + margin for o in obstacles)
