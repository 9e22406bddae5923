"""Generate one scenario into a sequence folder: simulate, render, ground truth, write."""

from __future__ import annotations

import dataclasses
import functools
import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from depotbench.core.errors import ScenarioError
from depotbench.core.files import DEFAULT_PNG_COMPRESSION
from depotbench.core.jit import compiled
from depotbench.core.progress import progress_bar
from depotbench.sim.flow import exact_flow, flow_at, rigid_motions
from depotbench.sim.ground_truth import ObjectState, visible_boxes
from depotbench.sim.mujoco_env import mujoco
from depotbench.sim.products import product
from depotbench.sim.render import FrameRenderer
from depotbench.sim.sensor import SensorModel
from depotbench.sim.sensor_profiles import profile_name
from depotbench.sim.sequence import SequenceWriter
from depotbench.sim.simulation import Simulation, Snapshot
from depotbench.sim.spec import ScenarioSpec, content_key
from depotbench.sim.world import World, build_world, intrinsics_of, scenario_streams
from scipy.spatial.transform import Rotation

LOG = logging.getLogger(__name__)

MOVING_SPEED_MPS = 0.01
"""An instance is 'moving' when any of its parts moves faster than this."""
START_TIME_S = 1.0
"""Timestamp of the first frame (TUM tools dislike a zero timestamp)."""


def object_states(
    world: World,
    now: Snapshot,
    nxt: Snapshot,
    boxes: list,
    counts: np.ndarray,
    unoccluded: dict[int, tuple[int, bool]],
) -> list[ObjectState]:
    """Every instance's ground truth at ``now``; ``nxt`` (one frame later) gives part speeds;
    ``boxes`` and ``counts`` are its visible box and pixels (``visible_boxes``,
    ``RenderedFrame.counts``), ``unoccluded`` each visible instance's unoccluded area
    (``FrameRenderer.unoccluded``)."""
    dt = nxt.time_s - now.time_s
    part_speed = np.linalg.norm(nxt.body_positions - now.body_positions, axis=1) / dt
    poses = []
    for info in world.instances:
        if info.kind == "actor":
            actor = world.actors[info.index]
            position, rotation = actor.root(now.time_s)
            linear, angular = actor.velocity(now.time_s)
        elif info.kind == "chair":
            body = world.chair_bodies[info.index]
            position, rotation = now.body_positions[body], now.body_rotations[body]
            dof = world.chair_qvel[info.index]
            linear = now.qvel[dof : dof + 3]
            angular = product(rotation, now.qvel[dof + 3 : dof + 6])
        else:
            position = world.object_positions[info.index]
            rotation, linear, angular = np.eye(3), np.zeros(3), np.zeros(3)
        poses.append((info, position, rotation, linear, angular))
    if not poses:
        return []
    quats = Rotation.from_matrix(np.array([pose[2] for pose in poses])).as_quat(canonical=True)
    states = []
    for (info, position, _, linear, angular), quat in zip(poses, quats, strict=True):
        bodies = np.flatnonzero(world.body_instance == info.instance_id)
        moving = info.kind != "object" and bool(part_speed[bodies].max() > MOVING_SPEED_MPS)
        count = int(counts[info.instance_id])
        box = boxes[info.instance_id - 1] if count else None
        states.append(
            ObjectState(
                instance_id=info.instance_id,
                class_name=info.class_name,
                prior=info.prior,
                position_m=tuple(float(v) for v in position),
                quat_xyzw=(float(quat[0]), float(quat[1]), float(quat[2]), float(quat[3])),
                linear_velocity_mps=tuple(float(v) for v in linear),
                angular_velocity_radps=tuple(float(v) for v in angular),
                moving=moving,
                box_xyxy=None if box is None else tuple(int(v) for v in box),
                visible_pixels=count,
                unoccluded_pixels=unoccluded[info.instance_id][0] if count else None,
                truncated=unoccluded[info.instance_id][1] if count else None,
            )
        )
    return states


FLOW_GRID = 4
"""Difficulty's mean flow of moving pixels is taken on every FLOW_GRID-th row and column."""


@dataclass
class DifficultyAccumulator:
    """Per-frame figures that say how hard a sequence is for dynamic SLAM."""

    dynamic_fraction: list[float] = field(default_factory=list)
    flow_sum: float = 0.0
    flow_pixels: int = 0
    camera_speed: list[float] = field(default_factory=list)

    def add(self, moving_mask: np.ndarray, moving_flow: np.ndarray, camera_speed: float) -> None:
        self.dynamic_fraction.append(float(moving_mask.mean()))
        magnitudes = np.linalg.norm(moving_flow, axis=1)
        magnitudes = magnitudes[np.isfinite(magnitudes)]
        self.flow_sum += float(magnitudes.sum())
        self.flow_pixels += int(magnitudes.size)
        self.camera_speed.append(camera_speed)

    def summary(self) -> dict[str, float]:
        fractions = np.array(self.dynamic_fraction)
        return {
            "dynamic_pixel_fraction_mean": round(float(fractions.mean()), 6),
            "dynamic_pixel_fraction_max": round(float(fractions.max()), 6),
            "frames_over_half_dynamic": round(float((fractions > 0.5).mean()), 6),
            "dynamic_flow_px_mean": round(self.flow_sum / self.flow_pixels, 6) if self.flow_pixels else 0.0,
            "camera_speed_mps_mean": round(float(np.mean(self.camera_speed)), 6),
        }


@functools.cache
def _say_if_off_reference() -> None:
    """Once a process: a warning where numpy or OpenBLAS run code that rounds otherwise than
    on the reference machines (loaded before ``core.numerics`` could set them: a program
    that imports numpy and then the bench). Its sequences are then this machine's bytes,
    not the frozen benchmarks'."""
    from depotbench.core.numerics import off_reference, reference_environment

    off = off_reference()
    if off:
        settings = " ".join(f"{k}={v!r}" for k, v in reference_environment().items())
        LOG.warning(
            f"{' and '.join(off)} compute otherwise than on the reference machines, so the sequences "
            f"generated here are not the frozen benchmarks' bytes: import depotbench before numpy, "
            f"or set {settings} (docs/determinism.md)"
        )


def generate(
    scenario: ScenarioSpec,
    out: Path | str,
    *,
    overwrite: bool = False,
    progress: bool = True,
    position: int = 0,
    inputs: tuple[Path, ...] = (),
    png_compression: int = DEFAULT_PNG_COMPRESSION,
) -> Path:
    """Write ``scenario`` as a sequence folder at ``out`` (atomically).

    The output is checked, locked and staged before the world is built, so a place
    that must not or cannot be written is refused before any work. ``png_compression``
    (zlib level 0-9) trades size for speed: the pixels are the same at every level.
    """
    out = Path(out)
    _say_if_off_reference()
    writer = SequenceWriter(
        out,
        intrinsics_of(scenario),
        fps=scenario.fps,
        meta={
            "scenario": dataclasses.asdict(scenario),
            "seed": scenario.seed,
            "sensor_profile": profile_name(scenario.sensor),
        },
        overwrite=overwrite,
        content_key=content_key(scenario),
        inputs=inputs,
        png_compression=png_compression,
    )
    with writer:
        if compiled() and (scenario.flow or scenario.sensor.enabled):
            from depotbench.sim import kernels

            kernels.ready()  # compiled or loaded before the first frame, a compile announced
        world = build_world(scenario)
        writer.meta["classes"] = world.classes()
        writer.meta["instances"] = [dataclasses.asdict(i) for i in world.instances]
        geom_instance = world.body_instance[world.model.geom_bodyid]
        renderer = FrameRenderer(world.model, scenario.width, scenario.height, geom_instance)
        try:
            frames = progress_bar(
                range(scenario.frames),
                desc=f"generate {scenario.name}",
                unit="frame",
                disable=not progress,
                leave=False,
                position=position,
            )
            with frames:  # closed (and its line cleared) before an error is printed
                writer.meta["difficulty"] = _write_frames(scenario, world, renderer, writer, frames)
        except mujoco.FatalError as exc:
            raise ScenarioError(f"{scenario.name}: MuJoCo cannot simulate this scene: {exc}") from None
        finally:
            renderer.close()
    return out


def _write_frames(
    scenario: ScenarioSpec,
    world: World,
    renderer: FrameRenderer,
    writer: SequenceWriter,
    frames: Iterable[int],
) -> dict[str, float]:
    """Simulate, render and write each frame with its ground truth; return the difficulty."""
    sensor = SensorModel(scenario.sensor, scenario_streams(scenario.seed)[4])
    clock = sensor.clock(scenario.frames, scenario.fps) if scenario.sensor.timing else None
    sim = Simulation(world)
    # Index -1 (the static world, or nothing) reads the appended 0: the world body. Like
    # every body of the static world, it never moves (test_scenes: _assert_only_instances_move).
    geom_body = np.append(world.model.geom_bodyid.astype(np.int64), 0)
    difficulty = DifficultyAccumulator()
    period = 1.0 / scenario.fps
    now = sim.snapshot()
    for k in frames:
        timing = clock.frame(k) if clock is not None else None
        if timing is not None and timing.dropped:  # lost by the driver: simulated, never rendered
            sim.advance_to((k + 1) * period)
            now = sim.snapshot()
            continue
        frame = renderer.render(sim.data, world.camera_id)
        rgb, depth, geom_ids, instances = frame.rgb, frame.depth, frame.geom_ids, frame.instances
        boxes, counts = visible_boxes(instances, len(world.instances)), frame.counts
        sim.advance_to((k + 1) * period)
        nxt = sim.snapshot()
        motion = rigid_motions(now.body_positions, now.body_rotations, nxt.body_positions, nxt.body_rotations)
        objects = object_states(world, now, nxt, boxes, counts, frame.unoccluded)
        is_moving = np.zeros(len(world.instances) + 1, bool)
        is_moving[[o.instance_id for o in objects if o.moving]] = True
        moving = is_moving[instances] & (depth > 0)
        # The mean flow of moving pixels is taken on a grid of every FLOW_GRID-th row and
        # column: a sixteenth of the work; on five library scenes the mean moved by 0.3% at most.
        vv, uu = np.nonzero(moving[::FLOW_GRID, ::FLOW_GRID])
        vv, uu = vv * FLOW_GRID, uu * FLOW_GRID
        flow = None
        poses = (now.world_from_camera, nxt.world_from_camera)
        if scenario.flow or sensor.needs_flow:
            flow = exact_flow(depth, geom_body[geom_ids], world.intrinsics, *poses, motion)
            moving_flow = flow[vv, uu]
        else:
            # Only those pixels' flow is needed: the same computation, cast as exact_flow does.
            moving_flow = flow_at(
                uu, vv, depth[vv, uu], geom_body[geom_ids[vv, uu]], world.intrinsics, *poses, motion
            ).astype(np.float32)
        camera_speed = float(np.linalg.norm(poses[1][:3, 3] - poses[0][:3, 3]) / period)
        difficulty.add(moving, moving_flow, camera_speed)
        clean = None
        if scenario.sensor.enabled:
            clean = depth
            rgb = sensor.rgb(rgb, flow, scenario.fps)
            delay = timing.depth_delay_s * scenario.fps if timing is not None else 0.0
            depth = sensor.depth(depth, flow, delay)
        stamp, depth_stamp, recorded = START_TIME_S + k * period, None, None
        if timing is not None and clock is not None:
            stamp = START_TIME_S + timing.stamp_s
            depth_stamp = stamp + timing.depth_delay_s
            recorded = clock.recorded_pose(k, world.rig.world_from_camera(timing.recorded_s))
        writer.add_frame(
            stamp,
            rgb,
            depth,
            now.world_from_camera,
            instances,
            objects,
            flow if scenario.flow else None,
            clean,
            depth_timestamp_s=depth_stamp,
            recorded_pose=recorded,
        )
        now = nxt
    return difficulty.summary()
