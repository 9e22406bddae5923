"""The RGB-D SLAM system: tracking with rejection, keyframes, local mapping, relocalisation.

Follows ORB-SLAM2's RGB-D structure: a constant-velocity motion model predicts
the pose, the last frame's map points are matched by projection, PnP RANSAC and
a robust (Huber) pose optimisation give the pose, the local map is matched and
the pose optimised again; keyframes add map points from depth and trigger a
local bundle adjustment and point culling. Mapping runs synchronously (so runs
are deterministic) and its time is reported apart from tracking, as ORB-SLAM
reports them. Rejection decides which keypoints tracking and mapping may use.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass

import cv2
import numpy as np
from depotbench.slam.bundle import BundleWindow, bundle_adjust
from depotbench.slam.config import SlamConfig, TrackingConfig, check_pyramid
from depotbench.slam.features import FeatureExtractor, FrameFeatures
from depotbench.slam.geometry import (
    backproject,
    constant_velocity,
    hamming,
    hamming_matrix,
    invert,
    orthonormalize,
    project,
    transform,
)
from depotbench.slam.map import KeyFrame, Map
from depotbench.slam.optimize import refine_pose
from depotbench.slam.rejection import Flow, box_classes, classify
from depotbench.slam.types import (
    REJECTION_CODES,
    Frame,
    FrameDiagnostics,
    FrameResult,
    PinholeCamera,
    Rejection,
    TrackingState,
)
from scipy.spatial import cKDTree

MIN_INIT_POINTS = 50
MIN_MATCHES = 15
MOTION_MODEL_MIN_MATCHES = 20
"""ORB-SLAM's TrackWithMotionModel widens its search below 20 matches and gives up below 20 again."""
ROTATION_BINS = 30
"""Matches against the last frame keep the 3 most common keypoint-angle changes (ORB-SLAM)."""
NEIGHBOURS = 8
"""Keypoints within the search radius considered per projected map point (nearest first)."""
RATIO_TEST = 0.8
"""Relocalisation's nearest/second-nearest test. It compares against every point of a keyframe
(ORB-SLAM: only within a vocabulary node), which is strict enough that TH_LOW (50) on top left
a prior_flow run on a 3-walker xyz scene lost for its last 92 of 200 frames; with TH_HIGH it
relocalised and tracked 152 of them (measured)."""
CLOSE_DEPTH_FACTOR = 40.0
"""ORB-SLAM's ThDepth: points closer than 40 baselines are 'close'."""


@dataclass
class _Tracked:
    world_from_camera: np.ndarray
    keypoints: np.ndarray
    point_ids: np.ndarray
    inliers: int


def _consistent_rotation(delta_deg: np.ndarray) -> np.ndarray:
    """Mask of matches whose keypoint-angle change falls in the 3 most common of 30 bins
    (ORB-SLAM's rotation-consistency check; a bin needs 10 % of the largest one's count)."""
    bins = (np.mod(delta_deg, 360.0) / (360.0 / ROTATION_BINS)).astype(int) % ROTATION_BINS
    counts = np.bincount(bins, minlength=ROTATION_BINS)
    top = np.argsort(-counts, kind="stable")[:3]
    top = top[counts[top] >= 0.1 * counts[top[0]]]
    return np.isin(bins, top)


def seed_frame(tracking: TrackingConfig, frame_index: int) -> None:
    """Seed OpenCV's RNG (the RANSACs of rejection and tracking) for a frame, before its
    rejection: decisions computed apart from the tracker (``depotbench.eval.run.stages.decision_path``,
    the shared frames of a branching run) then match the tracker's own."""
    cv2.setRNGSeed(tracking.seed + frame_index)


class Slam:
    def __init__(self, config: SlamConfig, camera: PinholeCamera) -> None:
        check_pyramid(config.tracking, camera.width, camera.height)
        self.config = config
        self.tc = config.tracking
        self.camera = camera
        self.bf = self.tc.baseline_fx
        self.close_depth_m = CLOSE_DEPTH_FACTOR * self.bf / camera.fx
        self.extractor = FeatureExtractor(self.tc)
        self.map = Map()
        self.state = TrackingState.NOT_INITIALIZED
        self.frame_index = 0
        self._previous: FrameFeatures | None = None
        self._last_pose: np.ndarray | None = None
        self._velocity = np.eye(4)
        self._last_point_ids = np.zeros(0, int)
        self._last_angles = np.zeros(0)
        self._last_octaves = np.zeros(0, int)
        self._reference_keyframe = 0
        self.trajectory: list[tuple[float, np.ndarray]] = []

    # -- public -----------------------------------------------------------------

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
        twin.map = self.map.copy()
        twin.trajectory = list(self.trajectory)
        for name in ("_last_pose", "_velocity", "_last_point_ids", "_last_angles", "_last_octaves"):
            value = getattr(self, name)
            setattr(twin, name, None if value is None else value.copy())
        return twin

    def process(
        self, frame: Frame, features: FrameFeatures | None = None, flow: Flow | None = None
    ) -> FrameResult:
        """Track one frame. ``features`` (see ``extract``) and ``flow`` (LK of every keypoint
        into the previous frame, ``rejection.flow_to_previous``) may come from a cache; then
        the frame's images are not read."""
        seed_frame(self.tc, self.frame_index)
        times: dict[str, float] = {}
        start = time.perf_counter()
        if features is None:
            features = self.extract(frame)
        times["extract"] = (time.perf_counter() - start) * 1e3
        start = time.perf_counter()
        codes = classify(
            self.config.strategy, features, self._previous, frame.detections, self.config.rejection, flow
        )
        usable = codes == REJECTION_CODES[Rejection.KEPT]
        times["reject"] = (time.perf_counter() - start) * 1e3
        start = time.perf_counter()
        tracked: _Tracked | None = None
        if self.state == TrackingState.NOT_INITIALIZED:
            tracked = self._initialize(features, usable)
            state = TrackingState.OK if tracked else TrackingState.NOT_INITIALIZED
        else:
            state = TrackingState.LOST
            if self.state in (TrackingState.OK, TrackingState.RELOCALIZED):
                tracked = self._track(features, usable)
                state = TrackingState.OK if tracked else TrackingState.LOST
            if tracked is None:
                tracked = self._relocalize(features, usable)
                if tracked is not None:
                    state = TrackingState.RELOCALIZED
        times["track"] = (time.perf_counter() - start) * 1e3
        times["tracking_total"] = times["extract"] + times["reject"] + times["track"]
        start = time.perf_counter()
        keyframe = False
        carried = None
        if tracked is not None and self.state != TrackingState.NOT_INITIALIZED:
            if self._need_keyframe(features, usable, tracked):
                carried = self._insert_keyframe(features, usable, tracked)
                keyframe = True
        elif tracked is not None:
            keyframe = True  # the initial keyframe
        times["mapping"] = (time.perf_counter() - start) * 1e3
        self._advance(features, tracked, state, carried)
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

    # -- tracking ---------------------------------------------------------------

    def _advance(
        self,
        features: FrameFeatures,
        tracked: _Tracked | None,
        state: TrackingState,
        new_points: tuple[np.ndarray, np.ndarray] | None,
    ) -> None:
        """Make this frame the last one. Its map points are the pose inliers and, on a
        keyframe, the points just made from it: ORB-SLAM puts those into the frame, so the
        next frame searches them too (people close to the camera among them)."""
        if tracked is not None:
            if self._last_pose is not None and state == TrackingState.OK:
                self._velocity = constant_velocity(self._last_pose, tracked.world_from_camera)
            else:
                self._velocity = np.eye(4)
            self._last_pose = orthonormalize(tracked.world_from_camera)
            keypoints, point_ids = tracked.keypoints, tracked.point_ids
            if new_points is not None:
                keypoints, point_ids = np.r_[keypoints, new_points[0]], np.r_[point_ids, new_points[1]]
            self._last_point_ids = point_ids
            self._last_angles = features.angles_deg[keypoints]
            self._last_octaves = features.octaves[keypoints]
        self.state = state
        self._previous = features
        self.frame_index += 1

    def _observations(self, features: FrameFeatures, keypoints: np.ndarray) -> tuple[np.ndarray, ...]:
        uv = features.undistorted_px[keypoints]
        depth = features.depth_m[keypoints]
        ur = np.where(depth > 0, uv[:, 0] - self.bf / np.where(depth > 0, depth, 1.0), np.nan)
        weight = 1.0 / self.tc.scale_factor ** features.octaves[keypoints]
        return uv, ur, weight

    def _initialize(self, features: FrameFeatures, usable: np.ndarray) -> _Tracked | None:
        candidates = usable & (features.depth_m > 0)
        if candidates.sum() < MIN_INIT_POINTS:
            return None
        tracked = _Tracked(np.eye(4), np.zeros(0, int), np.zeros(0, int), int(candidates.sum()))
        self._insert_keyframe(features, usable, tracked)
        keyframe = self.map.keyframes[-1]
        with_point = np.flatnonzero(keyframe.point_ids >= 0)
        return _Tracked(np.eye(4), with_point, keyframe.point_ids[with_point], len(with_point))

    def _match_by_projection(
        self,
        point_ids: np.ndarray,
        camera_from_world: np.ndarray,
        features: FrameFeatures,
        usable: np.ndarray,
        radius: float | np.ndarray,
        exclude: np.ndarray | None = None,
        reference_angles: np.ndarray | None = None,
        octave_window: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Matches (keypoint indices, point ids) of map points projected near usable keypoints;
        also returns the ids that projected into the image (for visibility counts).

        ``radius`` is one value or one per point; ``octave_window`` (lowest, highest) per point
        limits the pyramid levels a match may come from, as ORB-SLAM's search does.
        """
        empty = (np.zeros(0, int), np.zeros(0, int), np.zeros(0, int))
        angles = reference_angles
        per_point = {"radius": np.broadcast_to(np.asarray(radius, float), point_ids.shape)}
        if octave_window is not None:
            per_point["low"], per_point["high"] = octave_window
        if len(point_ids):
            alive = self.map.alive[point_ids]
            point_ids = point_ids[alive]
            angles = None if angles is None else angles[alive]
            per_point = {k: v[alive] for k, v in per_point.items()}
        candidates = np.flatnonzero(usable)
        if exclude is not None:
            candidates = candidates[~exclude[candidates]]
        if len(point_ids) == 0 or len(candidates) == 0:
            return empty
        pc = transform(camera_from_world, self.map.positions[point_ids])
        front = pc[:, 2] > self.tc.min_depth_m
        point_ids, pc = point_ids[front], pc[front]
        angles = None if angles is None else angles[front]
        per_point = {k: v[front] for k, v in per_point.items()}
        uv = project(self.camera, pc)
        inside = (
            (uv[:, 0] >= 0)
            & (uv[:, 0] < self.camera.width)
            & (uv[:, 1] >= 0)
            & (uv[:, 1] < self.camera.height)
        )
        point_ids, uv = point_ids[inside], uv[inside]
        angles = None if angles is None else angles[inside]
        per_point = {k: v[inside] for k, v in per_point.items()}
        if len(point_ids) == 0:
            return empty
        tree = cKDTree(features.undistorted_px[candidates])
        gap, nearest = tree.query(uv, k=NEIGHBOURS, distance_upper_bound=float(per_point["radius"].max()))
        found = (nearest < len(candidates)) & (gap <= per_point["radius"][:, None])
        pairs_point = np.nonzero(found)[0]
        if len(pairs_point) == 0:
            return (*empty[:2], point_ids)
        pairs_kp = candidates[nearest[found]]
        if octave_window is not None:
            level = features.octaves[pairs_kp]
            fits = (level >= per_point["low"][pairs_point]) & (level <= per_point["high"][pairs_point])
            pairs_point, pairs_kp = pairs_point[fits], pairs_kp[fits]
        distance = hamming(self.map.descriptors[point_ids[pairs_point]], features.descriptors[pairs_kp])
        good = distance <= self.tc.match_max_hamming
        if not good.any():
            return (*empty[:2], point_ids)
        pairs_point, pairs_kp, distance = pairs_point[good], pairs_kp[good], distance[good]
        # Best keypoint per point, then best point per keypoint (one-to-one).
        order = np.lexsort((distance, pairs_point))
        first = np.r_[True, np.diff(pairs_point[order]) != 0]
        best = order[first]
        order = np.lexsort((distance[best], pairs_kp[best]))
        first = np.r_[True, np.diff(pairs_kp[best][order]) != 0]
        best = best[order[first]]
        if angles is not None and len(best):
            best = best[_consistent_rotation(features.angles_deg[pairs_kp[best]] - angles[pairs_point[best]])]
        return pairs_kp[best], point_ids[pairs_point[best]], point_ids

    def _solve(
        self,
        features: FrameFeatures,
        keypoints: np.ndarray,
        point_ids: np.ndarray,
        guess_cw: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Robust pose from matches: (camera_from_world, inlier mask) or None.

        With a guess (the motion model's prediction) and ``motion_model_ransac`` off, the
        refinement starts from the guess, as ORB-SLAM's TrackWithMotionModel does; PnP RANSAC
        runs when there is no guess, when that is on, or when refining from the guess keeps
        fewer than ``MIN_MATCHES`` inliers (ORB-SLAM then falls back to its reference keyframe).
        """
        if len(keypoints) < 6:
            return None
        points_w = self.map.positions[point_ids]
        uv, ur, weight = self._observations(features, keypoints)
        from_guess = None
        if guess_cw is not None and not self.tc.motion_model_ransac:
            from_guess = refine_pose(guess_cw, points_w, uv, ur, weight, self.camera, self.bf)
            if from_guess[1].sum() >= MIN_MATCHES:
                return from_guess
        ok, rvec, tvec, _ = cv2.solvePnPRansac(
            points_w.astype(np.float64),
            uv,
            self.camera.matrix,
            None,
            iterationsCount=self.tc.ransac_iterations,
            reprojectionError=self.tc.ransac_reprojection_px,
            confidence=0.99,
            flags=cv2.SOLVEPNP_EPNP,
        )
        if not ok:
            if from_guess is not None or guess_cw is None:
                return from_guess
            return refine_pose(guess_cw, points_w, uv, ur, weight, self.camera, self.bf)
        pose_cw = np.eye(4)
        pose_cw[:3, :3] = cv2.Rodrigues(rvec)[0]
        pose_cw[:3, 3] = tvec.ravel()
        return refine_pose(pose_cw, points_w, uv, ur, weight, self.camera, self.bf)

    def _octave_window(self, octaves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pyramid levels where the last frame's points may be found (ORB-SLAM's
        SearchByProjection): after moving forward by more than the baseline the camera sees
        them larger (at their level or a coarser one), after moving back smaller (at their
        level or a finer one), else within one level of theirs."""
        forward = self._velocity[2, 3]
        baseline = self.bf / self.camera.fx
        if forward > baseline:
            return octaves, np.full_like(octaves, self.tc.n_levels)
        if -forward > baseline:
            return np.zeros_like(octaves), octaves
        return octaves - 1, octaves + 1

    def _track(self, features: FrameFeatures, usable: np.ndarray) -> _Tracked | None:
        assert self._last_pose is not None
        predicted_cw = invert(self._last_pose @ self._velocity)
        has_point = self._last_point_ids >= 0
        last_ids, last_angles = self._last_point_ids[has_point], self._last_angles[has_point]
        octaves = self._last_octaves[has_point]
        radius = self.tc.match_radius_px * self.tc.scale_factor**octaves
        window = self._octave_window(octaves)
        for widen in (1, 2):  # ORB-SLAM searches again at twice the radius below 20 matches
            kp, pid, _ = self._match_by_projection(
                last_ids,
                predicted_cw,
                features,
                usable,
                widen * radius,
                reference_angles=last_angles,
                octave_window=window,
            )
            if len(kp) >= MOTION_MODEL_MIN_MATCHES:
                break
        if len(kp) < MOTION_MODEL_MIN_MATCHES:
            return None
        solved = self._solve(features, kp, pid, predicted_cw)
        if solved is None:
            return None
        pose_cw, inl = solved
        kp, pid = kp[inl], pid[inl]
        self.map.visible[pid] += 1  # seen in this frame, as the local map's points below
        # Local map: points of the keyframes that see the tracked points.
        local_ids = self._local_points(pid)
        matched = np.zeros(len(features), bool)
        matched[kp] = True
        new_kp, new_pid, projected = self._match_by_projection(
            np.setdiff1d(local_ids, pid),
            pose_cw,
            features,
            usable,
            self.tc.local_radius_px,
            exclude=matched,
        )
        self.map.visible[projected] += 1
        kp, pid = np.r_[kp, new_kp], np.r_[pid, new_pid]
        if len(kp) < MIN_MATCHES:
            return None
        uv, ur, weight = self._observations(features, kp)
        pose_cw, inl = refine_pose(pose_cw, self.map.positions[pid], uv, ur, weight, self.camera, self.bf)
        kp, pid = kp[inl], pid[inl]
        self.map.found[pid] += 1
        if len(kp) < self.tc.min_inliers:
            return None
        return _Tracked(invert(pose_cw), kp, pid, len(kp))

    def _local_points(self, point_ids: np.ndarray) -> np.ndarray:
        """Points of the keyframes that see the frame's points, most shared first; the keyframe
        sharing the most becomes the reference (ORB-SLAM's UpdateLocalKeyFrames)."""
        counts: dict[int, int] = {}
        for point in point_ids:
            for kf_id in self.map.observations.get(int(point), {}):
                counts[kf_id] = counts.get(kf_id, 0) + 1
        local = sorted(counts, key=lambda k: (-counts[k], -k))[: self.tc.local_keyframes]
        if local:
            self._reference_keyframe = local[0]
        ids = [kf.point_ids[kf.point_ids >= 0] for kf in (self.map.keyframe(k) for k in local)]
        if not ids:
            return np.zeros(0, int)
        ids_all = np.unique(np.concatenate(ids))
        return ids_all[self.map.alive[ids_all]]

    def _relocalize(self, features: FrameFeatures, usable: np.ndarray) -> _Tracked | None:
        candidates = np.flatnonzero(usable)
        if len(candidates) < MIN_MATCHES:
            return None
        for keyframe in reversed(self.map.keyframes[-self.tc.relocalize_keyframes :]):
            ids = keyframe.point_ids[keyframe.point_ids >= 0]
            ids = ids[self.map.alive[ids]]
            if len(ids) < MIN_MATCHES:
                continue
            distances = hamming_matrix(features.descriptors[candidates], self.map.descriptors[ids])
            if distances.shape[1] < 2:
                continue
            two = np.partition(distances, 1, axis=1)[:, :2]
            best = np.argmin(distances, axis=1)
            good = (two[:, 0] <= self.tc.match_max_hamming) & (two[:, 0] < RATIO_TEST * two[:, 1])
            kp, pid = candidates[good], ids[best[good]]
            _, unique = np.unique(pid, return_index=True)
            kp, pid = kp[unique], pid[unique]
            if len(kp) < MIN_MATCHES:
                continue
            solved = self._solve(features, kp, pid, None)
            if solved is None:
                continue
            pose_cw, inl = solved
            if inl.sum() >= self.tc.min_inliers:
                return _Tracked(invert(pose_cw), kp[inl], pid[inl], int(inl.sum()))
        return None

    # -- mapping ----------------------------------------------------------------

    def _need_keyframe(self, features: FrameFeatures, usable: np.ndarray, tracked: _Tracked) -> bool:
        """ORB-SLAM's NeedNewKeyFrame for RGB-D with an idle local mapper (mapping here is
        synchronous, so always idle): a keyframe is due when the frame tracks fewer points than
        keyframe_inlier_ratio of its reference keyframe's established points (0.4 while the
        map has one keyframe), or when it tracks few close points and sees many untracked ones."""
        if not self.map.keyframes:
            return True
        n_keyframes = len(self.map.keyframes)
        reference = self.map.keyframe(min(self._reference_keyframe, n_keyframes - 1))
        ids = reference.point_ids[reference.point_ids >= 0]
        ids = ids[self.map.alive[ids]]
        # Established points: ORB-SLAM counts 2 observations per keyframe with depth.
        min_observations = 3 if n_keyframes > 2 else 2
        ref_points = int(np.sum(self.map.observation_weight[ids] >= min_observations))
        close = (features.depth_m > 0) & (features.depth_m < self.close_depth_m) & usable
        tracked_mask = np.zeros(len(features), bool)
        tracked_mask[tracked.keypoints] = True
        need_close = (close & tracked_mask).sum() < 100 and (close & ~tracked_mask).sum() > 70
        ratio = self.tc.keyframe_inlier_ratio if n_keyframes >= 2 else 0.4
        weak = tracked.inliers < ratio * ref_points
        return (weak or need_close) and tracked.inliers > MIN_MATCHES

    def _new_point_mask(
        self, features: FrameFeatures, usable: np.ndarray, point_ids: np.ndarray
    ) -> np.ndarray:
        """Keypoints that become map points at a keyframe (ORB-SLAM's CreateNewKeyFrame): the
        first keyframe takes every keypoint with depth; later ones go through keypoints from
        the closest, counting those already mapped, and stop at the first one farther than
        ThDepth once keyframe_points are counted. Close points (people, often) come first."""
        with_depth = usable & (features.depth_m > 0)
        if not self.map.keyframes:
            return with_depth & (point_ids < 0)
        order = np.flatnonzero(with_depth)
        order = order[np.argsort(features.depth_m[order], kind="stable")]
        stop = (features.depth_m[order] > self.close_depth_m) & (
            np.arange(len(order)) >= self.tc.keyframe_points
        )
        taken = order[: int(np.argmax(stop)) + 1] if stop.any() else order
        new = np.zeros(len(features), bool)
        new[taken] = True
        return new & (point_ids < 0)

    def _insert_keyframe(
        self, features: FrameFeatures, usable: np.ndarray, tracked: _Tracked
    ) -> tuple[np.ndarray, np.ndarray]:
        """Add the frame as a keyframe with its new map points; returns them (keypoints, ids)."""
        kf_id = len(self.map.keyframes)
        point_ids = np.full(len(features), -1)
        point_ids[tracked.keypoints] = tracked.point_ids
        new = self._new_point_mask(features, usable, point_ids)
        uv = features.undistorted_px[new]
        positions = transform(tracked.world_from_camera, backproject(self.camera, uv, features.depth_m[new]))
        point_ids[new] = self.map.add_points(positions, features.descriptors[new], kf_id)
        keyframe = KeyFrame(
            kf_id, self.frame_index, tracked.world_from_camera.copy(), features, usable, point_ids
        )
        self.map.keyframes.append(keyframe)
        for keypoint in np.flatnonzero(point_ids >= 0):
            self.map.observe(int(point_ids[keypoint]), kf_id, int(keypoint))
        self._reference_keyframe = kf_id
        if kf_id > 0:
            self._local_bundle_adjustment()
            self.map.cull(kf_id, self.tc.recent_point_keyframes)
            tracked.world_from_camera = self.map.keyframes[-1].world_from_camera.copy()
        made = np.flatnonzero(new & (point_ids >= 0))
        return made, point_ids[made]

    def _local_bundle_adjustment(self) -> None:
        window = [kf.id for kf in self.map.keyframes[-self.tc.ba_window :]]
        points = np.unique(np.concatenate([self.map.keyframe(k).point_ids for k in window]))
        points = points[(points >= 0)]
        points = points[self.map.alive[points]]
        if len(points) < 10:
            return
        obs_kf, obs_point, obs_kp = [], [], []
        for index, point in enumerate(points):
            for kf_id, keypoint in self.map.observations.get(int(point), {}).items():
                obs_kf.append(kf_id)
                obs_point.append(index)
                obs_kp.append(keypoint)
        obs_kf_arr = np.array(obs_kf)
        involved = np.unique(obs_kf_arr)
        slot = {kf: i for i, kf in enumerate(involved)}
        obs_pose = np.array([slot[k] for k in obs_kf])
        poses = np.array([invert(self.map.keyframe(k).world_from_camera) for k in involved])
        free = np.array([(k in window) and k != 0 for k in involved])
        uv = np.empty((len(obs_kf), 2))
        ur = np.empty(len(obs_kf))
        weight = np.empty(len(obs_kf))
        for kf_id in involved:
            rows = np.flatnonzero(obs_kf_arr == kf_id)
            keypoints = np.array(obs_kp)[rows]
            u, r, w = self._observations(self.map.keyframe(kf_id).features, keypoints)
            uv[rows], ur[rows], weight[rows] = u, r, w
        problem = BundleWindow(
            poses,
            free,
            self.map.positions[points].copy(),
            obs_pose,
            np.array(obs_point),
            uv,
            ur,
            weight,
            self.camera,
            self.bf,
        )
        new_poses, new_points, inlier, _ = bundle_adjust(problem, self.tc.ba_iterations)
        for i, kf_id in enumerate(involved):
            if free[i]:
                self.map.keyframe(kf_id).world_from_camera = invert(new_poses[i])
        self.map.positions[points] = new_points
        for k in np.flatnonzero(~inlier):
            self.map.forget(int(points[obs_point[k]]), obs_kf[k])
