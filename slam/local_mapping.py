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
MAX_FRAMES = 30
"""ORB-SLAM's mMaxFrames, the camera's frame rate (30 on TUM and the bench): a keyframe at least
every 30 frames, none within 30 frames of a relocalisation once the map holds more than 30."""


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
        since_relocalisation: int | None = None,
    ) -> bool:
        """ORB-SLAM3's NeedNewKeyFrame for RGB-D, its local mapper always idle (mapping here is
        synchronous); ``since_relocalisation`` counts frames (None: never relocalised).

        - No keyframe within ``MAX_FRAMES`` (30) frames of a relocalisation once the map holds
          more than 30 keyframes.
        - c1: 30 frames since the last keyframe (c1a), or an idle mapper (c1b), or weak
          tracking (c1c). The mapper is always idle here, so c1 always holds.
        - c2: the frame tracks more than 15 points and fewer than thRefRatio (0.75; 0.4 while
          the map has one keyframe) of the reference keyframe's points seen by at least two
          keyframes with depth (observation weight >= 3; >= 2 while the map has two), or it
          tracks under 100 close points (depth < ThDepth) and sees over 70 close ones untracked.
        A keyframe is due when c1 and c2 hold, so here when c2 does.
        """
        keyframes = map_.keyframes
        if not keyframes:
            return True
        n_keyframes = len(keyframes)
        if since_relocalisation is not None and since_relocalisation < MAX_FRAMES < n_keyframes:
            return False
        ref_points = self.reference_points(map_, reference_keyframe, n_keyframes)
        close = (features.depth_m > 0) & (features.depth_m < self.close_depth_m) & usable
        tracked_mask = np.zeros(len(features), bool)
        tracked_mask[tracked.keypoints] = True
        need_close = (close & tracked_mask).sum() < 100 and (close & ~tracked_mask).sum() > 70
        ratio = self.tc.keyframe_inlier_ratio if n_keyframes >= 2 else 0.4
        return (tracked.inliers < ratio * ref_points or need_close) and tracked.inliers > MIN_MATCHES

    @staticmethod
    def reference_points(map_: Map, reference_keyframe: int, n_keyframes: int) -> int:
        """ORB-SLAM's KeyFrame::TrackedMapPoints(nMinObs): the reference keyframe's points
        whose observation weight is at least 3 (2 while the map has at most two keyframes)."""
        reference = map_.keyframe(reference_keyframe)
        ids = reference.point_ids[reference.point_ids >= 0]
        ids = ids[map_.alive[ids]]
        min_observations = 3 if n_keyframes > 2 else 2
        return int(np.sum(map_.observation_weight[ids] >= min_observations))

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
        kf_id = len(map_.all_keyframes)
        point_ids = np.full(len(features), -1)
        point_ids[tracked.keypoints] = tracked.point_ids
        new = self.new_point_mask(map_, features, usable, point_ids)
        uv = features.undistorted_px[new]
        positions = transform(tracked.world_from_camera, backproject(self.camera, uv, features.depth_m[new]))
        point_ids[new] = map_.add_points(positions, features.descriptors[new], kf_id)
        keyframe = KeyFrame(kf_id, frame_index, tracked.world_from_camera.copy(), features, usable, point_ids)
        map_.add_keyframe(keyframe)
        observed = point_ids.copy()
        keyframe.point_ids = np.full(len(features), -1)
        for keypoint in np.flatnonzero(observed >= 0):
            map_.observe(int(observed[keypoint]), kf_id, int(keypoint))
        if kf_id > 0:
            map_.cull(kf_id, self.tc.recent_point_keyframes)
            if len(map_.keyframes) > 2:
                self.local_bundle_adjustment(map_, kf_id)
            tracked.world_from_camera = keyframe.world_from_camera.copy()
        made = np.flatnonzero(new & (keyframe.point_ids >= 0))
        return made, keyframe.point_ids[made]

    def local_bundle_adjustment(self, map_: Map, keyframe_id: int) -> None:
        """ORB-SLAM3's LocalBundleAdjustment: the keyframe and its covisible keyframes (at least
        15 shared points) move with every point they see; the other keyframes that see those
        points take part held fixed, as does the first keyframe (it fixes the gauge). Without a
        fixed keyframe the adjustment is skipped, as ORB-SLAM3 aborts it. Observations the
        adjustment finds to be outliers (chi-square over 7.815, 5.991 without depth) are
        dropped from the map."""
        local = np.r_[keyframe_id, map_.covisible(keyframe_id)]
        points = np.unique(np.concatenate([map_.keyframe(k).point_ids for k in local]))
        points = points[points >= 0]
        points = points[map_.alive[points]]
        if len(points) < 10:
            return
        obs_point, obs_kf, obs_kp = map_.observation_table(points)
        involved, obs_pose = np.unique(obs_kf, return_inverse=True)
        free = np.isin(involved, local) & (involved != 0)
        if free.all() or not free.any():
            return
        poses = np.array([invert(map_.keyframe(k).world_from_camera) for k in involved])
        uv = np.empty((len(obs_kf), 2))
        ur = np.empty(len(obs_kf))
        weight = np.empty(len(obs_kf))
        for slot, kf_id in enumerate(involved):
            rows = np.flatnonzero(obs_pose == slot)
            uv[rows], ur[rows], weight[rows] = observations(
                self.tc, map_.keyframe(kf_id).features, obs_kp[rows]
            )
        problem = BundleWindow(
            poses,
            free,
            map_.positions[points].copy(),
            obs_pose,
            obs_point,
            uv,
            ur,
            weight,
            self.camera,
            self.tc.baseline_fx,
        )
        new_poses, new_points, inlier, _ = bundle_adjust(problem, self.tc.ba_iterations)
        for slot in np.flatnonzero(free):
            map_.keyframe(int(involved[slot])).world_from_camera = invert(new_poses[slot])
        map_.positions[points] = new_points
        for k in np.flatnonzero(~inlier):
            map_.forget(int(points[obs_point[k]]), int(obs_kf[k]))
