"""Dense-map cost per keyframe: slam.dense_map.DenseMap beside plain back-projection.

Usage: python benchmarks/dense_map.py [--keyframes 30] [--voxel 0.02] [--fr1] [--width 640 --height 480]

Renders N keyframes of a box room (6 x 3 x 6 m, a checker texture) by ray casting from a camera
circling its middle while it turns, then, in this run on one core: the dense map (back-projection,
voxel merge) and its peer, the plain back-projection into the world that keeps every point (no
voxel merge). Prints per keyframe the mean and last milliseconds, the memory each holds after N
keyframes divided by N, the dense map's largest transient allocation in one keyframe
(tracemalloc), and the ratios. ``--fr1`` uses TUM fr1's distorted camera. Figures are printed,
never asserted.
"""

from __future__ import annotations

import argparse
import os
import time
import tracemalloc

os.environ.setdefault("OMP_NUM_THREADS", "1")

# depotbench first: numpy then runs the bench's code for the CPU (core/numerics.py)
import depotbench  # isort: skip  # noqa: E402, F401
import cv2  # noqa: E402
import numpy as np  # noqa: E402
from depotbench.core.camera import Intrinsics  # noqa: E402
from depotbench.sim.camera import TUM_FREIBURG  # noqa: E402
from depotbench.slam.dense_map import DenseMap, DenseMapConfig, back_project, pixel_rays  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

ROOM = np.array([3.0, 1.5, 3.0])
"""Half-sizes of the room (x, y, z), metres: its far corners lie within the default 5 m range."""

MB = 1e6


def _keyframes(camera: Intrinsics, n: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(world_from_camera, rgb, depth) of n views of the room: a 0.5 m circle, half a turn."""
    rays = pixel_rays(camera)
    directions = np.concatenate([rays, np.ones((*rays.shape[:2], 1))], axis=-1)
    frames = []
    for i in range(n):
        angle = np.pi * i / max(n - 1, 1)
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_rotvec([0.05 * np.sin(3 * angle), angle, 0.0]).as_matrix()
        pose[:3, 3] = [0.5 * np.cos(2 * angle), 0.1 * np.sin(angle), 0.5 * np.sin(2 * angle)]
        world_dir = directions @ pose[:3, :3].T
        with np.errstate(divide="ignore"):
            exits = (np.sign(world_dir) * ROOM - pose[:3, 3]) / world_dir
        depth = np.where(np.isfinite(exits), exits, np.inf).min(axis=-1)  # z-depth: the rays have z = 1
        hit = pose[:3, 3] + world_dir * depth[..., None]
        checker = (np.floor(hit / 0.25).astype(np.int64).sum(axis=-1) % 2).astype(np.float64)
        rgb = np.stack([60 + 150 * checker, 80 + 40 * (hit[..., 1] + ROOM[1]), 200 - 120 * checker], axis=-1)
        frames.append((pose, np.clip(rgb, 0, 255).astype(np.uint8), depth))
    return frames


def _peer(frames, camera: Intrinsics, config: DenseMapConfig, rays: np.ndarray):
    """Plain back-projection into the world, every point kept: milliseconds per keyframe, bytes."""
    kept, times = [], []
    for pose, rgb, depth in frames:
        started = time.perf_counter()
        valid = (depth > 0) & (depth >= config.min_depth_m) & (depth <= config.max_depth_m)
        world = back_project(depth, rays, valid) @ pose[:3, :3].T + pose[:3, 3]
        kept.append((world, rgb[valid]))
        times.append((time.perf_counter() - started) * 1e3)
    return np.array(times), sum(p.nbytes + c.nbytes for p, c in kept), sum(len(p) for p, _ in kept)


def _dense(frames, camera: Intrinsics, config: DenseMapConfig):
    dense = DenseMap(config)
    dense.rays(camera)  # the ray table is made once per camera: not a keyframe's cost
    times = []
    for pose, rgb, depth in frames:
        started = time.perf_counter()
        dense.add_keyframe(pose, rgb, depth, camera)
        times.append((time.perf_counter() - started) * 1e3)
    return np.array(times), dense


def _transient_peak(frames, camera: Intrinsics, config: DenseMapConfig) -> float:
    """The largest allocation above what the map already held, in one keyframe (bytes)."""
    dense = DenseMap(config)
    dense.rays(camera)
    worst = 0
    tracemalloc.start()
    for pose, rgb, depth in frames:
        tracemalloc.reset_peak()
        held, _ = tracemalloc.get_traced_memory()
        dense.add_keyframe(pose, rgb, depth, camera)
        worst = max(worst, tracemalloc.get_traced_memory()[1] - held)
    tracemalloc.stop()
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keyframes", type=int, default=30)
    parser.add_argument("--voxel", type=float, default=DenseMapConfig().voxel_m)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--fr1", action="store_true", help="TUM fr1's distorted camera (640x480)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    if args.fr1:
        camera = TUM_FREIBURG["freiburg1"]
    else:
        f = 525.0 * args.width / 640
        camera = Intrinsics(f, f, (args.width - 1) / 2, (args.height - 1) / 2, args.width, args.height)
    config = DenseMapConfig(voxel_m=args.voxel)
    n = args.keyframes
    frames = _keyframes(camera, n)

    started = time.perf_counter()
    rays = pixel_rays(camera)
    rays_ms = (time.perf_counter() - started) * 1e3
    peer_ms, peer_bytes, peer_points = _peer(frames, camera, config, rays)
    dense_ms, dense = _dense(frames, camera, config)
    transient = _transient_peak(frames, camera, config)

    print(
        f"{n} keyframes {camera.width}x{camera.height}"
        f"{' (TUM fr1, distorted)' if camera.distorted else ''}, voxel {config.voxel_m} m, one core"
    )
    print(f"ray table, once per camera: {rays_ms:.1f} ms, {rays.nbytes / MB:.1f} MB")
    from depotbench.core.text_table import Column, render

    columns = [Column("", "left"), *(Column(h) for h in ("ms/kf mean", "ms/kf last", "MB/kf held", "points"))]
    rows = [
        ["plain back-projection (peer)", peer_ms, peer_bytes, peer_points],
        ["dense map (voxel merge)", dense_ms, dense.nbytes, len(dense)],
    ]
    cells = [
        [name, f"{ms.mean():.1f}", f"{ms[-1]:.1f}", f"{held / MB / n:.2f}", str(points)]
        for name, ms, held, points in rows
    ]
    print(render(columns, cells))
    print(
        f"ratio dense / peer: time {dense_ms.mean() / peer_ms.mean():.2f}x, "
        f"memory held {dense.nbytes / peer_bytes:.3f}x; "
        f"dense map's largest transient per keyframe {transient / MB:.1f} MB"
    )


if __name__ == "__main__":
    main()
