"""Renderer cost per pass on the default scenario (MuJoCo, Mesa llvmpipe via EGL).

Usage: python benchmarks/render.py [--width W --height H --frames N --threads T --seed S]
                                   [--figure-triangles SHARE ... [--scene NAME] [--moments M] [--repeat R]]
                                   [--far-from METRES ... [--scene NAME] [--moments M] [--repeat R]]

Times the colour pass (RGB + depth), the instance pass (the instances alone, in their
segmentation colours) and a whole render (both passes and the unoccluded areas), with
depotbench's tessellation (one quad per box face, coarser spheres and capsules) and
with MuJoCo's defaults beside it.
``--threads`` sets Mesa's rasterizer threads (suites' workers use 0: rasterise in the calling thread).

``--figure-triangles 0.2 0.12`` instead builds the scene once per share of marching
cubes' triangles the figures keep (sim/shapes.py KEEP_FACES, 0.2 shipped), all in one
process, and renders the worlds in turn (both passes and the unoccluded areas, the
fastest of ``--repeat`` calls at each of ``--moments`` moments): what the figures'
triangles cost, measured side by side so that the machine's drift cancels.

``--far-from 3 inf`` renders one world the same way with each distance beyond which
pieces are drawn by their far versions (sim/render.py FAR_M, 3 m shipped; ``inf``:
never), and prints what share of the in-view figure triangles that puts in the far
versions and how many pixels' colour and instance differ from the first distance's.
"""

from __future__ import annotations

import argparse
import os
import time

from generation import check_scene, scenario_at  # benchmarks/ is the script's folder


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--threads", type=int, help="LP_NUM_THREADS (default: Mesa's, one per core)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--figure-triangles", type=float, nargs="+", metavar="SHARE")
    parser.add_argument("--far-from", type=float, nargs="+", metavar="METRES")
    parser.add_argument("--scene", help="--figure-triangles, --far-from: a library scene, not the default")
    parser.add_argument("--moments", type=int, default=8)
    parser.add_argument("--repeat", type=int, default=8)
    args = parser.parse_args()
    if args.moments < 1 or args.repeat < 1:
        parser.error("--moments and --repeat must be at least 1")
    check_scene(parser, args.scene)
    if args.threads is not None:
        os.environ["LP_NUM_THREADS"] = str(args.threads)  # read when the GL context is made
    if args.figure_triangles:
        _figure_triangles(args)
        return
    if args.far_from:
        _far_from(args)
        return

    from depotbench.sim.render import FrameRenderer
    from depotbench.sim.simulation import Simulation
    from depotbench.sim.world import build_world

    spec = scenario_at(None, args.width, args.height, args.seed, None)
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
        timings = {}
        for name, run in (
            ("colour pass (RGB + depth)", renderer._colour_pass),
            ("instance pass (segmentation of the instances)", renderer._instance_pass),
        ):
            start = time.perf_counter()
            for _ in range(args.frames):
                run(sim.data, world.camera_id)
            timings[name] = (time.perf_counter() - start) / args.frames
        rendering = 0.0
        start = time.perf_counter()
        for k in range(args.frames):
            sim.advance_to(k / spec.fps)
            t0 = time.perf_counter()
            renderer.render(sim.data, world.camera_id)
            rendering += time.perf_counter() - t0
        whole = (time.perf_counter() - start) / args.frames
        timings["render: both passes, decode, unoccluded areas"] = rendering / args.frames
        timings["full frame (advance and render)"] = whole
        renderer.close()
        print(f"{label} (numquads {quads}, numslices {slices}, numstacks {stacks}):")
        for name, seconds in timings.items():
            print(f"  {name:55s} {seconds * 1e3:7.2f} ms  ({1 / seconds:6.1f} /s)")


def _figure_triangles(args: argparse.Namespace) -> None:
    """Render the scene built at each share of figure triangles, in turn, in one process."""
    import depotbench.sim.shapes
    import numpy as np
    from depotbench.sim.render import FrameRenderer
    from depotbench.sim.simulation import Simulation
    from depotbench.sim.world import build_world

    spec = scenario_at(None, args.width, args.height, args.seed, args.scene)
    shipped = depotbench.sim.shapes.KEEP_FACES
    worlds = []
    try:
        for share in args.figure_triangles:
            depotbench.sim.shapes.KEEP_FACES = share
            world = build_world(spec)
            renderer = FrameRenderer(
                world.model, spec.width, spec.height, world.body_instance[world.model.geom_bodyid]
            )
            worlds.append((share, world, renderer, Simulation(world)))
    finally:
        depotbench.sim.shapes.KEEP_FACES = shipped
    fastest = np.full((len(worlds), args.moments), np.inf)
    duration = spec.frames / spec.fps
    for m, t in enumerate(np.linspace(0.1, 0.9, args.moments) * duration):
        for _, _, _, simulation in worlds:
            simulation.advance_to(float(t))
        for _ in range(args.repeat):
            for w, (_, world, renderer, simulation) in enumerate(worlds):
                renderer._gl.make_current()
                start = time.perf_counter()
                renderer.render(simulation.data, world.camera_id)
                fastest[w, m] = min(fastest[w, m], time.perf_counter() - start)
    print(
        f"{args.scene or 'default scenario'}, seed {args.seed}, {args.width}x{args.height}: both passes and "
        f"the unoccluded areas, fastest of {args.repeat} calls, mean over {args.moments} moments"
    )
    for w, (share, world, renderer, _) in enumerate(worlds):
        triangles = int(world.model.nmeshface)
        print(f"  figures keep {share:.2f}: {triangles:7d} mesh triangles  {fastest[w].mean() * 1e3:7.2f} ms")
        renderer.close()


def _far_from(args: argparse.Namespace) -> None:
    """Render one world in turn with each ``--far-from`` distance as ``FAR_M``."""
    import depotbench.sim.render
    import numpy as np
    from depotbench.sim.render import FrameRenderer
    from depotbench.sim.simulation import Simulation
    from depotbench.sim.world import build_world

    spec = scenario_at(None, args.width, args.height, args.seed, args.scene)
    world = build_world(spec)
    model = world.model
    renderer = FrameRenderer(model, spec.width, spec.height, world.body_instance[model.geom_bodyid])
    simulation = Simulation(world)
    faces = model.mesh_facenum[model.geom_dataid[renderer._near_version]]
    shipped = depotbench.sim.render.FAR_M
    fastest = np.full((len(args.far_from), args.moments), np.inf)
    far_share = np.zeros((len(args.far_from), 2))
    changed = np.zeros((len(args.far_from), 2))
    try:
        for m, t in enumerate(np.linspace(0.1, 0.9, args.moments) * spec.frames / spec.fps):
            simulation.advance_to(float(t))
            in_view = ~renderer._outside_view(simulation.data, world.camera_id)[renderer._near_version]
            for _ in range(args.repeat):
                for d, far_m in enumerate(args.far_from):
                    depotbench.sim.render.FAR_M = far_m
                    start = time.perf_counter()
                    renderer.render(simulation.data, world.camera_id)
                    fastest[d, m] = min(fastest[d, m], time.perf_counter() - start)
            frames = []
            for d, far_m in enumerate(args.far_from):
                depotbench.sim.render.FAR_M = far_m
                frames.append(renderer.render(simulation.data, world.camera_id))
                far = renderer._far_from(simulation.data, world.camera_id)
                far_share[d] += faces[far & in_view].sum(), faces[in_view].sum()
                changed[d, 0] += (frames[d].rgb != frames[0].rgb).any(axis=-1).sum()
                changed[d, 1] += (frames[d].instances != frames[0].instances).sum()
    finally:
        depotbench.sim.render.FAR_M = shipped
        renderer.close()
    print(
        f"{args.scene or 'default scenario'}, seed {args.seed}, {spec.width}x{spec.height}: render (both "
        f"passes and the unoccluded areas), fastest of {args.repeat} calls, mean over {args.moments} moments"
    )
    changed /= args.moments
    for d, far_m in enumerate(args.far_from):
        print(
            f"  far versions beyond {far_m:4.1f} m: {fastest[d].mean() * 1e3:6.2f} ms, "
            f"{far_share[d, 0] / max(far_share[d, 1], 1):4.0%} of in-view figure triangles far, pixels "
            f"changed a frame: colour {changed[d, 0]:6.0f}, instance {changed[d, 1]:5.0f}"
        )


if __name__ == "__main__":
    main()
