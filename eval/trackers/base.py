"""What every tracker gives back, whoever wrote it: per frame a state, a pose and a time.

The built-in pipeline, ORB-SLAM3 (in a subprocess) and any external program all
return a ``TrackerRun``; per-keypoint diagnostics come only from the built-in one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
from depotbench.core.errors import InputError
from depotbench.eval.metrics.trajectory import Trajectory
from depotbench.eval.trackers.evidence import Evidence
from depotbench.eval.trackers.frames import FrameSource
from depotbench.slam.types import FrameResult, TrackingState

if TYPE_CHECKING:
    from depotbench.eval.trackers.protocol import KeypointDecisions


class TrackerError(InputError):
    """An external tracker that is missing, failed, or gave output we cannot read.

    ``log`` keeps the end of what the program printed, and ``evidence`` how it was started
    and what it wrote (bounded), for the failed run's folder (``evidence.write_evidence``)."""

    def __init__(self, message: str, log: str = "", evidence: Evidence | None = None) -> None:
        super().__init__(message)
        self.log = log
        self.evidence = evidence

    def __reduce__(self):  # it crosses from worker processes with its log and evidence
        return (type(self), (str(self), self.log, self.evidence))


@dataclass(frozen=True, eq=False)
class TrackerRun:
    timestamps_s: np.ndarray
    states: tuple[TrackingState, ...]
    poses: tuple[np.ndarray | None, ...]
    """world_from_camera of each frame; None where the tracker gave none (lost, not started)."""
    track_ms: np.ndarray
    """Per-frame tracking time as the tracker measures it; NaN where it reports none."""
    keyframes: int | None
    total_s: float
    """Wall time of the whole run, start-up included."""
    results: list[FrameResult] | None = None
    """The built-in pipeline's per-frame results (per-keypoint diagnostics)."""
    labels: list[np.ndarray] | None = None
    """True moving label of each keypoint of ``results`` (generated sequences)."""
    stage_ms: dict[str, np.ndarray] = field(default_factory=dict)
    """Per-frame time of each stage, where the tracker reports stages."""
    decisions: KeypointDecisions | None = None
    """An external program's keypoint decisions (``{keypoints}``), scored like ``results``."""
    peak_memory_mb: float | None = None
    """The peak resident memory of an external program and what it waited for."""
    cpu_s: float | None = None
    """The user plus system CPU time of an external program and what it waited for, start-up
    included; None for the built-in tracker (its ``track_ms`` is timed frame by frame)."""
    log: str = ""
    """The end of an external program's standard output and error (for the run folder)."""
    map_points: np.ndarray | None = None
    """An external program's map (``{map}``): points (N, 3) in the frame of its trajectory."""
    map_colours: np.ndarray | None = None
    keyframe_poses: dict[int, np.ndarray] | None = None
    """world_from_camera of each keyframe by frame index, as the run left it (after local
    bundle adjustment): what a dense map is stitched with. The built-in tracker's only."""

    def __post_init__(self) -> None:
        n = len(self.timestamps_s)
        if not (len(self.states) == len(self.poses) == len(self.track_ms) == n):
            raise ValueError("a tracker run needs one state, pose and time per frame")

    @property
    def tracked(self) -> np.ndarray:
        return np.array([s in (TrackingState.OK, TrackingState.RELOCALIZED) for s in self.states], bool)

    def trajectory(self) -> Trajectory | None:
        """The poses of the tracked frames, or None when no frame has one."""
        keep = [i for i, pose in enumerate(self.poses) if pose is not None and self.tracked[i]]
        if not keep:
            return None
        return Trajectory.from_poses(self.timestamps_s[keep], np.array([self.poses[i] for i in keep]))


class Tracker(Protocol):
    """Anything that turns frames into poses."""

    name: str

    def run(self, frames: FrameSource, progress: bool) -> TrackerRun: ...
