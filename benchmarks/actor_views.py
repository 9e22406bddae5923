"""How a detector sees one actor, view by view: heading, gait moment, distance.

Usage: python benchmarks/actor_views.py [--kind cat] [--seeds 1 2 3] [--headings 8]
                                        [--moments 3] [--distance M] [--camera-height 0.9]
                                        [--detector onnx[:MODEL]] [--sheet PNG]

recognition.py counts the sightings that the library's scenes happen to show. This
separates the view from the scene: one actor of ``--kind`` stands alone on the depot
floor, ``--distance`` m in front of a static camera at ``--camera-height`` m that looks
at it, and is turned to each of ``--headings`` headings (0° walks to the image's right,
90° away from the camera, 270° towards it) at ``--moments`` moments of its walk (1/N s
apart), on each seed (the seed draws the actor's look and the depot).
Each view is rendered and given to the detector with its threshold lowered to 0.05,
so near misses show. A view counts as recognised when a box of the actor's class with
IoU >= 0.5 against the true visible box scores >= 0.3 (recognition.py's rule).

Prints, per heading: the share recognised, the mean score of the actor's class (0
where no box of its class overlaps), and what the best-overlapping box is called when
it is not the actor's class. ``--sheet`` writes every view's crop, labelled.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections import Counter
from pathlib import Path

# depotbench first: numpy then runs the bench's code for the CPU (core/numerics.py)
import depotbench  # isort: skip  # noqa: F401
import cv2
import numpy as np
from depotbench.core.errors import InputError
from depotbench.detectors.base import DetectorFrame
from depotbench.detectors.config import DetectorConfigError, parse_detector
from depotbench.eval.detection.evaluate import IOU_THRESHOLD, iou_matrix
from depotbench.eval.run.detections import build_detector
from depotbench.sim.conventions import quat_wxyz
from depotbench.sim.mujoco_env import mujoco
from depotbench.sim.render import FrameRenderer
from depotbench.sim.simulation import Simulation
from depotbench.sim.spec import ActorSpec, CameraSpec, ScenarioSpec
from depotbench.sim.world import World, build_world
from sheets import crop_around, fit, grid, write_png

KINDS = ("person", "dog", "cat", "bird")
"""Walking actors of a COCO class (COCO has no pig: recognition.py counts pigs called person)."""
RECOGNISED = 0.3
"""The score a view needs to count as recognised: recognition.py's confidence threshold."""
CAMERA_Y = -2.3
"""Where the camera stands: the open floor in front of the racks, as the library's scenes."""


@dataclasses.dataclass(frozen=True)
class View:
    seed: int
    heading_deg: float
    moment_s: float
    score: float
    """The best score of the actor's class among boxes with IoU >= 0.5; 0 if none."""
    called: str
    """The class of the box overlapping the actor most (``none`` without one)."""
    crop: np.ndarray


def _scenario(kind: str, seed: int, distance: float, height: float) -> ScenarioSpec:
    target = (0.0, CAMERA_Y + distance, 0.25 if kind != "person" else 0.9)
    return ScenarioSpec(
        name=f"{kind}_views",
        seed=seed,
        frames=1,
        actors=(ActorSpec(kind),),
        camera=CameraSpec(motion="static", position_m=(0.0, CAMERA_Y, height), target_m=target),
    )


def _place(world: World, data: mujoco.MjData, moment: float, spot: np.ndarray, heading: float) -> None:
    """The actor as it is at ``moment`` of its walk, moved to ``spot`` and turned so that
    its body faces ``heading`` (radians, about the vertical)."""
    positions, rotations = world.actors[0].pose(moment)
    root, facing = positions[0], rotations[0][:, 0]
    turn = heading - math.atan2(facing[1], facing[0])
    c, s = math.cos(turn), math.sin(turn)
    yaw = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    offset = np.array([root[0], root[1], 0.0])
    mocap = world.actor_mocap[0]
    data.mocap_pos[mocap] = (positions - offset) @ yaw.T + [spot[0], spot[1], 0.0]
    data.mocap_quat[mocap] = quat_wxyz(yaw @ rotations)
    mujoco.mj_forward(world.model, data)


def _views(args: argparse.Namespace, seed: int, detector) -> list[View]:
    spec = _scenario(args.kind, seed, args.distance, args.camera_height)
    world = build_world(spec)
    sim = Simulation(world)
    geom_instance = world.body_instance[world.model.geom_bodyid]
    renderer = FrameRenderer(world.model, spec.width, spec.height, geom_instance)
    instance = next(i.instance_id for i in world.instances if i.kind == "actor")
    spot = np.array([0.0, CAMERA_Y + args.distance])
    views = []
    try:
        for heading in np.arange(args.headings) * 360.0 / args.headings:
            for k in range(args.moments):
                moment = 0.5 + k / args.moments
                _place(world, sim.data, moment, spot, math.radians(float(heading)))
                frame = renderer.render(sim.data, world.camera_id)
                rgb, geoms = frame.rgb, frame.geom_ids
                mask = np.append(geom_instance, 0)[geoms] == instance
                rows, cols = np.nonzero(mask)
                if rows.size == 0:
                    raise ValueError(f"seed {seed}, heading {heading:.0f}°: the {args.kind} is out of view")
                box = np.array([[cols.min(), rows.min(), cols.max() + 1, rows.max() + 1]], float)
                found = detector.detect(DetectorFrame(len(views), 0.0, rgb))
                score, called = _score(found, box, args.kind)
                views.append(View(seed, float(heading), moment, score, called, _crop(rgb, box[0])))
    finally:
        renderer.close()
    return views


def _score(found, box: np.ndarray, wanted: str) -> tuple[float, str]:
    if not found:
        return 0.0, "none"
    boxes = np.array([d.box_xyxy for d in found], float)
    ious = iou_matrix(box, boxes)[0]
    mine = [
        d.confidence
        for d, iou in zip(found, ious, strict=True)
        if d.class_name == wanted and iou >= IOU_THRESHOLD
    ]
    best = int(np.argmax(ious))
    return (max(mine) if mine else 0.0), (found[best].class_name if ious[best] > 0 else "none")


def _crop(rgb: np.ndarray, box: np.ndarray, side: int = 160) -> np.ndarray:
    x0, y0, x1, y1 = box.astype(int)
    return fit(crop_around(rgb, (x0, y0, x1, y1), int(0.2 * max(x1 - x0, y1 - y0))), side)


def _report(views: list[View], kind: str) -> None:
    print(report(views, kind))


def report(views: list[View], kind: str) -> str:
    """Per heading, the views recognised as ``kind`` and what the others were called; then all."""
    from depotbench.core.text_table import Column, render

    def row(label: str, group: list[View], called: str) -> list[str]:
        hits = sum(v.score >= RECOGNISED for v in group)
        return [label, f"{hits}/{len(group)}", f"{np.mean([v.score for v in group]):.2f}", called]

    rows = []
    for heading in sorted({v.heading_deg for v in views}):
        group = [v for v in views if v.heading_deg == heading]
        others = Counter(v.called for v in group if v.score < RECOGNISED and v.called != kind)
        rows.append(
            row(f"{heading:.0f}°", group, ", ".join(f"{n} {k}" for n, k in others.most_common(3)) or "-")
        )
    spread = [
        np.mean([v.score >= RECOGNISED for v in views if v.seed == s])
        for s in sorted({v.seed for v in views})
    ]
    rows.append(row("all", views, f"(recognised per seed {min(spread):.2f}-{max(spread):.2f})"))
    columns = [
        Column("heading"),
        Column("recognised"),
        Column("mean score"),
        Column("called instead (best-overlapping box)", "left"),
    ]
    return render(columns, rows)


def _sheet(views: list[View], path: Path, columns: int, kind: str) -> None:
    """One row per seed and moment, one column per heading; each view labelled with its
    class's score and, when not recognised, what the detector called it instead."""
    side = 160
    tiles = []
    for v in sorted(views, key=lambda v: (v.seed, v.moment_s, v.heading_deg)):
        tile = np.full((side + 16, side, 3), 255, np.uint8)
        tile[: v.crop.shape[0], : v.crop.shape[1]] = v.crop[:, :, ::-1]
        label = f"s{v.seed} {v.heading_deg:.0f}d {v.moment_s:.2f}s {kind} {v.score:.2f}"
        if v.score < RECOGNISED:
            label += f" ({v.called})" if v.called != kind else " (low)"
        cv2.putText(tile, label, (2, side + 12), cv2.FONT_HERSHEY_PLAIN, 0.75, (0, 0, 0), 1)
        tiles.append(tile)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, grid(tiles, columns))
    print(f"wrote {path} ({len(views)} views)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kind", choices=KINDS, default="cat")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--headings", type=int, default=8)
    parser.add_argument("--moments", type=int, default=3)
    parser.add_argument(
        "--distance", type=float, help="metres from the camera along the floor (3.0 for a person, else 1.3)"
    )
    parser.add_argument("--camera-height", type=float, default=0.9)
    parser.add_argument("--detector", default="onnx", help="onnx (the shipped YOLOX-nano) or onnx:MODEL")
    parser.add_argument("--sheet", type=Path, help="write a labelled picture of every view to this new .png")
    args = parser.parse_args()
    if args.sheet is not None and (args.sheet.suffix.lower() != ".png" or args.sheet.exists()):
        # Checked before the run: the picture never replaces a file that is already there.
        parser.error(f"--sheet {args.sheet}: give a new .png path")
    if args.distance is None:
        args.distance = 3.0 if args.kind == "person" else 1.3
    if min(args.seeds) < 0:
        parser.error("--seeds must be 0 or more")
    if args.headings < 1 or args.moments < 1:
        parser.error("--headings and --moments must be at least 1")
    if not 0.3 <= args.distance <= 4.0:
        parser.error("--distance must lie in 0.3-4.0 m (the open floor in front of the racks)")
    if not 0.1 <= args.camera_height <= 3.0:
        parser.error("--camera-height must lie in 0.1-3.0 m")
    if args.detector.partition(":")[0] != "onnx":
        parser.error("--detector: an image detector is needed (onnx or onnx:MODEL)")
    try:
        config = parse_detector(args.detector, settings={"confidence": "0.05"})
    except DetectorConfigError as exc:
        parser.error(str(exc))
    try:
        detector = build_detector(config, None)
    except InputError as exc:
        parser.error(str(exc))
    if args.kind not in detector.names:
        parser.error(f"--kind {args.kind}: {detector.name} has no class {args.kind!r}")
    try:
        views = [v for seed in args.seeds for v in _views(args, seed, detector)]
    except ValueError as exc:  # the actor out of view: --distance and --camera-height do not fit
        parser.error(f"{exc}; try another --distance or --camera-height")
    print(
        f"{detector.name}: the {args.kind} alone, {args.distance} m from a static camera at "
        f"{args.camera_height} m; seeds {args.seeds}, {args.moments} moments per heading; "
        f"recognised: a {args.kind} box with IoU >= {IOU_THRESHOLD} scoring >= {RECOGNISED}"
    )
    _report(views, args.kind)
    if args.sheet is not None:
        _sheet(views, args.sheet, columns=args.headings, kind=args.kind)
    return 0


if __name__ == "__main__":
    sys.exit(main())
