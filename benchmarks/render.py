"""Renderer cost per pass on the default scenario (MuJoCo, Mesa llvmpipe via EGL).

Usage: python benchmarks/render.py [--width W --height H --frames N --threads T --seed S]

Times the RGB + depth pass, the segmentation pass and the unoccluded pass (the
visible instances drawn alone, each in its own bit, OR-ed), with depotbench's
tessellation (one quad per box face, coarser spheres and capsules) and with MuJoCo's
defaults beside it.
``--threads`` sets Mesa's rasterizer threads (suites' workers use 0: rasterise in the calling thread).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--threads", type=int, help="LP_NUM_THREADS (default: Mesa's, one per core)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.threads is not None:
        os.environ["LP_NUM_THREADS"] = str(args.threads)  # read when the GL context is made

    import numpy as np

    from sim.mujoco_env import mujoco
    from sim.render import FrameRenderer
    from sim.simulation import Simulation
    from sim.spec import default_scenario
    from sim.world import build_world

    spec = dataclasses.replace(
        default_scenario(seed=args.seed),
        width=args.width,
        height=args.height,
        focal_px=525.0 * args.width / 640,
    )
    world = build_world(spec)
    model = world.model
    ours = (model.vis.quality.numquads, model.vis.quality.numslices, model.vis.quality.numstacks)
    geom_instance = world.body_instance[model.geom_bodyid]
    print(
        f"{args.width}x{args.height}, {model.ngeom} geoms, {model.nmeshface} mesh triangles, seed {args.seed}"
    )
    for label, (quads, slices, stacks) in (
        ("depotbench", ours),
        ("MuJoCo's default tessellation", (4, 28, 16)),
    ):
        model.vis.quality.numquads, model.vis.quality.numslices, model.vis.quality.numstacks = (
            quads,
            slices,
            stacks,
        )
        renderer = FrameRenderer(model, args.width, args.height, geom_instance)
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
        passes = 0.0
        start = time.perf_counter()
        for k in range(args.frames):
            sim.advance_to(k / spec.fps)
            _, _, geom_ids = renderer.render(sim.data, world.camera_id)
            seen = np.unique(geom_instance[geom_ids[geom_ids >= 0]])
            t0 = time.perf_counter()
            renderer.unoccluded(sim.data, world.camera_id, [int(i) for i in seen if i > 0])
            passes += time.perf_counter() - t0
        whole = (time.perf_counter() - start) / args.frames
        timings["unoccluded pass"] = passes / args.frames
        timings["full frame (advance, both passes, decode, unoccluded)"] = whole
        renderer.close()
        print(f"{label} (numquads {quads}, numslices {slices}, numstacks {stacks}):")
        for name, seconds in timings.items():
            print(f"  {name:55s} {seconds * 1e3:7.2f} ms  ({1 / seconds:6.1f} /s)")


if __name__ == "__main__":
    main()
