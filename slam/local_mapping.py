"""Local mapping: when a frame becomes a keyframe, the points it adds, culling, local BA.

Holds ORB-SLAM's NeedNewKeyFrame (RGB-D, with an always idle mapper), CreateNewKeyFrame's
new map points from depth, MapPointCulling (in ``Map.cull``) and the local bundle adjustment
over the last ``ba_window`` (5) keyframes, the keyframes that see their points held fixed.
Mapping runs synchronously inside ``Slam.process``, so runs are deterministic; the methods
take the map as an argument and keep no state of their own, so a forked system shares them.
"""

from __future__ import annotations

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam.bundle import BundleWindow, bundle_adjust
from depotbench.slam.config import TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.geometry import backproject, invert, transform
from depotbench.slam.map import KeyFrame, Map
from depotbench.slam.pose import MIN_MATCHES, Tracked, observations

CLOSE_DEPTH_FACTOR = 40.0
"""ORB-SLAM's ThDepth: points closer than 40 baselines are 'close'."""


class LocalMapping:
    def __init__(self, tc: TrackingConfig, camera: Intrinsics) -> None:
        self.tc = tc
        self.camera = camera
        self.close_depth_m = CLOSE_DEPTH_FACTOR * tc.baseline_fx / camera.fx

    def need_keyframe(
        self,
        map_: Map,
        features: FrameFeatures,
        usable: np.ndarray,
        tracked: Tracked,
        reference_keyframe: int,
    ) -> bool:
        """ORB-SLAM's NeedNewKeyFrame for RGB-D with an idle local mapper (mapping here is
        synchronous, so always idle): a keyframe is due when the frame tracks fewer points than
        keyframe_inlier_ratio of its reference keyframe's established points (0.4 while the
        map has one keyframe), or when it tracks few close points and sees many untracked ones."""
        if not map_.keyframes:
            return True
        n_keyframes = len(map_.keyframes)
        reference = map_.keyframe(min(reference_keyframe, n_keyframes - 1))
        ids = reference.point_ids[reference.point_ids >= 0]
        ids = ids[map_.alive[ids]]
        # Established points: ORB-SLAM counts 2 observations per keyframe with depth.
        min_observations = 3 if n_keyframes > 2 else 2
        ref_points = int(np.sum(map_.observation_weight[ids] >= min_observations))
        close = (features.depth_m > 0) & (features.depth_m < self.close_depth_m) & usable
        tracked_mask = np.zeros(len(features), bool)
        tracked_mask[tracked.keypoints] = True
        need_close = (close & tracked_mask).sum() < 100 and (close & ~tracked_mask).sum() > 70
        ratio = self.tc.keyframe_inlier_ratio if n_keyframes >= 2 else 0.4
        weak = tracked.inliers < ratio * ref_points
        return (weak or need_close) and tracked.inliers > MIN_MATCHES

    def new_point_mask(
        self, map_: Map, features: FrameFeatures, usable: np.ndarray, point_ids: np.ndarray
    ) -> np.ndarray:
        """Keypoints that become map points at a keyframe (ORB-SLAM's CreateNewKeyFrame): the
        first keyframe takes every keypoint with depth; later ones go through keypoints from
        the closest, counting those already mapped, and stop at the first one farther than
        ThDepth once keyframe_points are counted. Close points (people, often) come first."""
        with_depth = usable & (features.depth_m > 0)
        if not map_.keyframes:
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

    def insert_keyframe(
        self, map_: Map, features: FrameFeatures, usable: np.ndarray, tracked: Tracked, frame_index: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Add the frame as a keyframe with its new map points, then (after the first) adjust
        the local window, cull recent points and move ``tracked`` to the adjusted pose;
        returns the new points (keypoints, ids)."""
        kf_id = len(map_.keyframes)
        point_ids = np.full(len(features), -1)
        point_ids[tracked.keypoints] = tracked.point_ids
        new = self.new_point_mask(map_, features, usable, point_ids)
        uv = features.undistorted_px[new]
        positions = transform(tracked.world_from_camera, backproject(self.camera, uv, features.depth_m[new]))
        point_ids[new] = map_.add_points(positions, features.descriptors[new], kf_id)
        keyframe = KeyFrame(kf_id, frame_index, tracked.world_from_camera.copy(), features, usable, point_ids)
        map_.keyframes.append(keyframe)
        for keypoint in np.flatnonzero(point_ids >= 0):
            map_.observe(int(point_ids[keypoint]), kf_id, int(keypoint))
        if kf_id > 0:
            self.local_bundle_adjustment(map_)
            map_.cull(kf_id, self.tc.recent_point_keyframes)
            tracked.world_from_camera = map_.keyframes[-1].world_from_camera.copy()
        made = np.flatnonzero(new & (point_ids >= 0))
        return made, point_ids[made]

    def local_bundle_adjustment(self, map_: Map) -> None:
        """Adjust the last ``ba_window`` keyframes (not the first: it fixes the gauge) and their
        points; keyframes outside the window that see those points take part, held fixed.
        Observations the adjustment finds to be outliers are dropped from the map."""
        window = [kf.id for kf in map_.keyframes[-self.tc.ba_window :]]
        points = np.unique(np.concatenate([map_.keyframe(k).point_ids for k in window]))
        points = points[(points >= 0)]
        points = points[map_.alive[points]]
        if len(points) < 10:
            return
        obs_kf, obs_point, obs_kp = [], [], []
        for index, point in enumerate(points):
            for kf_id, keypoint in map_.observations.get(int(point), {}).items():
                obs_kf.append(kf_id)
                obs_point.append(index)
                obs_kp.append(keypoint)
        obs_kf_arr = np.array(obs_kf)
        involved = np.unique(obs_kf_arr)
        slot = {kf: i for i, kf in enumerate(involved)}
        obs_pose = np.array([slot[k] for k in obs_kf])
        poses = np.array([invert(map_.keyframe(k).world_from_camera) for k in involved])
        free = np.array([(k in window) and k != 0 for k in involved])
        uv = np.empty((len(obs_kf), 2))
        ur = np.empty(len(obs_kf))
        weight = np.empty(len(obs_kf))
        for kf_id in involved:
            rows = np.flatnonzero(obs_kf_arr == kf_id)
            keypoints = np.array(obs_kp)[rows]
            u, r, w = observations(self.tc, map_.keyframe(kf_id).features, keypoints)
            uv[rows], ur[rows], weight[rows] = u, r, w
        problem = BundleWindow(
            poses,
            free,
            map_.positions[points].copy(),
            obs_pose,
            np.array(obs_point),
            uv,
            ur,
            weight,
            self.camera,
            self.tc.baseline_fx,
        )
        new_poses, new_points, inlier, _ = bundle_adjust(problem, self.tc.ba_iterations)
        for i, kf_id in enumerate(involved):
            if free[i]:
                map_.keyframe(kf_id).world_from_camera = invert(new_poses[i])
        map_.positions[points] = new_points
        for k in np.flatnonzero(~inlier):
            map_.forget(int(points[obs_point[k]]), obs_kf[k])
