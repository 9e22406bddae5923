"""Tracking: the per-frame state machine of ORB-SLAM's Tracking for RGB-D.

Holds the state carried from frame to frame (state, last pose, constant-velocity motion
model, the last frame's map points, the reference keyframe) and the order of the steps: the
first frame with at least ``MIN_INIT_POINTS`` (50) usable keypoints with depth initialises
the map; then each frame is tracked with the motion model against the last frame's points
(at least ``MOTION_MODEL_MIN_MATCHES`` (20) matches, the search widened once), or against the
reference keyframe when that fails and for two frames after a relocalisation, then against
the local map (ORB-SLAM's predicted-scale search over the local keyframes), and a frame that
fails, or follows a lost one, is relocalised. It decides keyframes through local mapping.
Matching, pose solving, mapping and relocalisation live in the modules below it; this one
only calls them in ORB-SLAM's order.
"""

from __future__ import annotations

import copy

import cv2
import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam.config import TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.geometry import constant_velocity, invert, orthonormalize
from depotbench.slam.local_mapping import MAX_FRAMES, LocalMapping
from depotbench.slam.map import Map
from depotbench.slam.mapping_clock import MAX_QUEUED, MappingClock
from depotbench.slam.matcher import Matcher, octave_window
from depotbench.slam.optimize import refine_pose
from depotbench.slam.pose import MIN_MATCHES, Tracked, observations, solve_pose
from depotbench.slam.relocalisation import relocalise
from depotbench.slam.types import TrackingState

MIN_INIT_POINTS = 50
RELOCALISED_MIN_INLIERS = 50
"""TrackLocalMap needs 50 inliers (30 otherwise) within MAX_FRAMES (30) frames of a relocalisation."""
RELOCALISED_SEARCH_TH = 5.0
"""SearchLocalPoints widens th from 3 to 5 for the two frames after a relocalisation (ORB-SLAM)."""
FIRST_STAGE_MIN_INLIERS = 10
"""TrackWithMotionModel and TrackReferenceKeyFrame fail below 10 inliers (nmatchesMap)."""
MOTION_MODEL_MIN_MATCHES = 20
"""ORB-SLAM's TrackWithMotionModel widens its search below 20 matches and gives up below 20 again."""


def seed_frame(tracking: TrackingConfig, frame_index: int) -> None:
    """Seed OpenCV's RNG (the RANSACs of rejection and tracking) for a frame, before its
    rejection: decisions computed apart from the tracker (``depotbench.eval.run.stages.decision_path``,
    the shared frames of a branching run) then match the tracker's own."""
    cv2.setRNGSeed(tracking.seed + frame_index)


class Tracking:
    """The tracking state of one system and its map; ``Slam`` drives it frame by frame."""

    def __init__(self, tc: TrackingConfig, camera: Intrinsics) -> None:
        self.tc = tc
        self.camera = camera
        self.matcher = Matcher(tc, camera)
        self.mapping = LocalMapping(tc, camera)
        self.clock = MappingClock(self.mapping, tc.mapper_time_scale) if tc.mapper_time_scale > 0 else None
        """ORB-SLAM3's mapping thread on a virtual clock; None maps each keyframe at once."""
        self.map = Map()
        self.state = TrackingState.NOT_INITIALIZED
        self.frame_index = 0
        self.previous: FrameFeatures | None = None
        self._last_pose: np.ndarray | None = None
        self._velocity = np.eye(4)
        self._last_point_ids = np.zeros(0, int)
        self._last_angles = np.zeros(0)
        self._last_octaves = np.zeros(0, int)
        self._reference_keyframe = 0
        self._relocalised_at: int | None = None
        self._tracked_pose = np.eye(4)
        """The frame's pose as tracked, before a keyframe's bundle adjustment moves it."""
        self._outliers = (np.zeros(0, int), np.zeros(0, int))
        """The last frame's matches the final pose optimisation set aside (keypoints, point ids)."""

    def fork(self) -> Tracking:
        """An independent copy (the map too); matcher, mapper and features are shared: they
        hold no state, or nothing changes them."""
        twin = copy.copy(self)
        twin.map = self.map.copy()
        twin.clock = None if self.clock is None else self.clock.copy()
        for name in (
            "_last_pose",
            "_velocity",
            "_last_point_ids",
            "_last_angles",
            "_last_octaves",
            "_tracked_pose",
        ):
            value = getattr(self, name)
            setattr(twin, name, None if value is None else value.copy())
        return twin

    # -- the steps of one frame, in the order Slam.process calls them -----------------

    def track(self, features: FrameFeatures, usable: np.ndarray) -> tuple[Tracked | None, TrackingState]:
        """The frame's pose and matches (None when it has none) and its state: initialise,
        else track (after OK or RELOCALIZED) and relocalise when that fails."""
        if self.state == TrackingState.NOT_INITIALIZED:
            tracked = self._initialize(features, usable)
            return tracked, TrackingState.OK if tracked else TrackingState.NOT_INITIALIZED
        tracked = None
        state = TrackingState.LOST
        if self.state in (TrackingState.OK, TrackingState.RELOCALIZED):
            tracked = self._track(features, usable)  # sets the frame's set-aside matches
            state = TrackingState.OK if tracked else TrackingState.LOST
        if tracked is None:
            self._outliers = (np.zeros(0, int), np.zeros(0, int))  # only a tracked frame has some
            tracked = relocalise(self.map, self.matcher, self.tc, self.camera, features, usable)
            if tracked is not None:
                state = TrackingState.RELOCALIZED
        return tracked, state

    def catch_up(self, time_s: float) -> None:
        """Before a frame arriving at ``time_s`` is tracked: the mapping steps that end by then."""
        if self.clock is not None:
            self.clock.run_until(self.map, time_s, inclusive=False)

    def keyframe(
        self, features: FrameFeatures, usable: np.ndarray, tracked: Tracked | None, time_s: float = 0.0
    ) -> tuple[bool, tuple[np.ndarray, np.ndarray] | None]:
        """Whether the tracked frame (arrived at ``time_s``) is a keyframe, inserting it when
        due, and the map points it added (keypoints, ids), which the next frame searches too."""
        if tracked is None:
            return False, None
        if self.state == TrackingState.NOT_INITIALIZED:
            return True, None  # the initial keyframe, inserted by _initialize
        since = None if self._relocalised_at is None else self.frame_index - self._relocalised_at
        self._tracked_pose = tracked.world_from_camera.copy()
        clock = self.clock
        idle = clock is None or clock.idle
        since_keyframe = self.frame_index - self.map.all_keyframes[-1].frame_index
        wanted = self.mapping.need_keyframe(
            self.map, features, usable, tracked, self._reference_keyframe, since, idle, since_keyframe
        )
        if wanted and not idle:
            clock.interrupt(time_s)
        if wanted and (idle or clock.waiting < MAX_QUEUED):
            return True, self._insert_keyframe(features, usable, tracked, time_s)
        return False, None

    def advance(
        self,
        features: FrameFeatures,
        tracked: Tracked | None,
        state: TrackingState,
        new_points: tuple[np.ndarray, np.ndarray] | None,
    ) -> None:
        """Make this frame the last one. Its map points are the pose inliers and, on a
        keyframe, the points just made from it: ORB-SLAM puts those into the frame, so the
        next frame searches them too (people close to the camera among them). The motion
        model is the motion to the frame's tracked pose (ORB-SLAM updates it before the
        keyframe's bundle adjustment); the next prediction starts from the adjusted pose."""
        if tracked is not None:
            if self._last_pose is not None and state == TrackingState.OK:
                self._velocity = constant_velocity(self._last_pose, self._tracked_pose)
            else:
                self._velocity = np.eye(4)
            self._last_pose = orthonormalize(tracked.world_from_camera)
            keypoints, point_ids = tracked.keypoints, tracked.point_ids
            if new_points is not None:
                keypoints, point_ids = np.r_[keypoints, new_points[0]], np.r_[point_ids, new_points[1]]
            self._last_point_ids = point_ids
            self._last_angles = features.angles_deg[keypoints]
            self._last_octaves = features.octaves[keypoints]
        if state == TrackingState.RELOCALIZED:
            self._relocalised_at = self.frame_index
        self.state = state
        self.previous = features
        self.frame_index += 1

    # -- inside ------------------------------------------------------------------------

    def _insert_keyframe(
        self, features: FrameFeatures, usable: np.ndarray, tracked: Tracked, time_s: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Insert the keyframe and map it: at once, or through the clock (which maps it now
        only if its steps take no time). A frame whose keyframe is mapped moves to its
        adjusted pose; the points it made from depth are those left after fusion."""
        new = self.mapping.insert_keyframe(
            self.map, features, usable, tracked, self.frame_index, self._outliers
        )
        keyframe = self.map.all_keyframes[-1]
        if keyframe.id > 0:
            if self.clock is None:
                self.mapping.map_keyframe(self.map, keyframe.id)
            else:
                self.clock.insert(keyframe.id, time_s)
                self.clock.run_until(self.map, time_s, inclusive=True)
            if self.clock is None or self.clock.idle:
                tracked.world_from_camera = keyframe.world_from_camera.copy()
        self._reference_keyframe = keyframe.id  # ORB-SLAM: mpReferenceKF = pKF
        made = np.flatnonzero(new & (keyframe.point_ids >= 0))
        return made, keyframe.point_ids[made]

    def _initialize(self, features: FrameFeatures, usable: np.ndarray) -> Tracked | None:
        candidates = usable & (features.depth_m > 0)
        if candidates.sum() < MIN_INIT_POINTS:
            return None
        tracked = Tracked(np.eye(4), np.zeros(0, int), np.zeros(0, int), int(candidates.sum()))
        self._insert_keyframe(features, usable, tracked)
        keyframe = self.map.keyframes[-1]
        with_point = np.flatnonzero(keyframe.point_ids >= 0)
        return Tracked(np.eye(4), with_point, keyframe.point_ids[with_point], len(with_point))

    def _track(self, features: FrameFeatures, usable: np.ndarray) -> Tracked | None:
        """Track with the motion model against the last frame's points, or against the
        reference keyframe when that fails or right after a relocalisation, then against the
        local map (ORB-SLAM's TrackWithMotionModel, TrackReferenceKeyFrame, TrackLocalMap)."""
        assert self._last_pose is not None
        recently = self._relocalised_at is not None and self.frame_index < self._relocalised_at + 2
        first = None if recently else self._track_motion_model(features, usable)
        if first is None:
            first = self._track_reference_keyframe(features, usable)
        if first is None:
            return None
        pose_cw, kp, pid, searched = first
        self.map.visible[pid] += 1  # seen in this frame, as the local map's points below
        # Local map: points of the keyframes around those that see the tracked points.
        local_ids = self._local_points(pid)
        searched_before = np.zeros(len(self.map.positions), bool)
        searched_before[searched] = True
        matched = np.zeros(len(features), bool)
        matched[kp] = True
        new_kp, new_pid, projected = self.matcher.search_local_points(
            self.map,
            local_ids[~searched_before[local_ids]],  # both ascending: as setdiff1d, 0.3 ms sooner
            pose_cw,
            features,
            usable,
            matched,
            RELOCALISED_SEARCH_TH if recently else self.tc.local_search_th,
        )
        self.map.visible[projected] += 1
        kp, pid = np.r_[kp, new_kp], np.r_[pid, new_pid]
        if len(kp) < MIN_MATCHES:
            return None
        uv, ur, weight = observations(self.tc, features, kp)
        pose_cw, inl = refine_pose(
            pose_cw, self.map.positions[pid], uv, ur, weight, self.camera, self.tc.baseline_fx
        )
        self._outliers = (kp[~inl], pid[~inl])
        kp, pid = kp[inl], pid[inl]
        self.map.found[pid] += 1
        after_relocalisation = (
            self._relocalised_at is not None and self.frame_index < self._relocalised_at + MAX_FRAMES
        )
        if len(kp) < (RELOCALISED_MIN_INLIERS if after_relocalisation else self.tc.min_inliers):
            return None
        return Tracked(invert(pose_cw), kp, pid, len(kp))

    def _track_motion_model(
        self, features: FrameFeatures, usable: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """ORB-SLAM's TrackWithMotionModel: the last frame's points searched around their
        projection by the constant-velocity prediction (twice as wide below 20 matches), the
        pose optimised from the prediction; it fails below 20 matches or 10 inliers.
        Returns (camera_from_world, inlier keypoints, their points, every point matched)."""
        assert self._last_pose is not None
        predicted_cw = invert(self._last_pose @ self._velocity)
        resolved = self.map.resolve(self._last_point_ids)  # points fused since: their survivors
        has_point = resolved >= 0
        last_ids, last_angles = resolved[has_point], self._last_angles[has_point]
        octaves = self._last_octaves[has_point]
        radius = self.tc.match_radius_px * self.tc.scale_factor**octaves
        window = octave_window(
            octaves, self._velocity[2, 3], self.tc.baseline_fx / self.camera.fx, self.tc.n_levels
        )
        for widen in (1, 2):  # ORB-SLAM searches again at twice the radius below 20 matches
            kp, pid, _ = self.matcher.search_by_projection(
                self.map,
                last_ids,
                predicted_cw,
                features,
                usable,
                widen * radius,
                reference_angles=last_angles,
                octave_window=window,
                depth_check=True,
            )
            if len(kp) >= MOTION_MODEL_MIN_MATCHES:
                break
        if len(kp) < MOTION_MODEL_MIN_MATCHES:
            return None
        return self._optimise(features, kp, pid, predicted_cw)

    def _track_reference_keyframe(
        self, features: FrameFeatures, usable: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """ORB-SLAM's TrackReferenceKeyFrame: the reference keyframe's points matched by
        descriptor (``Matcher.search_keyframe``), at least 15, the pose optimised from the last
        frame's; it fails below 10 inliers."""
        assert self._last_pose is not None
        live = [kf.id for kf in self.map.keyframes]
        if not live:
            return None
        reference = self.map.keyframe(
            self._reference_keyframe if self._reference_keyframe in live else live[-1]
        )
        with_point = np.flatnonzero(reference.point_ids >= 0)
        kp, pid = self.matcher.search_keyframe(
            self.map,
            reference.point_ids[with_point],
            reference.features.angles_deg[with_point],
            features,
            usable,
        )
        if len(kp) < MIN_MATCHES:
            return None
        return self._optimise(features, kp, pid, invert(self._last_pose))

    def _optimise(
        self, features: FrameFeatures, kp: np.ndarray, pid: np.ndarray, guess_cw: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Optimise the pose from ``guess_cw`` on the matches (``solve_pose``: PnP RANSAC first
        with ``motion_model_ransac``, or as a fallback); at least ``FIRST_STAGE_MIN_INLIERS``
        (10) inliers, as ORB-SLAM's nmatchesMap >= 10."""
        solved = solve_pose(self.tc, self.camera, features, kp, self.map.positions[pid], guess_cw)
        if solved is None or solved[1].sum() < FIRST_STAGE_MIN_INLIERS:
            return None
        pose_cw, inl = solved
        return pose_cw, kp[inl], pid[inl], pid

    def _local_points(self, point_ids: np.ndarray) -> np.ndarray:
        """The points of the local keyframes (ORB-SLAM's UpdateLocalKeyFrames): every keyframe
        that sees one of ``point_ids``, and for each of those, while the set holds at most
        ``local_keyframes`` (80): its best covisible keyframe not yet in, a child not yet in,
        and its parent, after which the search stops (ORB-SLAM breaks out of the loop there).
        The keyframe seeing the most of ``point_ids`` becomes the reference."""
        counts = self.map.sightings(point_ids)
        seeing = [int(k) for k in np.flatnonzero(counts)]
        if not seeing:
            return np.zeros(0, int)
        self._reference_keyframe = seeing[int(np.argmax(counts[seeing]))]  # the first of the most
        local = list(seeing)
        included = set(local)
        for kf_id in seeing:
            if len(local) > self.tc.local_keyframes:
                break
            for extra in (self.map.covisible(kf_id, 10), self.map.children(kf_id)):
                new = [int(k) for k in extra if int(k) not in included][:1]
                local += new
                included.update(new)
            parent = self.map.keyframe(kf_id).parent
            if parent >= 0 and parent not in included and not self.map.keyframe(parent).bad:
                local.append(parent)
                included.add(parent)
                break
        return self.map.points_of(local)
