"""The RGB-D SLAM system: one frame in, its pose and per-keypoint diagnostics out.

Follows ORB-SLAM2's RGB-D structure, one module per part: ``tracking`` (the per-frame state
machine: motion model, reference keyframe, local map, relocalisation), ``matcher`` (search by
projection, the local-map search, fusion and triangulation pairs, search by descriptor),
``map`` (keyframes, points and the covisibility graph), ``pose`` (PnP RANSAC and robust pose
refinement), ``local_mapping`` (keyframes, new points from depth and by triangulation,
fusion, point and keyframe culling, local bundle adjustment) and ``relocalisation``.
``Slam`` is their face: it extracts features, runs the rejection strategy (which decides the
keypoints tracking and mapping may use), steps tracking and times each stage. Mapping runs
synchronously (so runs are deterministic) and its time is reported apart from tracking, as
ORB-SLAM reports them.
"""

from __future__ import annotations

import copy
import time

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam.config import SlamConfig, check_pyramid
from depotbench.slam.features import FeatureExtractor, FrameFeatures
from depotbench.slam.map import Map
from depotbench.slam.matcher import consistent_rotation as _consistent_rotation
from depotbench.slam.rejection import Flow, box_classes, classify
from depotbench.slam.tracking import Tracking, seed_frame
from depotbench.slam.types import (
    REJECTION_CODES,
    Frame,
    FrameDiagnostics,
    FrameResult,
    Rejection,
    TrackingState,
)

__all__ = ["Slam", "_consistent_rotation", "seed_frame"]
"""``seed_frame`` and ``_consistent_rotation`` are imported from here by eval and the tests."""


class Slam:
    def __init__(self, config: SlamConfig, camera: Intrinsics) -> None:
        check_pyramid(config.tracking, camera.width, camera.height)
        self.config = config
        self.tc = config.tracking
        self.camera = camera
        self.extractor = FeatureExtractor(self.tc)
        self.tracking = Tracking(self.tc, camera)
        self.trajectory: list[tuple[float, np.ndarray]] = []

    @property
    def map(self) -> Map:
        return self.tracking.map

    @property
    def state(self) -> TrackingState:
        return self.tracking.state

    @property
    def frame_index(self) -> int:
        return self.tracking.frame_index

    def fork(self, config: SlamConfig) -> Slam:
        """An independent copy of this system's state that goes on with ``config``.

        Sweeps run configurations that keep the same keypoints up to some frame once up
        to there and fork (``depotbench.eval.trackers.builtin.BuiltinTracker.run_tree``). Only the
        rejection settings may differ: tracking with other settings is another run.
        """
        if config.tracking != self.tc:
            raise ValueError("a fork may change rejection settings only, not tracking settings")
        twin = copy.copy(self)  # the extractor and camera are shared; they hold no state
        twin.config = config
        twin.tracking = self.tracking.fork()
        twin.trajectory = list(self.trajectory)
        return twin

    def process(
        self, frame: Frame, features: FrameFeatures | None = None, flow: Flow | None = None
    ) -> FrameResult:
        """Track one frame. ``features`` (see ``extract``) and ``flow`` (LK of every keypoint
        into the previous frame, ``rejection.flow_to_previous``) may come from a cache; then
        the frame's images are not read."""
        tracking = self.tracking
        seed_frame(self.tc, tracking.frame_index)
        times: dict[str, float] = {}
        start = time.perf_counter()
        if features is None:
            features = self.extract(frame)
        times["extract"] = (time.perf_counter() - start) * 1e3
        start = time.perf_counter()
        tracking.catch_up(frame.timestamp_s)  # the mapping steps that end before this frame
        caught_up_ms = (time.perf_counter() - start) * 1e3
        start = time.perf_counter()
        codes = classify(
            self.config.strategy, features, tracking.previous, frame.detections, self.config.rejection, flow
        )
        usable = codes == REJECTION_CODES[Rejection.KEPT]
        times["reject"] = (time.perf_counter() - start) * 1e3
        start = time.perf_counter()
        tracked, state = tracking.track(features, usable)
        times["track"] = (time.perf_counter() - start) * 1e3
        times["tracking_total"] = times["extract"] + times["reject"] + times["track"]
        start = time.perf_counter()
        keyframe, carried = tracking.keyframe(features, usable, tracked, frame.timestamp_s)
        times["mapping"] = caught_up_ms + (time.perf_counter() - start) * 1e3
        tracking.advance(features, tracked, state, carried)
        inlier = np.zeros(len(features), bool)
        pose = None
        if tracked is not None:
            inlier[tracked.keypoints] = True
            pose = tracked.world_from_camera.copy()
            self.trajectory.append((frame.timestamp_s, pose))
        diagnostics = FrameDiagnostics(
            timestamp_s=frame.timestamp_s,
            state=state,
            keypoints_px=features.keypoints_px,
            keypoint_classes=box_classes(
                features.keypoints_px, list(frame.detections), self.config.rejection.box_dilation_px
            ),
            rejection=codes,
            inlier=inlier,
            stage_ms=times,
            keyframe=keyframe,
        )
        return FrameResult(frame.timestamp_s, pose, state, diagnostics)

    def extract(self, frame: Frame) -> FrameFeatures:
        return self.extractor.extract(frame.rgb, frame.depth_m, self.camera)
