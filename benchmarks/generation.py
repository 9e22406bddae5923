"""Generation speed: simulate + render + ground truth + write, frames per second.

Usage: python benchmarks/generation.py [--frames N] [--width W --height H] [--png-compression 0 1]
                                       [--repeat R] [--peer] [--profiles P ...] [--scene NAME]
                                       [--stages [--seed S] [--peer]]

For the default scenario (or a library scene: ``--scene dog_and_cat_roaming``), prints
the rate of one process (Mesa's default threads) and of two processes with one thread
each, as suites run their workers (``depotbench.core.executors.single_threaded``), for each PNG
level asked. Each worker generates
its own seed. Two rates per line: per frame once the world is built (simulation,
both render passes, the unoccluded passes, ground truth and PNG writes), and with
building the world (meshing the figures, textures, compiling) counted too.

This 2-core machine's speed drifts by up to a third between runs of one build:
``--repeat R`` measures each line R times and prints the median with the range. To
compare two checkouts, start ``--stages`` in each at the same moment (one worker each,
as suites run two): both see the same machine, and their frame loops compare where
runs taken in turn do not (docs/performance.md, "Generation rate").

``--peer`` also runs, after each measurement, a peer beside which the rates read as
ratios: MuJoCo alone rendering the same worlds the plain way (one pass for RGB and
depth, one segmentation pass, read with ``mjr_readPixels``; no culling, far versions,
instance or unoccluded passes, ground truth or writes), in two one-thread processes as
suites run theirs. Issue 14 set 30 frames/s against MuJoCo alone at about 35 a process
(rendering-notes.md); this machine's speed drifts by a third between hours, and the
ratio to a peer measured in the same minutes should not. The peer draws every figure
piece at full detail (no far versions) and no collision stand-ins. ``--profiles perfect tum``
measures the two-process line once per sensor profile, each beside the same peer (the peer
renders the worlds, which no sensor changes): the clean and the TUM profile in one run.

``--stages`` instead breaks one one-thread process's frame down by stage (as suites'
workers run it): the colour pass, the instance pass, the unoccluded areas,
poses and physics, boxes, object states, the sensor model, handing the frame to the
writer, and the deflate in the writer's threads (their CPU time), with the rest of the
loop as "other" and the world's build apart; ``--profiles`` gives one breakdown per sensor
profile. With ``--peer`` it then measures MuJoCo alone on the same world in two processes
and prints the highest share of its rate that generation could reach were every stage but
the format's own work free (the colour, instance and unoccluded passes and the deflate; and
with the sensor model): a bound, since the stages are timed in one process alone.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import tempfile
import time
from collections import defaultdict
from pathlib import Path

# depotbench first: numpy then runs the bench's code for the CPU (core/numerics.py)
import depotbench  # isort: skip  # noqa: F401
import numpy as np


def _run(args: tuple) -> tuple[float, float]:
    """(seconds to build the world, seconds to generate, world building included), both
    of one ``generate`` call: the build is timed inside it, since a build timed apart and
    subtracted is off by its own drift (on a tiny run under load, a negative rate)."""
    frames, width, height, seed, out, one_thread, png_compression, scene, *sensor = args
    if one_thread:
        from depotbench.core.executors import single_threaded

        single_threaded()
    import depotbench.sim.generate
    from depotbench.sim.world import build_world

    spec = scenario_at(frames, width, height, seed, scene, *sensor)
    build_world(scenario_at(frames, width, height, seed + 1000, scene))  # warm imports and code paths
    built: dict[str, float] = defaultdict(float)
    depotbench.sim.generate.build_world = _timed(build_world, "build", built, time.perf_counter)
    start = time.perf_counter()
    depotbench.sim.generate.generate(spec, Path(out), progress=False, png_compression=png_compression)
    return built["build"], time.perf_counter() - start


def scenario_at(
    frames: int | None, width: int, height: int, seed: int, scene: str | None, sensor: str | None = None
):
    """The default scenario, or a library scene, at this image size and seed, with
    ``frames`` frames (None: the scenario's own length) and ``sensor`` (a profile's name;
    None: the scenario's own). render.py uses it too."""
    from depotbench.sim.spec import default_scenario
    from depotbench.sim.world import at_size

    if scene is None:
        spec = default_scenario(seed=seed) if frames is None else default_scenario(frames=frames, seed=seed)
    else:
        from depotbench.scenes import library
        from depotbench.scenes.schema import to_scenario

        update = {"seed": seed} if frames is None else {"frames": frames, "duration_s": None, "seed": seed}
        spec = to_scenario(library.get(scene).model_copy(update=update))
    if sensor is not None:
        import dataclasses

        from depotbench.sim.sensor_profiles import PROFILES

        spec = dataclasses.replace(spec, sensor=PROFILES[sensor])
    return at_size(spec, width, height)


def check_scene(parser: argparse.ArgumentParser, scene: str | None) -> None:
    """A --scene that is no library scene: one line naming the choices, exit 2."""
    if scene is None:
        return
    from depotbench.scenes import library

    if scene not in library.names():
        parser.error(f"--scene: no library scene {scene!r}; choose one of {', '.join(library.names())}")


def _peer(args: tuple[int, int, int, int, str | None]) -> float:
    """Seconds MuJoCo alone takes to render ``frames`` frames of a world the plain way:
    ``mjr_render`` then ``mjr_readPixels`` of RGB and depth, then a segmentation pass
    read as RGB, at the world's states along the clip (moving them is not timed)."""
    frames, width, height, seed, scene = args
    from depotbench.core.executors import single_threaded

    single_threaded()
    from depotbench.sim.mujoco_env import mujoco
    from depotbench.sim.render import HIDDEN_GROUP, detail_pairs
    from depotbench.sim.simulation import Simulation
    from depotbench.sim.world import build_world
    from mujoco import gl_context

    spec = scenario_at(frames, width, height, seed, scene)
    world = build_world(spec)
    model, sim = world.model, Simulation(world)
    # Each figure piece once, at full detail: its far version (depotbench.sim.render) stays hidden.
    model.geom_group[detail_pairs(model)[1]] = HIDDEN_GROUP
    gl = gl_context.GLContext(width, height)
    gl.make_current()
    try:
        scene_ = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
        context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, context)
        option, camera = mujoco.MjvOption(), mujoco.MjvCamera()
        camera.type, camera.fixedcamid = mujoco.mjtCamera.mjCAMERA_FIXED, world.camera_id
        rect = mujoco.MjrRect(0, 0, width, height)
        rgb = np.empty((height, width, 3), np.uint8)
        depth = np.empty((height, width), np.float32)
        spent = 0.0
        for k in range(frames):
            sim.advance_to(k / spec.fps)
            start = time.perf_counter()
            mujoco.mjv_updateScene(model, sim.data, option, None, camera, mujoco.mjtCatBit.mjCAT_ALL, scene_)
            for segment in (False, True):
                scene_.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = segment
                scene_.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = segment
                mujoco.mjr_render(rect, scene_, context)
                mujoco.mjr_readPixels(rgb, None if segment else depth, rect, context)
            spent += time.perf_counter() - start
        context.free()
    finally:
        gl.free()
    return spent


def _side_by_side(ctx, function, jobs: list[tuple]) -> list:
    """``function`` of each job, the jobs run side by side, one fresh process each. The
    pool is closed and joined, not terminated as ``with Pool`` does: terminating spawned
    workers left four semaphores for the resource tracker to warn about at exit."""
    pool = ctx.Pool(len(jobs))
    try:
        results = pool.map(function, jobs)
    except BaseException:
        pool.terminate()
        raise
    pool.close()
    pool.join()
    return results


def _measure_peer(ctx, jobs: list[tuple]) -> float:
    """Total frames/s of MuJoCo alone (``_peer``) in the jobs' processes, side by side."""
    seconds = _side_by_side(ctx, _peer, jobs)
    return sum(job[0] / s for job, s in zip(jobs, seconds, strict=True))


def _measure(ctx, jobs: list[tuple]) -> tuple[float, float]:
    """Total frames/s of the jobs run side by side: once built, and with building."""
    results = _side_by_side(ctx, _run, jobs)
    steady = sum(job[0] / (total - build) for job, (build, total) in zip(jobs, results, strict=True))
    return steady, sum(job[0] / total for job, (_, total) in zip(jobs, results, strict=True))


STAGES = (
    ("colour pass (RGB and depth)", "depotbench.sim.render", "FrameRenderer._colour_pass"),
    ("instance pass", "depotbench.sim.render", "FrameRenderer._instance_pass"),
    ("unoccluded areas", "depotbench.sim.render", "FrameRenderer._unoccluded_areas"),
    ("rest of render", "depotbench.sim.render", "FrameRenderer.render"),
    ("poses and physics", "depotbench.sim.simulation", "Simulation.advance_to"),
    ("snapshots", "depotbench.sim.simulation", "Simulation.snapshot"),
    ("moving pixels' flow", "depotbench.sim.generate", "flow_at"),
    ("exact flow (sensor, gt/flow)", "depotbench.sim.generate", "exact_flow"),
    ("boxes", "depotbench.sim.generate", "visible_boxes"),
    ("object states", "depotbench.sim.generate", "object_states"),
    ("sensor model", "depotbench.sim.sensor", "SensorModel.rgb"),
    ("sensor model", "depotbench.sim.sensor", "SensorModel.depth"),
    ("hand to the writer", "depotbench.sim.sequence", "SequenceWriter.add_frame"),
    ("deflate (writer threads)", "depotbench.sim.png", "_deflate"),
)
"""(label, module, attribute) of each timed stage. The passes run inside ``render``,
whose time they are taken from; deflate runs in the writer's threads, so its thread
CPU time is counted, which the frame loop does not wait for."""


FORMAT_WORK = ("colour pass (RGB and depth)", "instance pass", "unoccluded areas", "deflate (writer threads)")
"""The stages no generator of this format can leave out: the RGB and depth images, the
instance masks and each object's unoccluded area (docs/format.md), and deflating the PNGs,
whose bytes the benchmarks' locks freeze. MuJoCo alone (``--peer``) does none of the last three."""


def _stages(job: tuple) -> dict[str, float]:
    """Milliseconds a frame of each stage of one process's frames (one thread, as suites run
    their workers), with the loop, the deflate's thread CPU time, the world's build and the
    whole call; run in a fresh process each (the stages are timed by wrapping functions)."""
    frames, width, height, seed, png_compression, scene, sensor = job
    import importlib

    from depotbench.core.executors import single_threaded

    single_threaded()
    from depotbench.sim.generate import generate
    from depotbench.sim.world import build_world

    spent: dict[str, float] = defaultdict(float)
    for label, module_name, attribute in STAGES:
        module = importlib.import_module(module_name)
        owner_name, _, name = attribute.rpartition(".")
        owner = getattr(module, owner_name) if owner_name else module
        clock = time.thread_time if name == "_deflate" else time.perf_counter
        setattr(owner, name, _timed(getattr(owner, name), label, spent, clock))
    import depotbench.sim.generate

    loop: dict[str, float] = defaultdict(float)
    depotbench.sim.generate._write_frames = _timed(
        depotbench.sim.generate._write_frames, "loop", loop, time.perf_counter
    )
    spec = scenario_at(frames, width, height, seed, scene, sensor)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        generate(spec, Path(tmp) / "s", progress=False, png_compression=png_compression)
        whole = time.perf_counter() - start
    total = loop["loop"]
    start = time.perf_counter()
    build_world(spec)  # once more, alone: generate's took as long
    build = time.perf_counter() - start
    spent["rest of render"] -= sum(spent[label] for label, _, _ in STAGES[:3])
    stages = {label: seconds / frames * 1e3 for label, seconds in spent.items()}
    stages["other"] = (
        (total - sum(s for label, s in spent.items() if label != "deflate (writer threads)")) / frames * 1e3
    )
    stages["frame loop"] = total / frames * 1e3
    stages["building the world"] = build * 1e3
    stages["the whole generate call"] = whole * 1e3
    return stages


def _print_stages(
    stages: dict[str, float], frames: int, seed: int, scene: str | None, sensor: str | None
) -> None:
    profile = "" if sensor is None else f", sensor {sensor}"
    print(f"{scene or 'default scenario'}{profile}, seed {seed}, {frames} frames, one process, one thread")
    print(f"  {'stage':28s} ms/frame  share of the loop")
    loop = stages["frame loop"]
    for label in dict.fromkeys(label for label, _, _ in STAGES if label in stages):
        if label != "deflate (writer threads)":
            print(f"  {label:28s} {stages[label]:7.2f}  {stages[label] / loop:5.1%}")
    print(f"  {'other':28s} {stages['other']:7.2f}  {stages['other'] / loop:5.1%}")
    print(f"  {'frame loop':28s} {loop:7.2f}  ({1e3 / loop:.1f} frames/s)")
    deflate = stages.get("deflate (writer threads)", 0.0)
    print(f"  {'deflate (writer threads)':28s} {deflate:7.2f}  CPU time beside the loop")
    print(f"  {'building the world':28s} {stages['building the world']:7.0f}  ms, once")
    whole = stages["the whole generate call"]
    print(f"  {'the whole generate call':28s} {whole:7.0f}  ms (with set-up and the last writes)")


def ceiling(peer_fps: float, stages: dict[str, float], extra: tuple[str, ...] = ()) -> tuple[float, float]:
    """(ms of one core a frame that ``FORMAT_WORK`` and ``extra`` take, the highest share of
    MuJoCo alone's rate two processes could reach were every other stage free). MuJoCo alone
    at ``peer_fps`` in two one-thread processes spends 2000 / ``peer_fps`` ms of a core a
    frame; generation spends at least the work's. Stages timed in one process alone run no
    slower than beside a second, so the share is an upper bound."""
    work = sum(stages.get(label, 0.0) for label in (*FORMAT_WORK, *extra))
    return work, 2e3 / peer_fps / work


def _timed(function, label: str, spent: dict[str, float], clock):
    def timed(*args, **kwargs):
        start = clock()
        try:
            return function(*args, **kwargs)
        finally:
            spent[label] += clock() - start

    return timed


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=90)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--png-compression", type=int, nargs="+", default=[1, 0])
    parser.add_argument("--repeat", type=int, default=1, help="measure each line this many times")
    parser.add_argument("--scene", help="a library scene instead of the default scenario")
    parser.add_argument("--stages", action="store_true", help="time each stage of one process's frames")
    parser.add_argument(
        "--peer",
        action="store_true",
        help="also measure MuJoCo alone rendering the same worlds, for ratios; with --stages, the share "
        "of its rate that the format's own work leaves room for",
    )
    parser.add_argument(
        "--profiles",
        nargs="+",
        choices=["perfect", "kinect", "tum"],
        help="the two-process line once per sensor profile, each beside one peer (default: the scene's own); "
        "with --stages, a breakdown per profile",
    )
    parser.add_argument("--seed", type=int, default=0, help="--stages: the seed")
    parser.add_argument(
        "--sensors",
        nargs=2,
        metavar=("BASE", "OTHER"),
        choices=["perfect", "kinect", "tum"],
        help="instead: one process's rate with each sensor profile, measured in turn (--repeat times), "
        "and OTHER's rate as a share of BASE's (e.g. perfect tum)",
    )
    args = parser.parse_args()
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    ctx = mp.get_context("spawn")
    check_scene(parser, args.scene)
    if args.sensors:
        _compare_sensors(ctx, args)
        return
    if args.stages:  # at the first PNG level asked
        _stages_and_ceiling(ctx, args)
        return
    name = args.scene or "default scenario"
    print(f"{name}, {args.width}x{args.height}, {args.frames} frames per process, PNG writes included")
    print("frames/s, summed over the processes: once the world is built | with building the world")
    if args.repeat > 1:
        print(f"median of {args.repeat} runs [lowest-highest]")
    with tempfile.TemporaryDirectory() as tmp:
        for level in args.png_compression:

            def jobs(
                first: int, n: int, one_thread: bool, run: int, level: int = level, sensor: str | None = None
            ) -> list:
                return [
                    (
                        args.frames,
                        args.width,
                        args.height,
                        s,
                        f"{tmp}/s{s}-{level}-{run}-{sensor}",
                        one_thread,
                        level,
                        args.scene,
                        sensor,
                    )
                    for s in range(first, first + n)
                ]

            profiles = args.profiles or [None]
            singles, peers = [], []
            doubles: dict[str | None, list] = {profile: [] for profile in profiles}
            for run in range(args.repeat):
                singles.append(_measure(ctx, jobs(0, 1, False, run, sensor=profiles[0])))
                for profile in profiles:
                    doubles[profile].append(_measure(ctx, jobs(1, 2, True, run, sensor=profile)))
                if args.peer:
                    peer_jobs = [(args.frames, args.width, args.height, s, args.scene) for s in (1, 2)]
                    peers.append(_measure_peer(ctx, peer_jobs))
            print(f"PNG level {level}")
            label = "" if profiles == [None] else f" ({profiles[0]})"
            print(f"  1 process{label:16s}: {_summary(singles)}")
            for profile in profiles:
                label = "" if profile is None else f", {profile}"
                ratio = np.median([d[0] for d in doubles[profile]]) / np.median([s[0] for s in singles])
                rate = _summary(doubles[profile])
                print(f"  2 processes{label}: {rate}  (x{ratio:.2f} of one process, once built)")
            if peers:
                peer = _summary([(p,) for p in peers])
                print(f"  MuJoCo alone, 2 processes : {peer}  (RGB and depth, segmentation)")
                for profile in profiles:
                    label = "" if profile is None else f" ({profile})"
                    pairs = zip(doubles[profile], peers, strict=True)
                    shares = _summary([(d[0] / p,) for d, p in pairs], digits=2)
                    print(f"  2 processes{label} / MuJoCo alone: {shares}  (each run's own)")


def _stages_and_ceiling(ctx, args: argparse.Namespace) -> None:
    """``--stages``: each profile's breakdown (one fresh process each); with ``--peer``, MuJoCo
    alone on the same world in two processes, and the share of its rate that the format's own
    work leaves room for (``ceiling``)."""
    profiles = args.profiles or [None]
    level = args.png_compression[0]
    breakdowns = {}
    for sensor in profiles:
        job = (args.frames, args.width, args.height, args.seed, level, args.scene, sensor)
        breakdowns[sensor] = _side_by_side(ctx, _stages, [job])[0]
        _print_stages(breakdowns[sensor], args.frames, args.seed, args.scene, sensor)
    if not args.peer:
        return
    peer_jobs = [(args.frames, args.width, args.height, args.seed, args.scene)] * 2
    peer = _measure_peer(ctx, peer_jobs)
    print(f"MuJoCo alone, 2 processes: {peer:.1f} frames/s, {2e3 / peer:.2f} ms of a core a frame")
    print("the highest share of it two processes could reach with every other stage free (an upper bound):")
    for sensor, stages in breakdowns.items():
        name = sensor or "its sensor"
        work, share = ceiling(peer, stages)
        print(f"  {name:10s} the passes and deflate        {work:6.2f} ms a frame: at most {share:.2f}")
        if "sensor model" in stages:
            work, share = ceiling(peer, stages, ("sensor model",))
            print(f"  {name:10s} and the sensor model          {work:6.2f} ms a frame: at most {share:.2f}")


def _compare_sensors(ctx, args: argparse.Namespace) -> None:
    """One process's rate with each of two sensor profiles, alternated run by run so both see
    the same machine, and the second's rate as a share of the first's (the ratio per run)."""
    base, other = args.sensors
    level = args.png_compression[0]
    name = args.scene or "default scenario"
    print(f"{name}, {args.width}x{args.height}, {args.frames} frames, one process, PNG level {level}")
    rates: dict[str, list[tuple[float, float]]] = {base: [], other: []}
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(args.repeat):
            for sensor in (base, other):
                job = (
                    args.frames,
                    args.width,
                    args.height,
                    0,
                    f"{tmp}/{sensor}-{run}",
                    False,
                    level,
                    args.scene,
                )
                rates[sensor].append(_measure(ctx, [(*job, sensor)]))
    for sensor in (base, other):
        print(f"  sensor {sensor:8s}: {_summary(rates[sensor])} frames/s (once built | with building)")
    shares = [(o[0] / b[0],) for b, o in zip(rates[base], rates[other], strict=True)]
    print(f"  {other} / {base}: {_summary(shares, digits=2)} of the rate, once built (each run's own)")


def _summary(rates: list[tuple[float, ...]], digits: int = 1) -> str:
    """'steady | with building' as a median, with the range when measured more than once."""
    columns = []
    for values in zip(*rates, strict=True):
        text = f"{np.median(values):5.{digits}f}"
        if len(values) > 1:
            text += f" [{min(values):.{digits}f}-{max(values):.{digits}f}]"
        columns.append(text)
    return " | ".join(columns)


if __name__ == "__main__":
    main()
