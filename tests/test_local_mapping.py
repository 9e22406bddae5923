"""Local mapping as ORB-SLAM builds it (issue 40), each rule against something independent.

- The keyframe decision against ORB-SLAM3's NeedNewKeyFrame written out on plain counts.
- The covisibility weights against shared points counted from index sets; the covisibility
  bundle adjustment against ``bundle_adjust`` on a window built by hand where the two coincide,
  and a weakly connected keyframe held fixed where they do not.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from depotbench.core.camera import Intrinsics
from depotbench.slam.bundle import BundleWindow, bundle_adjust
from depotbench.slam.config import TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.geometry import invert
from depotbench.slam.local_mapping import CLOSE_DEPTH_FACTOR, LocalMapping
from depotbench.slam.map import KeyFrame, Map
from depotbench.slam.pose import Tracked, observations

CAMERA = Intrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
TC = TrackingConfig()
THDEPTH = CLOSE_DEPTH_FACTOR * TC.baseline_fx / CAMERA.fx


def features(depths: np.ndarray, seed: int = 0) -> FrameFeatures:
    """Keypoints on a grid with the given depths, random descriptors, level 0."""
    rng = np.random.default_rng(seed)
    n = len(depths)
    px = np.c_[np.arange(n) % 600 + 20.0, np.arange(n) // 600 * 10 + 20.0].astype(np.float32)
    return FrameFeatures(
        np.zeros((0, 0), np.uint8),
        px,
        px.astype(np.float64),
        np.zeros(n, int),
        rng.integers(0, 256, (n, 32), dtype=np.uint8),
        np.asarray(depths, float),
        np.zeros(n),
    )


# -- the keyframe decision ----------------------------------------------------------------


def orb_need_new_keyframe(
    n_kfs: int, ref_matches: int, inliers: int, tracked_close: int, untracked_close: int, since_reloc: int
) -> bool:
    """Tracking::NeedNewKeyFrame of ORB-SLAM3 for RGB-D (not inertial), local mapper idle,
    written out on its counts."""
    if since_reloc < 30 and n_kfs > 30:
        return False
    need_close = tracked_close < 100 and untracked_close > 70
    th_ref_ratio = 0.4 if n_kfs < 2 else 0.75
    c1b = True  # mCurrentFrame.mnId >= mnLastKeyFrameId + mMinFrames (0) and the mapper idle
    c2 = (inliers < ref_matches * th_ref_ratio or need_close) and inliers > 15
    return c1b and c2


def _decision_case(
    n_kfs: int, ref_weights: list[int], tracked_close: int, untracked_close: int, tracked_far: int
) -> tuple[Map, FrameFeatures, Tracked, int]:
    """A map of ``n_kfs`` keyframes whose last (the reference) sees points of the given
    observation weights, and a frame with that many close/far tracked keypoints."""
    map_ = Map()
    ref_features = features(np.full(len(ref_weights), 2.0))
    ids = map_.add_points(np.zeros((len(ref_weights), 3)), ref_features.descriptors, 0)
    map_.observation_weight[ids] = ref_weights
    for k in range(n_kfs):
        point_ids = ids.copy() if k == n_kfs - 1 else np.full(len(ref_weights), -1)
        map_.add_keyframe(KeyFrame(k, k, np.eye(4), ref_features, np.ones(len(ref_weights), bool), point_ids))
    depths = np.r_[
        np.full(tracked_close, 1.0), np.full(untracked_close, 1.5), np.full(tracked_far, THDEPTH + 1.0), 9.0
    ]
    frame = features(depths, 1)
    tracked_kp = np.r_[np.arange(tracked_close), tracked_close + untracked_close + np.arange(tracked_far)]
    tracked = Tracked(np.eye(4), tracked_kp, np.zeros(len(tracked_kp), int), len(tracked_kp))
    return map_, frame, tracked, n_kfs - 1


@pytest.mark.parametrize("n_kfs", [1, 2, 3, 31])
def test_keyframe_decision_is_orb_slam3s_rule_on_counts(n_kfs: int):
    """Over a grid of counts around each threshold (0.4 / 0.75 of the reference's points, 100
    tracked close, 70 untracked close, 15 inliers, 30 frames after relocalisation) the
    decision on the constructed map equals the rule written out on the counts."""
    mapping = LocalMapping(TC, CAMERA)
    checked = 0
    for ref_count, tracked_close, untracked_close, tracked_far, since in itertools.product(
        (40, 200, 400), (0, 10, 99, 100), (0, 70, 71), (0, 5, 140, 299, 301), (5, 29, 30, None)
    ):
        weights = [2] * 37 + [3] * (ref_count // 2) + [6] * (ref_count - ref_count // 2)
        map_, frame, tracked, reference = _decision_case(
            n_kfs, weights, tracked_close, untracked_close, tracked_far
        )
        min_weight = 3 if n_kfs > 2 else 2
        ref_matches = sum(w >= min_weight for w in weights)
        expected = orb_need_new_keyframe(
            n_kfs,
            ref_matches,
            tracked.inliers,
            tracked_close,
            untracked_close,
            10**6 if since is None else since,
        )
        got = mapping.need_keyframe(map_, frame, np.ones(len(frame), bool), tracked, reference, since)
        assert got == expected, (n_kfs, ref_count, tracked_close, untracked_close, tracked_far, since)
        checked += 1
    assert checked == 3 * 4 * 3 * 5 * 4


def test_keyframe_decision_counts_only_usable_close_keypoints():
    """A close keypoint the rejection removed is neither tracked nor a candidate: 80 untracked
    close keypoints of which 20 are rejected leave 60 (<= 70), so no keyframe is due."""
    mapping = LocalMapping(TC, CAMERA)
    map_, frame, tracked, reference = _decision_case(3, [3] * 50, 50, 80, 0)
    usable = np.ones(len(frame), bool)
    assert mapping.need_keyframe(map_, frame, usable, tracked, reference)
    usable[50:70] = False
    assert not mapping.need_keyframe(map_, frame, usable, tracked, reference)


# -- a synthetic map: points on a wall seen by keyframes moving sideways --------------------


def _pose(x: float, yaw: float = 0.0) -> np.ndarray:
    """world_from_camera of a camera at (x, 0, 0) turned by ``yaw`` about y."""
    c, s = np.cos(yaw), np.sin(yaw)
    pose = np.eye(4)
    pose[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    pose[0, 3] = x
    return pose


def synthetic_map(
    centers: list[float], visible: list[np.ndarray], n_points: int = 120, seed: int = 0
) -> tuple[Map, np.ndarray, list[np.ndarray]]:
    """A map whose keyframe k (camera at x = centers[k]) observes the points ``visible[k]``
    (indices) with exact pixels and depths; returns the map, the true points and poses."""
    rng = np.random.default_rng(seed)
    points = np.c_[
        rng.uniform(-1.5, 1.5, n_points), rng.uniform(-1.0, 1.0, n_points), rng.uniform(3, 5, n_points)
    ]
    map_ = Map()
    map_.add_points(points.copy(), rng.integers(0, 256, (n_points, 32), dtype=np.uint8), 0)
    poses = []
    for k, (x, seen) in enumerate(zip(centers, visible, strict=True)):
        pose = _pose(x, 0.02 * k)
        poses.append(pose)
        pc = (points[seen] - pose[:3, 3]) @ pose[:3, :3]
        uv = np.c_[CAMERA.fx * pc[:, 0] / pc[:, 2] + CAMERA.cx, CAMERA.fy * pc[:, 1] / pc[:, 2] + CAMERA.cy]
        frame = FrameFeatures(
            np.zeros((0, 0), np.uint8),
            uv.astype(np.float32),
            uv,
            np.zeros(len(seen), int),
            map_.descriptors[seen],
            pc[:, 2],
            np.zeros(len(seen)),
        )
        map_.add_keyframe(
            KeyFrame(k, k, pose.copy(), frame, np.ones(len(seen), bool), np.full(len(seen), -1))
        )
        for keypoint, point in enumerate(seen):
            map_.observe(int(point), k, keypoint)
    return map_, points, poses


def test_covisibility_counts_shared_points_and_follows_observations():
    """covisibility[i, j] is the number of points both see, counted by hand from the index
    sets; it follows forgotten observations and culled points."""
    visible = [np.arange(0, 60), np.arange(20, 80), np.arange(50, 110), np.arange(100, 120)]
    map_, _, _ = synthetic_map([0.0, 0.2, 0.4, 0.6], visible)
    for i, j in itertools.permutations(range(4), 2):
        assert map_.covisibility[i, j] == len(np.intersect1d(visible[i], visible[j])), (i, j)
    assert list(map_.covisible(1)) == [0, 2]  # 40 and 30 shared
    assert list(map_.covisible(3)) == [2]  # 10 shared: below 15, the best one is taken
    map_.forget(55, 1)
    map_.cull_points(np.array([56, 57]))
    assert map_.covisibility[1, 2] == 30 - 3 and map_.covisibility[0, 2] == 10 - 2
    assert map_.covisibility[0, 1] == 40 - 1 - 2
    assert (map_.covisibility == map_.covisibility.T).all()


def _perturbed(map_: Map, seed: int, first: int = 1) -> None:
    """Keyframes from ``first`` on and every point moved by ~1 cm."""
    rng = np.random.default_rng(seed)
    for kf in map_.all_keyframes[first:]:
        kf.world_from_camera[:3, 3] += rng.normal(0, 0.01, 3)
    map_.positions += rng.normal(0, 0.01, map_.positions.shape)


def test_covisibility_bundle_adjustment_equals_the_plain_window_where_they_coincide():
    """Every keyframe shares at least 15 points with the last: the covisibility window is the
    whole map, keyframe 0 fixed. The result equals bundle_adjust on that window built by hand
    (every observation, first keyframe fixed)."""
    visible = [
        np.arange(0, 80),
        np.arange(10, 90),
        np.arange(20, 100),
        np.arange(30, 110),
        np.arange(40, 120),
    ]
    map_, _, _ = synthetic_map([0.0, 0.15, 0.3, 0.45, 0.6], visible)
    _perturbed(map_, 1)
    reference = map_.copy()
    LocalMapping(TC, CAMERA).local_bundle_adjustment(map_, 4)
    index, kfs, kps = reference.observation_table(np.arange(120))
    uv = np.empty((len(kfs), 2))
    ur, weight = np.empty(len(kfs)), np.empty(len(kfs))
    for k in range(5):
        rows = kfs == k
        uv[rows], ur[rows], weight[rows] = observations(TC, reference.keyframe(k).features, kps[rows])
    window = BundleWindow(
        np.array([invert(kf.world_from_camera) for kf in reference.all_keyframes]),
        np.array([False, True, True, True, True]),
        reference.positions.copy(),
        kfs,
        index,
        uv,
        ur,
        weight,
        CAMERA,
        TC.baseline_fx,
    )
    poses, points, _, _ = bundle_adjust(window, TC.ba_iterations)
    for k in range(5):
        assert np.allclose(map_.keyframe(k).world_from_camera, invert(poses[k]), atol=1e-9), k
    assert np.allclose(map_.positions, points, atol=1e-9)


def test_covisibility_bundle_adjustment_holds_weakly_connected_keyframes_fixed():
    """Keyframe 1 shares only 10 points with the last keyframe (4) and none of 2-4's neighbours
    set it free: it takes part held fixed (pose unchanged) where a window of the last five
    keyframes would have moved it; keyframes 2-4 (moved by ~1 cm, the observations exact) come
    back to the truth."""
    visible = [
        np.arange(0, 60),
        np.r_[np.arange(0, 50), np.arange(110, 120)],
        np.arange(40, 120),
        np.arange(45, 120),
        np.arange(50, 120),
    ]
    map_, truth, poses = synthetic_map([0.0, 0.15, 0.3, 0.45, 0.6], visible)
    assert 1 not in map_.covisible(4) and map_.covisibility[1, 4] == 10
    _perturbed(map_, 2, first=2)
    before = [kf.world_from_camera.copy() for kf in map_.all_keyframes]
    LocalMapping(TC, CAMERA).local_bundle_adjustment(map_, 4)
    assert np.array_equal(map_.keyframe(0).world_from_camera, before[0])
    assert np.array_equal(map_.keyframe(1).world_from_camera, before[1])
    for k in (2, 3, 4):
        assert np.linalg.norm(before[k][:3, 3] - poses[k][:3, 3]) > 1e-3
        assert np.allclose(map_.keyframe(k).world_from_camera, poses[k], atol=1e-9), k
