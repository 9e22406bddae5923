"""Renderer cost per pass on the default scenario (MuJoCo, Mesa llvmpipe via EGL).

Usage: python benchmarks/render.py [--width W --height H --frames N]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from sim.mujoco_env import mujoco
from sim.render import FrameRenderer
from sim.simulation import Simulation
from sim.spec import default_scenario
from sim.world import build_world


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--frames", type=int, default=60)
    args = parser.parse_args()
    spec = dataclasses.replace(
        default_scenario(), width=args.width, height=args.height, focal_px=525.0 * args.width / 640
    )
    world = build_world(spec)
    renderer = FrameRenderer(world.model, args.width, args.height)
    sim = Simulation(world)
    renderer.render(sim.data, world.camera_id)
    flags = mujoco.mjtRndFlag
    scene = renderer._scene
    timings = {}
    for name, seg in (("RGB + depth pass", False), ("segmentation pass", True)):
        scene.flags[flags.mjRND_SEGMENT] = seg
        scene.flags[flags.mjRND_IDCOLOR] = seg
        start = time.perf_counter()
        for _ in range(args.frames):
            mujoco.mjr_render(renderer._rect, scene, renderer._context)
            mujoco.mjr_readPixels(
                renderer._rgb, None if seg else renderer._depth, renderer._rect, renderer._context
            )
        timings[name] = (time.perf_counter() - start) / args.frames
    start = time.perf_counter()
    for k in range(args.frames):
        sim.advance_to(k / spec.fps)
        renderer.render(sim.data, world.camera_id)
    timings["full frame (advance + both passes + decode)"] = (time.perf_counter() - start) / args.frames
    print(f"{args.width}x{args.height}, {world.model.ngeom} geoms")
    for name, seconds in timings.items():
        print(f"{name:45s} {seconds * 1e3:7.2f} ms  ({1 / seconds:6.1f} /s)")


if __name__ == "__main__":
    main()
