"""Dense maps seen from above: each map point in its colour where it is static world, in red
where it is a ghost (a moving instance's surface and no static one within the threshold), in
grey where it is neither, with the map's figures under it: method 2's two pictures of the
"residual shadows", with numbers."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from depotbench.core.files import MAX_META_BYTES, open_regular, read_json
from depotbench.eval.metrics.alignment import Similarity
from depotbench.eval.metrics.map import ReferenceClouds, map_distances

STATIC, GHOST, NEITHER = 0, 1, 2
GHOST_RGB = (0.85, 0.05, 0.05)
NEITHER_RGB = (0.6, 0.6, 0.6)


@dataclass(frozen=True)
class PlacedMap:
    """A run's map in the ground-truth frame, each point's kind, and the run's map figures."""

    title: str
    points_m: np.ndarray
    colours: np.ndarray
    kinds: np.ndarray
    figures: dict


MAP_PROPERTIES = (
    ("float", "x"),
    ("float", "y"),
    ("float", "z"),
    ("uchar", "red"),
    ("uchar", "green"),
    ("uchar", "blue"),
    ("uchar", "alpha"),
)
"""A map.ply's vertex, as ``slam.dense_map.write_ply`` writes it: 16 bytes."""


def check_map_ply(path: Path) -> None:
    """Refuse (ValueError, naming what is wrong) a map.ply that is not the binary PLY a run
    writes, whole: its header read within 4 KiB, its body exactly its vertices' bytes. A file
    cut short or edited would otherwise reach the PLY reader, which fails on it unpredictably."""
    with os.fdopen(open_regular(path, 1 << 40, "map.ply"), "rb") as handle:  # a FIFO: refused, not waited on
        head = handle.read(4096)
    end = head.find(b"end_header\n")
    if not head.startswith(b"ply\n") or end < 0:
        raise ValueError("not a binary PLY with a header (no ply ... end_header)")
    lines = [line.split() for line in head[:end].decode("ascii", "replace").splitlines()[1:]]
    if ["format", "binary_little_endian", "1.0"] not in lines:
        raise ValueError("not binary little-endian PLY")
    vertices = [line for line in lines if line[:2] == ["element", "vertex"]]
    properties = [tuple(line[1:]) for line in lines if line[:1] == ["property"]]
    if len(vertices) != 1 or len(vertices[0]) != 3 or not vertices[0][2].isdigit():
        raise ValueError("no vertex count")
    if tuple(properties) != MAP_PROPERTIES:
        raise ValueError(f"vertex properties {properties}, not a map's x, y, z and colour")
    count, size = int(vertices[0][2]), path.stat().st_size
    expected = end + len(b"end_header\n") + 16 * count
    if size != expected:
        raise ValueError(f"{size} bytes where {count} vertices take {expected}")


def placed_map(run_folder: Path, reference: ReferenceClouds, title: str) -> PlacedMap:
    """A run folder's map.ply placed by metrics.json's ``map.to_groundtruth`` and classified at
    the threshold its figures are given at."""
    figures = read_json(run_folder / "metrics.json", MAX_META_BYTES, "run's metrics.json")["map"]
    check_map_ply(run_folder / "map.ply")
    cloud = trimesh.load(run_folder / "map.ply")
    points = np.asarray(cloud.vertices, dtype=np.float64)
    return placed_points(points, np.asarray(cloud.colors)[:, :3], figures, reference, title)


def placed_points(
    points: np.ndarray, colours: np.ndarray, figures: dict, reference: ReferenceClouds, title: str
) -> PlacedMap:
    """A map's points (in the run's world, colours 0-255) placed by its figures'
    ``to_groundtruth`` and classified at the threshold they are given at."""
    moved = np.asarray(figures["to_groundtruth"])
    placed = Similarity(moved[:3, :3], moved[:3, 3], 1.0)
    distances = map_distances(points, reference, placed)
    threshold = figures["threshold_m"]
    near_moving = (distances.to_moving_m <= threshold).any(axis=1) if distances.to_moving_m.size else False
    kinds = np.where(
        distances.to_static_m <= threshold, STATIC, np.where(near_moving, GHOST, NEITHER)
    ).astype(np.uint8)
    world = points @ placed.rotation.T + placed.translation
    return PlacedMap(title, world, np.asarray(colours, dtype=np.float64)[:, :3] / 255.0, kinds, figures)


def top_views(maps: list[PlacedMap]):
    """One panel per map, side by side on shared axes, seen from above (the world's z is up),
    ghosts drawn last so that none hides under the floor."""
    from depotbench.eval.sweep.summary import pyplot

    plt = pyplot()
    fig, axes = plt.subplots(1, len(maps), figsize=(5.2 * len(maps), 5.6), sharex=True, sharey=True)
    axes = np.atleast_1d(axes)
    for ax, placed in zip(axes, maps, strict=True):
        colours = placed.colours.copy()
        colours[placed.kinds == GHOST] = GHOST_RGB
        colours[placed.kinds == NEITHER] = NEITHER_RGB
        order = np.argsort(placed.kinds == GHOST, kind="stable")  # ghosts on top
        ax.scatter(
            placed.points_m[order, 0], placed.points_m[order, 1], s=0.4, c=colours[order], linewidths=0
        )
        f = placed.figures
        ghosts = sum(f["ghosts"].values())
        ax.set_title(placed.title)
        ax.set_xlabel(
            f"ghost fraction {f['ghost_fraction']:.3f} ({ghosts:,} points)\n"
            f"F-score {f['f_score']:.3f} at {f['threshold_m'] * 100:g} cm "
            f"(accuracy {f['accuracy']:.3f}, completeness {f['completeness']:.3f})"
        )
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    return fig
