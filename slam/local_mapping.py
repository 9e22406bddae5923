"""Local mapping as ORB-SLAM3 builds it: when a frame becomes a keyframe and what it adds.

Holds ORB-SLAM3's NeedNewKeyFrame (RGB-D, with an always idle mapper), CreateNewKeyFrame's
new map points from depth, and its local mapper's steps in their order: ProcessNewKeyFrame
(normals, distance ranges and descriptors of the keyframe's points), MapPointCulling (in
``Map.cull``), CreateNewMapPoints (points triangulated with the 10 best covisible
keyframes), SearchInNeighbors (fusion with their points), the local bundle adjustment over
the covisibility window (the new keyframe and those sharing at least 15 points with it; the
keyframes that see their points held fixed) and KeyFrameCulling (90 % redundant close points).
Mapping runs inside ``Slam.process``, so runs are deterministic: by default each keyframe is
mapped to its end before the next frame (``map_keyframe``: the mapper is always idle), or
ORB-SLAM3's thread is modelled on a virtual clock (``depotbench.slam.mapping_clock``:
fusion, bundle adjustment and culling skipped while keyframes queue, the adjustment
interrupted). The methods take the map as an argument and keep no state of their own, so a
forked system shares them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam.bundle import BundleWindow, LevenbergMarquardt
from depotbench.slam.config import TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.geometry import backproject, invert, transform
from depotbench.slam.map import KeyFrame, Map
from depotbench.slam.matcher import fuse_candidates, search_for_triangulation
from depotbench.slam.pose import MIN_MATCHES, Tracked, observations

CLOSE_DEPTH_FACTOR = 40.0
"""ORB-SLAM's ThDepth: points closer than 40 baselines are 'close'."""
NEIGHBOURS_TRIANGULATION = 10
"""CreateNewMapPoints pairs a keyframe with its 10 best covisible keyframes (RGB-D)."""
REDUNDANT_SHARE = 0.9
"""KeyFrameCulling: a keyframe goes when over 90 % of its close points are seen elsewhere."""
REDUNDANT_OBSERVERS = 3
"""... by more than 3 other keyframes (ORB-SLAM3: nObs > thObs = 3; ORB-SLAM2 took 3 or more)."""
MAX_CULLING_CHECKS = 100
"""KeyFrameCulling looks at most at the first 100 covisible keyframes."""
MAX_FRAMES = 30
"""ORB-SLAM's mMaxFrames, the camera's frame rate (30 on TUM and the bench): a keyframe at least
every 30 frames, none within 30 frames of a relocalisation once the map holds more than 30."""


@dataclass(frozen=True, eq=False)
class LocalWindow:
    """A local bundle adjustment's problem and the map entries its rows stand for: window
    point k is map point ``points[k]``, pose slot j keyframe ``involved[j]``; observation i
    is of ``points[obs_point[i]]`` by keyframe ``obs_kf[i]``."""

    problem: BundleWindow
    points: np.ndarray
    involved: np.ndarray
    obs_point: np.ndarray
    obs_kf: np.ndarray


class LocalMapping:
    def __init__(self, tc: TrackingConfig, camera: Intrinsics) -> None:
        self.tc = tc
        self.camera = camera
        self.close_depth_m = CLOSE_DEPTH_FACTOR * tc.baseline_fx / camera.fx
        self.baseline_m = tc.baseline_fx / camera.fx

    def need_keyframe(
        self,
        map_: Map,
        features: FrameFeatures,
        usable: np.ndarray,
        tracked: Tracked,
        reference_keyframe: int,
        since_relocalisation: int | None = None,
        mapper_idle: bool = True,
        since_keyframe: int = 0,
    ) -> bool:
        """ORB-SLAM3's NeedNewKeyFrame for RGB-D up to its mapper's answer: whether the frame
        is wanted as a keyframe (a busy mapper then takes it only while fewer than three
        wait, ``depotbench.slam.mapping_clock``). ``since_relocalisation`` and
        ``since_keyframe`` count frames (None: never relocalised).

        - No keyframe within ``MAX_FRAMES`` (30) frames of a relocalisation once the map holds
          more than 30 keyframes.
        - c1: ``MAX_FRAMES`` frames since the last keyframe (c1a), or an idle mapper (c1b), or
          weak tracking (c1c: fewer than a quarter of the reference keyframe's points tracked,
          or the close-point rule below). A mapper that takes no time is always idle.
        - c2: the frame tracks more than 15 points and fewer than thRefRatio (0.75; 0.4 while
          the map has one keyframe) of the reference keyframe's points seen by at least two
          keyframes with depth (observation weight >= 3; >= 2 while the map has two), or it
          tracks under 100 close points (depth < ThDepth) and sees over 70 close ones untracked.
        A keyframe is wanted when c1 and c2 hold.
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
        weak = tracked.inliers < 0.25 * ref_points or need_close
        c1 = since_keyframe >= MAX_FRAMES or mapper_idle or weak
        return c1 and (tracked.inliers < ratio * ref_points or need_close) and tracked.inliers > MIN_MATCHES

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
        self,
        map_: Map,
        features: FrameFeatures,
        usable: np.ndarray,
        tracked: Tracked,
        frame_index: int,
        outliers: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Add the frame as a keyframe with its new map points from depth (ORB-SLAM's
        CreateNewKeyFrame and ProcessNewKeyFrame: the points' observations, normals, distances
        and descriptors, the keyframe's parent); the local mapper's steps come after it
        (``map_keyframe``, or ``depotbench.slam.mapping_clock`` in virtual time). Returns
        the keypoints whose points it made from depth.

        ``outliers`` (keypoints, point ids): matches the frame's pose optimisation set aside.
        ORB-SLAM keeps them in the keyframe ("so that bundle adjustment will finally decide
        if they are outliers or not") while the next frame does without them."""
        kf_id = len(map_.all_keyframes)
        point_ids = np.full(len(features), -1)
        if outliers is not None:
            point_ids[outliers[0]] = outliers[1]
        point_ids[tracked.keypoints] = tracked.point_ids
        new = self.new_point_mask(map_, features, usable, point_ids)
        uv = features.undistorted_px[new]
        positions = transform(tracked.world_from_camera, backproject(self.camera, uv, features.depth_m[new]))
        point_ids[new] = map_.add_points(positions, features.descriptors[new], kf_id)
        keyframe = KeyFrame(kf_id, frame_index, tracked.world_from_camera.copy(), features, usable, point_ids)
        map_.add_keyframe(keyframe)
        observed = point_ids.copy()
        keyframe.point_ids = np.full(len(features), -1)
        with_point = np.flatnonzero(observed >= 0)
        map_.observe_many(observed[with_point], kf_id, with_point)
        self._update_points(map_, keyframe.point_ids)
        if kf_id > 0:
            best = map_.covisible(kf_id, 1)
            keyframe.parent = int(best[0]) if len(best) else kf_id - 1
        return new

    def map_keyframe(self, map_: Map, keyframe_id: int) -> None:
        """The local mapper's steps on a keyframe, each run to its end (an idle mapper that
        takes no time): MapPointCulling, CreateNewMapPoints, SearchInNeighbors, the local
        bundle adjustment (from three keyframes) and KeyFrameCulling."""
        map_.cull(keyframe_id, self.tc.recent_point_keyframes)
        self.create_new_map_points(map_, keyframe_id)
        self.search_in_neighbors(map_, keyframe_id)
        if len(map_.keyframes) > 2:
            self.local_bundle_adjustment(map_, keyframe_id)
        self.keyframe_culling(map_, keyframe_id)

    def _update_points(self, map_: Map, point_ids: np.ndarray, descriptors: bool = True) -> None:
        map_.update_points(point_ids, self.tc.scale_factor, self.tc.n_levels, descriptors)

    def create_new_map_points(self, map_: Map, keyframe_id: int) -> int:
        """ORB-SLAM's CreateNewMapPoints: with each of its ``NEIGHBOURS_TRIANGULATION`` (10)
        best covisible keyframes whose centre lies at least the stereo baseline (bf / fx)
        away, pair the keyframe's keypoints that have no point (``search_for_triangulation``)
        and make a point of each pair that ``triangulate`` accepts; returns how many."""
        keyframe = map_.keyframe(keyframe_id)
        pose1 = invert(keyframe.world_from_camera)
        made = 0
        for other_id in map_.covisible(keyframe_id, NEIGHBOURS_TRIANGULATION):
            other = map_.keyframe(int(other_id))
            if np.linalg.norm(other.center - keyframe.center) < self.baseline_m:
                continue
            pose2 = invert(other.world_from_camera)
            i1, i2 = search_for_triangulation(
                self.tc,
                self.camera,
                keyframe.features,
                keyframe.usable & (keyframe.point_ids < 0),
                pose1,
                other.features,
                other.usable & (other.point_ids < 0),
                pose2,
            )
            if not len(i1):
                continue
            points, ok = self.triangulate(keyframe.features, i1, pose1, other.features, i2, pose2)
            i1, i2 = i1[ok], i2[ok]
            ids = map_.add_points(points[ok], keyframe.features.descriptors[i1], keyframe_id)
            map_.observe_many(ids, keyframe_id, i1)
            map_.observe_many(ids, int(other_id), i2)
            self._update_points(map_, ids)
            made += len(ids)
        return made

    def triangulate(
        self,
        features1: FrameFeatures,
        i1: np.ndarray,
        pose1_cw: np.ndarray,
        features2: FrameFeatures,
        i2: np.ndarray,
        pose2_cw: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """ORB-SLAM's CreateNewMapPoints for matched keypoints: (world points, accepted).

        Where the rays' parallax exceeds the depth's own (2 atan(b / 2 / depth) of the first
        keypoint with depth; any parallax over 0.02 degrees without depth) the point is
        triangulated linearly (DLT, SVD); otherwise it is back-projected from the keypoint
        with the larger stereo parallax. A point is kept when it lies in front of both
        cameras, reprojects within chi-square 7.8 (with depth, on u, v, u_r) or 5.991 (u, v)
        sigma^2 in both, and its distances to the two centres agree with the keypoints'
        levels within 1.5 x scale_factor."""
        tc, camera = self.tc, self.camera
        k_inv = np.linalg.inv(camera.matrix)
        xn1 = np.c_[features1.undistorted_px[i1], np.ones(len(i1))] @ k_inv.T
        xn2 = np.c_[features2.undistorted_px[i2], np.ones(len(i2))] @ k_inv.T
        ray1 = xn1 @ pose1_cw[:3, :3]  # R_wc @ xn, row-wise
        ray2 = xn2 @ pose2_cw[:3, :3]
        cos_rays = np.einsum("ij,ij->i", ray1, ray2) / (
            np.linalg.norm(ray1, axis=1) * np.linalg.norm(ray2, axis=1)
        )
        depth1, depth2 = features1.depth_m[i1], features2.depth_m[i2]
        stereo1, stereo2 = depth1 > 0, depth2 > 0
        half = self.baseline_m / 2
        cos_stereo1 = np.where(
            stereo1, np.cos(2 * np.arctan2(half, np.where(stereo1, depth1, 1.0))), cos_rays + 1
        )
        from2 = ~stereo1 & stereo2  # ORB-SLAM computes the second keypoint's only without the first's
        cos_stereo2 = np.where(
            from2, np.cos(2 * np.arctan2(half, np.where(stereo2, depth2, 1.0))), cos_rays + 1
        )
        cos_stereo = np.minimum(cos_stereo1, cos_stereo2)
        linear = (cos_rays < cos_stereo) & (cos_rays > 0) & (stereo1 | stereo2 | (cos_rays < 0.9998))
        use1 = ~linear & stereo1 & (cos_stereo1 < cos_stereo2)
        use2 = ~linear & ~use1 & stereo2 & (cos_stereo2 < cos_stereo1)
        points = np.zeros((len(i1), 3))
        ok = linear | use1 | use2
        if linear.any():
            a = np.stack(
                [
                    xn1[linear, 0, None] * pose1_cw[2] - pose1_cw[0],
                    xn1[linear, 1, None] * pose1_cw[2] - pose1_cw[1],
                    xn2[linear, 0, None] * pose2_cw[2] - pose2_cw[0],
                    xn2[linear, 1, None] * pose2_cw[2] - pose2_cw[1],
                ],
                axis=1,
            )
            homogeneous = np.linalg.svd(a)[2][:, 3]
            w = homogeneous[:, 3]
            ok[np.flatnonzero(linear)[w == 0]] = False
            points[linear] = homogeneous[:, :3] / np.where(w == 0, 1.0, w)[:, None]
        for use, features, index, pose in ((use1, features1, i1, pose1_cw), (use2, features2, i2, pose2_cw)):
            if use.any():
                pc = backproject(camera, features.undistorted_px[index[use]], features.depth_m[index[use]])
                points[use] = transform(invert(pose), pc)
        for features, index, pose, stereo in (
            (features1, i1, pose1_cw, stereo1),
            (features2, i2, pose2_cw, stereo2),
        ):
            pc = transform(pose, points)
            z = pc[:, 2]
            ok &= z > 0
            safe = np.where(z > 0, z, 1.0)
            u = camera.fx * pc[:, 0] / safe + camera.cx
            v = camera.fy * pc[:, 1] / safe + camera.cy
            kp = features.undistorted_px[index]
            e2 = (u - kp[:, 0]) ** 2 + (v - kp[:, 1]) ** 2
            ur = features.right_px(tc.baseline_fx)[index]
            e2 = e2 + np.where(stereo, (u - tc.baseline_fx / safe - ur) ** 2, 0.0)
            sigma2 = tc.scale_factor ** (2.0 * features.octaves[index])
            ok &= e2 <= np.where(stereo, 7.8, 5.991) * sigma2
        center1 = invert(pose1_cw)[:3, 3]
        center2 = invert(pose2_cw)[:3, 3]
        dist1 = np.linalg.norm(points - center1, axis=1)
        dist2 = np.linalg.norm(points - center2, axis=1)
        ok &= (dist1 > 0) & (dist2 > 0)
        ratio_dist = dist2 / np.where(dist1 > 0, dist1, 1.0)
        ratio_octave = tc.scale_factor ** (features1.octaves[i1] - features2.octaves[i2]).astype(float)
        factor = 1.5 * tc.scale_factor
        ok &= (ratio_dist * factor >= ratio_octave) & (ratio_dist <= ratio_octave * factor)
        return points, ok

    @staticmethod
    def fusion_targets(map_: Map, keyframe_id: int) -> list[int]:
        """SearchInNeighbors' targets: the keyframe's 10 best covisible keyframes, then the
        20 best of each, each once, the keyframe itself left out."""
        targets: list[int] = []
        for first in map_.covisible(keyframe_id, 10):
            if int(first) not in targets:
                targets.append(int(first))
        for first in list(targets):
            for second in map_.covisible(first, 20):
                if int(second) != keyframe_id and int(second) not in targets:
                    targets.append(int(second))
        return targets

    def search_in_neighbors(self, map_: Map, keyframe_id: int) -> int:
        """ORB-SLAM's SearchInNeighbors: the targets are the keyframe's 10 best covisible
        keyframes and their 20 best each; its points are fused into every target, then the
        targets' points into it (``fuse_candidates``; a keypoint that already has a point
        keeps whichever of the two more keyframes see, the other is merged into it), and the
        keyframe's points get their normals, distances and descriptors again. Returns the
        number of fusions."""
        targets = self.fusion_targets(map_, keyframe_id)
        keyframe = map_.keyframe(keyframe_id)
        fused = 0
        for target in targets:
            ids = map_.resolve(keyframe.point_ids[keyframe.point_ids >= 0])
            fused += self._fuse(map_, target, ids)
        candidates = [map_.keyframe(t).point_ids for t in targets]
        if candidates:
            ids = np.unique(np.concatenate(candidates))
            fused += self._fuse(map_, keyframe_id, ids[ids >= 0])
        self._update_points(map_, keyframe.point_ids)
        return fused

    def _fuse(self, map_: Map, keyframe_id: int, point_ids: np.ndarray) -> int:
        """Fuse ``point_ids`` into keyframe ``keyframe_id`` (ORB-SLAM's Fuse), one match at a time."""
        keyframe = map_.keyframe(keyframe_id)
        point_ids = np.unique(point_ids[point_ids >= 0])
        point_ids = point_ids[map_.alive[point_ids]]
        point_ids = point_ids[~np.isin(point_ids, keyframe.point_ids)]  # those it sees already
        if not len(point_ids):
            return 0
        ids, kps = fuse_candidates(
            self.tc,
            self.camera,
            map_,
            point_ids,
            invert(keyframe.world_from_camera),
            keyframe.features,
            keyframe.usable,
        )
        fused = 0
        for point, keypoint in zip(ids.tolist(), kps.tolist(), strict=True):
            point = map_.resolve_one(point)
            if not map_.alive[point] or keyframe_id in map_.observations.get(point, {}):
                continue
            there = int(keyframe.point_ids[keypoint])
            if there >= 0 and map_.alive[there]:
                if map_.observation_weight[there] > map_.observation_weight[point]:
                    map_.replace_point(point, there)
                else:
                    map_.replace_point(there, point)
            else:
                map_.observe(point, keyframe_id, int(keypoint))
            fused += 1
        return fused

    def keyframe_culling(self, map_: Map, keyframe_id: int) -> int:
        """ORB-SLAM3's KeyFrameCulling: a covisible keyframe (not the first) is culled when more
        than 90 % of its points with close depth (0 < depth <= ThDepth) are seen by more than
        three other keyframes (weight > 3) at the same, a finer or the next coarser level.
        Returns how many were culled."""
        culled = 0
        for candidate in map_.covisible(keyframe_id)[:MAX_CULLING_CHECKS]:
            candidate = int(candidate)
            if candidate == 0 or map_.keyframe(candidate).bad:
                continue
            kf = map_.keyframe(candidate)
            depth = kf.features.depth_m
            keypoints = np.flatnonzero((kf.point_ids >= 0) & (depth > 0) & (depth <= self.close_depth_m))
            keypoints = keypoints[map_.alive[kf.point_ids[keypoints]]]
            if not len(keypoints):
                continue
            points = kf.point_ids[keypoints]
            heavy = map_.observation_weight[points] > 3
            index, kfs, kps = map_.observation_table(points[heavy])
            others = kfs != candidate
            levels = map_.keypoint_values("octaves", kfs[others], kps[others])
            own = kf.features.octaves[keypoints[heavy]][index[others]]
            counts = np.bincount(index[others][levels <= own + 1], minlength=int(heavy.sum()))
            redundant = int(np.sum(counts > REDUNDANT_OBSERVERS))
            if redundant > REDUNDANT_SHARE * len(keypoints):
                map_.set_bad(candidate)
                culled += 1
        return culled

    def local_bundle_adjustment(self, map_: Map, keyframe_id: int) -> None:
        """ORB-SLAM3's LocalBundleAdjustment: the keyframe and its covisible keyframes (at least
        15 shared points) move with every point they see; the other keyframes that see those
        points take part held fixed, as does the first keyframe (it fixes the gauge). Without a
        fixed keyframe the adjustment is skipped, as ORB-SLAM3 aborts it. Observations the
        adjustment finds to be outliers (chi-square over 7.815, 5.991 without depth) are
        dropped from the map, and with them a point left seen by at most one keyframe with
        depth (MapPoint::EraseObservation)."""
        window = self.local_window(map_, keyframe_id)
        if window is None:
            return
        self.apply_adjustment(map_, window, LevenbergMarquardt(window.problem).run(self.tc.ba_iterations))

    def local_window(self, map_: Map, keyframe_id: int) -> LocalWindow | None:
        """The local bundle adjustment's problem around a keyframe (None where ORB-SLAM3 skips
        it: under 10 points, or no keyframe to hold fixed)."""
        local = np.r_[keyframe_id, map_.covisible(keyframe_id)]
        points = np.unique(np.concatenate([map_.keyframe(k).point_ids for k in local]))
        points = points[points >= 0]
        points = points[map_.alive[points]]
        if len(points) < 10:
            return None
        obs_point, obs_kf, obs_kp = map_.observation_table(points)
        involved, obs_pose = np.unique(obs_kf, return_inverse=True)
        free = np.isin(involved, local) & (involved != 0)
        if free.all() or not free.any():
            return None
        poses = np.array([invert(map_.keyframe(k).world_from_camera) for k in involved])
        uv = np.empty((len(obs_kf), 2))
        ur = np.empty(len(obs_kf))
        weight = np.empty(len(obs_kf))
        # Each keyframe's observations, in row order, by one stable sort: a mask per keyframe
        # walked every observation once per keyframe (150 x 60,000 at TUM's length).
        by_slot = np.argsort(obs_pose, kind="stable")
        ends = np.cumsum(np.bincount(obs_pose, minlength=len(involved)))
        for slot, kf_id in enumerate(involved):
            rows = by_slot[(ends[slot - 1] if slot else 0) : ends[slot]]
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
        return LocalWindow(problem, points, involved, obs_point, obs_kf)

    def apply_adjustment(self, map_: Map, window: LocalWindow, solver: LevenbergMarquardt) -> None:
        """Write an adjustment's poses and points into the map and drop the observations it
        finds to be outliers (ORB-SLAM does so after an interrupted adjustment too)."""
        new_poses, new_points, inlier, _ = solver.result()
        points, obs_point, obs_kf = window.points, window.obs_point, window.obs_kf
        for slot in np.flatnonzero(window.problem.free):
            map_.keyframe(int(window.involved[slot])).world_from_camera = invert(new_poses[slot])
        map_.positions[points] = new_points
        for k in np.flatnonzero(~inlier):
            map_.erase_observation(int(points[obs_point[k]]), int(obs_kf[k]))
        self._update_points(map_, points, descriptors=False)
