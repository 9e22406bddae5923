"""A run's dense map: its keyframes' depth stitched by their final poses, leaving out what the
run's rejection marked dynamic (``depotbench.slam.dense_map``), and scored against the exact
static world and the moving instances of a generated sequence (``depotbench.eval.metrics.map``).

The map is taken after the run, from each keyframe's pose as local bundle adjustment left it
(what method 2's map thread stitches with), its images as the tracker saw them (``mask`` runs:
blanked boxes) and its own rejection decisions. It is brought into the ground-truth frame by
its first keyframe: the SLAM's world is that keyframe's camera, and its true pose places it.
The trajectory's ATE alignment (Umeyama on positions) would not do: it leaves the rotation
undetermined for a camera that hardly moves (walking_static's moves under 2 cm), and a map
turned by it scored an F-score of 0 where the anchored one scores like the trajectory.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np
from depotbench.eval.metrics.alignment import Similarity
from depotbench.eval.metrics.map import DEFAULT_THRESHOLDS_M, ReferenceClouds, map_metrics, reference_clouds
from depotbench.eval.run.detections import sequence_fingerprint
from depotbench.eval.trackers.base import TrackerRun
from depotbench.eval.trackers.frames import FrameSource
from depotbench.slam.config import SlamConfig
from depotbench.slam.dense_map import DenseMap, exclusion_mask

SCORED_AT_M = 0.05
"""The threshold a run's headline map figures are given at (the middle of 2, 5 and 10 cm: a
Kinect-like sensor's noise keeps a perfect map at about 0.9 accuracy there, at 0.7 at 2 cm)."""


REFERENCES_KEPT = 2
"""Reference clouds a process keeps (a 90-frame hall is about 1M points, 50 MB with its trees):
a sweep's jobs come sequence by sequence, so the runs of one sequence build it once."""
_references: OrderedDict[tuple[str, str], ReferenceClouds] = OrderedDict()


def reference_of(sequence) -> ReferenceClouds:
    """``reference_clouds`` of a sequence, kept for the next run on it (keyed by its files)."""
    key = (str(sequence.root), sequence_fingerprint(sequence))
    if key in _references:
        _references.move_to_end(key)
        return _references[key]
    found = _references[key] = reference_clouds(sequence)
    while len(_references) > REFERENCES_KEPT:
        _references.popitem(last=False)
    return found


@dataclass(frozen=True)
class RunMap:
    """A run's map (the built-in tracker's dense map, or what an external program wrote at
    ``{map}``), in the run's world frame, and on a generated sequence its scores."""

    points: np.ndarray
    colours: np.ndarray
    keyframes: int | None
    """The keyframes the built-in map was stitched from; None for a program's own map."""
    scores: dict[str, Any] | None
    """``MapMetrics.to_json()`` with the threshold of the headline figures; None without a
    ground truth to score against (a real TUM folder)."""

    def figures(self) -> dict[str, Any]:
        """What metrics.json keeps of the map."""
        out: dict[str, Any] = {"points": len(self.points), "keyframes": self.keyframes}
        if self.scores is not None:
            out |= self.scores
        return out


def build_map(frames: FrameSource, run: TrackerRun, config: SlamConfig, strategy: str) -> DenseMap | None:
    """The dense map of a built-in run: None where the tracker reports no keyframe poses or no
    per-keypoint decisions (an external program)."""
    if run.keyframe_poses is None or run.results is None:
        return None
    sequence = frames.sequence
    camera = sequence.intrinsics
    dense = DenseMap()
    rule = "none" if strategy == "mask" else strategy  # mask: the boxes are blanked in the images
    for index, pose in sorted(run.keyframe_poses.items()):
        rgb, depth_raw = frames.images(index)
        depth_m = depth_raw.astype(np.float32) / np.float32(camera.depth_scale)
        detections = list(frames.detections(index))
        exclude = exclusion_mask(
            rule, run.results[index].diagnostics, detections, camera, rejection=config.rejection
        )
        dense.add_keyframe(pose, rgb, depth_m, camera, exclude)
    return dense


def anchor(sequence, run: TrackerRun) -> Similarity:
    """The rigid motion taking the run's world into the ground truth's: the first keyframe's
    (a program's map: the first tracked frame's) true pose times its estimated pose's inverse."""
    if run.keyframe_poses:
        first = min(run.keyframe_poses)
        estimated = run.keyframe_poses[first]
    else:
        first = next(i for i, pose in enumerate(run.poses) if pose is not None and run.tracked[i])
        estimated = run.poses[first]
    moved = sequence.world_from_camera(first) @ np.linalg.inv(estimated)
    return Similarity(moved[:3, :3], moved[:3, 3], 1.0)


def score_map(frames: FrameSource, points: np.ndarray, run: TrackerRun) -> dict[str, Any] | None:
    """The map against the sequence's exact static world and moving instances, at 2, 5 and 10 cm,
    placed by its first keyframe; None without a ground truth (a real TUM folder) or without a
    tracked frame to place it by."""
    sequence = frames.sequence
    if not sequence.is_generated or len(points) == 0 or (not run.keyframe_poses and not run.tracked.any()):
        return None
    placed = anchor(sequence, run)
    scores = map_metrics(points, reference_of(sequence), DEFAULT_THRESHOLDS_M, transform=placed)
    headline = scores.at(SCORED_AT_M)
    to_truth = np.eye(4)
    to_truth[:3, :3], to_truth[:3, 3] = placed.rotation, placed.translation
    return scores.to_json() | {
        "to_groundtruth": to_truth.tolist(),
        "threshold_m": SCORED_AT_M,
        "f_score": headline.f_score,
        "accuracy": headline.accuracy,
        "completeness": headline.completeness,
        "ghost_fraction": headline.ghost_fraction,
        "ghosts": dict(headline.ghosts),
    }


def run_map(frames: FrameSource, run: TrackerRun, config: SlamConfig, strategy: str) -> RunMap | None:
    """The run's map and its scores: the built-in tracker's dense map (``build_map``), or the
    map an external program wrote; None where the run has neither."""
    if run.map_points is not None:
        points, colours, keyframes = run.map_points, run.map_colours, None
    else:
        dense = build_map(frames, run, config, strategy)
        if dense is None:
            return None
        points, colours, keyframes = dense.points(), dense.colours(), dense.keyframes
    return RunMap(points, colours, keyframes, score_map(frames, points, run))
