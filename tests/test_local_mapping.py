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
from depotbench.slam.matcher import Matcher, predict_level, search_for_triangulation
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
    n_kfs: int,
    ref_matches: int,
    inliers: int,
    tracked_close: int,
    untracked_close: int,
    since_reloc: int,
    idle: bool = True,
    since_keyframe: int = 0,
) -> bool:
    """Tracking::NeedNewKeyFrame of ORB-SLAM3 for RGB-D (not inertial) up to the busy
    mapper's queue rule, written out on its counts."""
    if since_reloc < 30 and n_kfs > 30:
        return False
    need_close = tracked_close < 100 and untracked_close > 70
    th_ref_ratio = 0.4 if n_kfs < 2 else 0.75
    c1a = since_keyframe >= 30  # mCurrentFrame.mnId >= mnLastKeyFrameId + mMaxFrames
    c1b = idle  # mCurrentFrame.mnId >= mnLastKeyFrameId + mMinFrames (0) and the mapper idle
    c1c = inliers < ref_matches * 0.25 or need_close  # RGB-D, not inertial
    c2 = (inliers < ref_matches * th_ref_ratio or need_close) and inliers > 15
    return (c1a or c1b or c1c) and c2


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


@pytest.mark.parametrize(("idle", "since_keyframe"), [(True, 0), (False, 0), (False, 29), (False, 30)])
@pytest.mark.parametrize("n_kfs", [1, 2, 3, 31])
def test_keyframe_decision_is_orb_slam3s_rule_on_counts(n_kfs: int, idle: bool, since_keyframe: int):
    """Over a grid of counts around each threshold (0.25 / 0.4 / 0.75 of the reference's
    points, 100 tracked close, 70 untracked close, 15 inliers, 30 frames after relocalisation
    or since the last keyframe), with the mapper idle or busy, the decision on the constructed
    map equals the rule written out on the counts."""
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
            idle,
            since_keyframe,
        )
        usable = np.ones(len(frame), bool)
        got = mapping.need_keyframe(map_, frame, usable, tracked, reference, since, idle, since_keyframe)
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


def test_keypoint_values_are_each_keyframes_own_as_keyframes_come_and_after_a_copy():
    """``Map.keypoint_values`` gathers from one table that grows with the keyframes: asked
    between keyframes of different sizes, and on a copy that then goes its own way, it gives
    each keyframe's own octaves and descriptors."""
    rng = np.random.default_rng(4)
    map_ = Map()

    def add(target: Map, n: int) -> None:
        frame = features(np.full(n, 2.0), int(rng.integers(1 << 30)))
        frame.octaves[:] = rng.integers(0, 8, n)
        target.add_keyframe(
            KeyFrame(len(target.all_keyframes), 0, np.eye(4), frame, np.ones(n, bool), np.full(n, -1))
        )

    def check(target: Map) -> None:
        kfs = rng.integers(0, len(target.all_keyframes), 500)
        kps = np.array([rng.integers(0, len(target.keyframe(k).features)) for k in kfs])
        for name in ("octaves", "descriptors"):
            expected = np.array(
                [getattr(target.keyframe(k).features, name)[i] for k, i in zip(kfs, kps, strict=True)]
            )
            np.testing.assert_array_equal(target.keypoint_values(name, kfs, kps), expected)

    for n in (5, 300, 1, 40):
        add(map_, n)
        check(map_)
    fork = map_.copy()
    for n in (700, 2, 1000):  # the table's room doubles past what it held
        add(map_, n)
        check(map_)
    add(fork, 9)
    check(fork)
    assert len(fork.all_keyframes) == 5 and len(map_.all_keyframes) == 7


# -- triangulation (CreateNewMapPoints) ------------------------------------------------------


def _view(
    points: np.ndarray, pose: np.ndarray, depth: bool, octaves: np.ndarray | None = None
) -> FrameFeatures:
    """Exact keypoints of world ``points`` seen from ``pose`` (world_from_camera)."""
    pc = (points - pose[:3, 3]) @ pose[:3, :3]
    uv = np.c_[CAMERA.fx * pc[:, 0] / pc[:, 2] + CAMERA.cx, CAMERA.fy * pc[:, 1] / pc[:, 2] + CAMERA.cy]
    n = len(points)
    return FrameFeatures(
        np.zeros((0, 0), np.uint8),
        uv.astype(np.float32),
        uv,
        np.zeros(n, int) if octaves is None else octaves,
        np.random.default_rng(7).integers(0, 256, (n, 32), dtype=np.uint8),
        pc[:, 2] if depth else np.zeros(n),
        np.zeros(n),
    )


def test_triangulation_recovers_known_points_from_two_views_without_depth():
    """Two views 0.3 m apart of points 2-5 m away, no depth: the DLT gives each point back
    (1e-9 m); a swapped pair fails the reprojection test and a pair seen at levels 0 and 5
    fails the scale test (their distances agree, 1.2^5 = 2.5 does not)."""
    rng = np.random.default_rng(3)
    truth = np.c_[rng.uniform(-1, 1, 40), rng.uniform(-0.7, 0.7, 40), rng.uniform(2, 5, 40)]
    pose1, pose2 = _pose(0.0), _pose(0.3, 0.05)
    octaves2 = np.zeros(40, int)
    octaves2[39] = 5
    view1, view2 = _view(truth, pose1, False), _view(truth, pose2, False, octaves2)
    i1 = np.arange(40)
    i2 = np.arange(40)
    i2[[0, 1]] = [1, 0]  # a swapped pair
    mapping = LocalMapping(TC, CAMERA)
    points, ok = mapping.triangulate(view1, i1, invert(pose1), view2, i2, invert(pose2))
    assert not ok[0] and not ok[1] and not ok[39]
    assert ok[2:39].all()
    assert np.abs(points[2:39] - truth[2:39]).max() < 1e-9


def test_triangulation_takes_the_depth_where_it_sees_more_parallax_than_the_rays():
    """With depth (measured 2 % long) the rule picks by parallax: 0.3 m apart at 2-3 m the rays'
    parallax (about 6 degrees) beats the depth's (2 atan(b / 2 / z), about 2 degrees), so the
    DLT gives the true point; 2 cm apart at 4-5 m the depth's wins, so the point is the
    first view's back-projection, 2 % long (its reprojection in the second view still passes)."""
    rng = np.random.default_rng(4)
    mapping = LocalMapping(TC, CAMERA)
    for baseline, near, far, dlt in ((0.3, 2.0, 3.0, True), (0.02, 4.0, 5.0, False)):
        truth = np.c_[rng.uniform(-0.3, 0.3, 20), rng.uniform(-0.3, 0.3, 20), rng.uniform(near, far, 20)]
        pose1, pose2 = _pose(0.0), _pose(baseline)
        view1 = _view(truth, pose1, True)
        long1 = FrameFeatures(
            *[
                getattr(view1, f)
                for f in ("grey", "keypoints_px", "undistorted_px", "octaves", "descriptors")
            ],
            view1.depth_m * 1.02,
            view1.angles_deg,
        )
        view2 = _view(truth, pose2, False)
        rays = np.cos(np.arctan2(baseline, truth[:, 2]))  # about the parallax of the two rays
        depth_parallax = np.cos(2 * np.arctan2(mapping.baseline_m / 2, long1.depth_m))
        assert ((rays < depth_parallax) == dlt).all()
        idx = np.arange(20)
        points, ok = mapping.triangulate(long1, idx, invert(pose1), view2, idx, invert(pose2))
        expected = truth if dlt else truth * 1.02  # the first camera sits at the origin
        assert ok.all(), (baseline, ok)
        assert np.abs(points - expected).max() < 1e-9, baseline


def test_search_for_triangulation_pairs_keypoints_on_their_epipolar_lines():
    """Each keypoint of view 1 is paired with its true keypoint in view 2; a decoy with the
    same descriptor 6 px off the epipolar line is refused, and keypoints that already have
    a point are left out."""
    rng = np.random.default_rng(5)
    truth = np.c_[rng.uniform(-1, 1, 30), rng.uniform(-0.7, 0.7, 30), rng.uniform(2, 5, 30)]
    pose1, pose2 = _pose(0.0), _pose(0.25, 0.03)
    view1, view2 = _view(truth, pose1, False), _view(truth, pose2, False)
    decoy_px = view2.undistorted_px[:1] + [[0.0, 6.0]]
    view2 = FrameFeatures(
        view2.grey,
        np.r_[view2.keypoints_px, decoy_px.astype(np.float32)],
        np.r_[view2.undistorted_px, decoy_px],
        np.r_[view2.octaves, 0],
        np.r_[view2.descriptors, view1.descriptors[:1]],
        np.r_[view2.depth_m, 0.0],
        np.r_[view2.angles_deg, 0.0],
    )
    view2.descriptors[:30] = view1.descriptors  # the true pairs share descriptors
    view2.descriptors[0, 0] ^= 1  # the decoy is the closer descriptor for keypoint 0
    free1 = np.ones(30, bool)
    free1[29] = False
    i1, i2 = search_for_triangulation(
        TC, CAMERA, view1, free1, invert(pose1), view2, np.ones(31, bool), invert(pose2)
    )
    assert list(i1) == list(range(29)) and list(i2) == list(range(29))


# -- keyframe culling and fusion ---------------------------------------------------------------


def _culling_map(others: int, share: float, coarse: bool = False) -> Map:
    """Keyframe 1 sees 100 close points (depth 2 m, level 1); ``share`` of them are also seen
    by ``others`` keyframes (2 .. others + 1) at level 0, or at level 3 with ``coarse``; the
    rest only by keyframe 1 and keyframe 0. Keyframe 0 sees all of keyframe 1's points (it is
    never culled); each other keyframe also sees 20 points of its own, which keeps it."""
    n = 100
    own = 20
    map_ = Map()
    ids = map_.add_points(np.zeros((n, 3)), np.zeros((n, 32), np.uint8), 0)
    seen_often = np.arange(int(round(share * n)))
    for k in range(others + 2):
        size = n + own
        octaves = np.full(size, 1 if k == 1 else (3 if coarse else 0))
        frame = FrameFeatures(
            np.zeros((0, 0), np.uint8),
            np.zeros((size, 2), np.float32),
            np.zeros((size, 2)),
            octaves,
            np.zeros((size, 32), np.uint8),
            np.full(size, 2.0),
            np.zeros(size),
        )
        map_.add_keyframe(KeyFrame(k, k, np.eye(4), frame, np.ones(size, bool), np.full(size, -1)))
        for i in ids if k < 2 else seen_often:
            map_.observe(int(i), k, int(i))
        if k >= 2:
            private = map_.add_points(np.zeros((own, 3)), np.zeros((own, 32), np.uint8), k)
            for j, point in enumerate(private):
                map_.observe(int(point), k, n + j)
    return map_


@pytest.mark.parametrize(
    ("others", "share", "coarse", "culled"),
    [
        (4, 0.95, False, True),  # 95 % seen by 4 others (5 with keyframe 0): redundant
        (4, 0.90, False, False),  # exactly 90 %: not over 90 %
        (3, 0.95, False, True),  # 3 others plus keyframe 0 make 4 > 3
        (2, 0.95, False, False),  # 2 others plus keyframe 0 make 3, not more than 3
        (4, 0.95, True, False),  # the others see them two levels coarser: they do not count
    ],
)
def test_keyframe_culling_drops_a_keyframe_whose_close_points_others_see(others, share, coarse, culled):
    """ORB-SLAM3's KeyFrameCulling counted by hand: keyframe 1 goes when over 90 % of its close
    points are seen by more than 3 other keyframes at its level + 1 or finer."""
    map_ = _culling_map(others, share, coarse)
    removed = LocalMapping(TC, CAMERA).keyframe_culling(map_, others + 1)
    assert removed == int(culled)
    assert map_.keyframe(1).bad == culled
    assert 1 not in [kf.id for kf in map_.keyframes] if culled else len(map_.keyframes) == others + 2
    if culled:  # its observations are gone, the covisibility with it too
        assert (map_.keyframe(1).point_ids == -1).all() and (map_.covisibility[1] == 0).all()
        assert all(1 not in map_.observations.get(p, {}) for p in range(100))


def test_keyframe_culling_ignores_far_points_and_keeps_the_first_keyframe():
    """Points farther than ThDepth do not count either way (here: all of keyframe 1's non-
    redundant points are far, so its close points are all redundant); keyframe 0 is never culled."""
    map_ = _culling_map(4, 0.5)
    map_.keyframe(1).features.depth_m[50:] = THDEPTH + 1.0
    mapping = LocalMapping(TC, CAMERA)
    assert mapping.keyframe_culling(map_, 5) == 1 and map_.keyframe(1).bad
    assert not map_.keyframe(0).bad


def test_observing_many_at_once_equals_observing_one_by_one():
    """Map.observe_many against observe in a loop: the same observation dictionaries (in the
    same order), covisibility, counts, weights (a keypoint without depth weighs 1) and point
    ids, a point listed twice taking only its first keypoint."""
    visible = [np.arange(0, 60), np.arange(20, 80), np.arange(50, 110)]
    maps = [synthetic_map([0.0, 0.2, 0.4], visible)[0] for _ in range(2)]
    for map_ in maps:
        frame = maps[0].keyframe(2).features
        depth = frame.depth_m.copy()
        depth[::4] = 0.0
        view = FrameFeatures(
            frame.grey,
            frame.keypoints_px,
            frame.undistorted_px,
            frame.octaves,
            frame.descriptors,
            depth,
            frame.angles_deg,
        )
        map_.add_keyframe(KeyFrame(3, 3, np.eye(4), view, np.ones(len(depth), bool), np.full(len(depth), -1)))
    points = np.r_[np.arange(30, 90), 40, 115]
    keypoints = np.r_[np.arange(60), 7, 60 - 1]
    for point, keypoint in zip(points, keypoints, strict=True):
        maps[0].observe(int(point), 3, int(keypoint))
    maps[1].observe_many(points, 3, keypoints)
    one, many = maps
    assert list(one.observations.items()) == list(many.observations.items())
    assert all(list(one.observations[p]) == list(many.observations[p]) for p in one.observations)
    np.testing.assert_array_equal(one.covisibility, many.covisibility)
    np.testing.assert_array_equal(one.n_observations, many.n_observations)
    np.testing.assert_array_equal(one.observation_weight, many.observation_weight)
    np.testing.assert_array_equal(one.keyframe(3).point_ids, many.keyframe(3).point_ids)
    assert one.covisibility[3, :3].tolist() == [30, 50, 40]  # points 30-59, 30-79, 50-89 shared


def test_resolving_one_point_follows_its_merges_as_resolving_many_does():
    """``Map.resolve_one`` (Fuse's one match at a time) against ``Map.resolve``: chains of
    merged points followed to their end, live points and -1 left as they are."""
    map_ = synthetic_map([0.0, 0.2], [np.arange(0, 40), np.arange(10, 50)])[0]
    map_.replace_point(3, 7)
    map_.replace_point(7, 12)  # 3 -> 7 -> 12
    map_.replace_point(20, 21)
    ids = np.r_[-1, np.arange(0, 50)]
    assert [map_.resolve_one(int(i)) for i in ids] == map_.resolve(ids).tolist()
    assert map_.resolve_one(3) == 12 and map_.resolve_one(-1) == -1


def test_sightings_and_local_points_follow_the_observations():
    """Map.sightings (how many of a frame's points each keyframe sees) and Map.points_of (the
    points of a set of keyframes) against the observation dictionaries, counted by hand, after
    forgotten observations, culled points, a merge and a culled keyframe; a point listed twice
    (two keypoints of a frame after a fusion) counts twice, as ORB-SLAM counts per keypoint.
    Map.observation_table lists the same observations in the dictionaries' order."""
    visible = [np.arange(0, 60), np.arange(20, 80), np.arange(50, 110), np.arange(100, 120)]
    map_, _, _ = synthetic_map([0.0, 0.2, 0.4, 0.6], visible)
    map_.forget(55, 1)
    map_.cull_points(np.array([56, 57]))
    map_.replace_point(25, 70)
    map_.set_bad(3)
    frame_points = np.r_[np.arange(10, 75, 3), 70, 70]

    def by_hand(points):
        counts = np.zeros(len(map_.all_keyframes), int)
        for point in points:
            for kf in map_.observations.get(int(point), {}):
                counts[kf] += 1
        return counts

    np.testing.assert_array_equal(map_.sightings(frame_points), by_hand(frame_points))
    assert map_.covisible(0).tolist() == [1]  # 2 shares 8 points with it: under 15
    copy = map_.copy()
    copy.set_bad(1)  # a culled keyframe is nobody's neighbour (in the copy only): 2 is the best left
    assert copy.covisible(0).tolist() == [2] and map_.covisible(0).tolist() == [1]
    assert map_.sightings(frame_points)[3] == 0 and map_.sightings(np.array([70]))[0] == 1  # 25 merged
    for keyframes in ([0], [1, 2], [0, 1, 2, 3]):
        expected = sorted(p for p, seen in map_.observations.items() if set(seen) & set(keyframes))
        assert map_.points_of(keyframes).tolist() == [p for p in expected if map_.alive[p]]
    # observation_table: every observation, point by point in the dictionaries' order
    table = [
        (i, kf, kp)
        for i, p in enumerate(frame_points)
        for kf, kp in map_.observations.get(int(p), {}).items()
    ]
    assert list(zip(*(a.tolist() for a in map_.observation_table(frame_points)), strict=True)) == table


def test_fusion_adds_observations_and_merges_duplicates():
    """Points projected onto a keyframe: a point over a free keypoint with its descriptor is
    added there; a point over a keypoint that holds another point merges with it (the one seen
    by fewer keyframes goes, its observations move); a point 30 px off its keypoint, and one
    behind the camera, are left alone."""
    rng = np.random.default_rng(8)
    truth = np.c_[rng.uniform(-1, 1, 4), rng.uniform(-0.5, 0.5, 4), rng.uniform(2, 3, 4)]
    seen = truth.copy()
    truth[3, 2] = -2.0  # the point is behind; its keypoint is where it would be in front
    pose = _pose(0.0)
    view = _view(seen, pose, True)
    view.undistorted_px[2] += 30.0
    map_ = Map()
    map_.add_keyframe(
        KeyFrame(0, 0, _pose(0.1), _view(seen, _pose(0.1), True), np.ones(4, bool), np.full(4, -1))
    )
    map_.add_keyframe(KeyFrame(1, 1, pose, view, np.ones(4, bool), np.full(4, -1)))
    ids = map_.add_points(truth, view.descriptors.copy(), 0)
    duplicate = map_.add_points(truth[1:2], view.descriptors[1:2], 1)[0]
    map_.observe(int(duplicate), 1, 1)  # keyframe 1's keypoint 1 holds a duplicate seen once
    for i in ids:
        map_.observe(int(i), 0, int(i))
    mapping = LocalMapping(TC, CAMERA)
    mapping._update_points(map_, np.r_[ids, duplicate])
    fused = mapping._fuse(map_, 1, ids)
    assert fused == 2
    assert map_.keyframe(1).point_ids[0] == ids[0] and 1 in map_.observations[int(ids[0])]
    assert not map_.alive[duplicate] and map_.replaced[duplicate] == ids[1]  # merged into ids[1]
    assert map_.keyframe(1).point_ids[1] == ids[1] and set(map_.observations[int(ids[1])]) == {0, 1}
    assert map_.keyframe(1).point_ids[2] == -1 and map_.keyframe(1).point_ids[3] == -1


# -- the predicted-scale local-map search --------------------------------------------------------


def test_predicted_level_is_orb_slams_predict_scale():
    """ceil(log(max_distance / distance) / log(1.2)) clipped to the pyramid, on values where
    the log is well away from an integer."""
    max_distance = np.array([4.0, 4.0, 4.0, 4.0, 1.0, 40.0])
    distance = np.array([4.1, 3.9, 2.0, 1.0, 3.0, 1.0])
    expected = [0, 1, 4, 7, 0, 7]  # 4/2 = 2 -> 3.8 -> 4; 4/1 -> 7.6 -> 8 -> 7; 1/3 -> < 0 -> 0
    assert list(predict_level(max_distance, distance, 1.2, 8)) == expected


def _search_reference(map_, point_ids, pose_cw, frame, usable, exclude, th):
    """SearchLocalPoints written out point by point and keypoint by keypoint."""
    center = invert(pose_cw)[:3, 3]
    best_of_point = {}
    in_view = []
    for p in point_ids:
        pw = map_.positions[p]
        pc = pose_cw[:3, :3] @ pw + pose_cw[:3, 3]
        if pc[2] <= 0:
            continue
        u = CAMERA.fx * pc[0] / pc[2] + CAMERA.cx
        v = CAMERA.fy * pc[1] / pc[2] + CAMERA.cy
        if not (0 <= u < CAMERA.width and 0 <= v < CAMERA.height):
            continue
        dist = np.linalg.norm(pw - center)
        if dist < 0.8 * map_.min_distance[p] or dist > 1.2 * map_.max_distance[p]:
            continue
        view_cos = (pw - center) @ map_.normals[p] / dist
        if view_cos < 0.5:
            continue
        in_view.append(p)
        level = min(max(int(np.ceil(np.log(map_.max_distance[p] / dist) / np.log(1.2))), 0), 7)
        r = th * (2.5 if view_cos > 0.998 else 4.0) * 1.2**level
        found = []
        for k in range(len(frame)):
            if not usable[k] or exclude[k]:
                continue
            x, y = frame.undistorted_px[k]
            if abs(x - u) >= r or abs(y - v) >= r:
                continue
            if not level - 1 <= frame.octaves[k] <= level:
                continue
            if frame.depth_m[k] > 0 and abs((u - 40.0 / pc[2]) - (x - 40.0 / frame.depth_m[k])) > r:
                continue
            d = int(np.unpackbits(map_.descriptors[p] ^ frame.descriptors[k]).sum())
            found.append((d, k))
        if not found:
            continue
        found.sort()
        d1, k1 = found[0]
        if d1 > 100:
            continue
        if len(found) > 1:
            d2, k2 = found[1]
            if frame.octaves[k2] == frame.octaves[k1] and d1 > 0.8 * d2:
                continue
        best_of_point[p] = (d1, k1)
    best_of_keypoint = {}
    for p, (d, k) in best_of_point.items():
        if k not in best_of_keypoint or d < best_of_keypoint[k][0]:
            best_of_keypoint[k] = (d, p)
    return {(k, p) for k, (d, p) in best_of_keypoint.items()}, set(in_view)


def test_local_map_search_equals_the_rule_written_out():
    """On 300 points (some out of range, off their normal or behind) and a frame of their
    keypoints moved by up to 8 px, at their predicted level or up to two finer, with noisy
    depth and descriptors, plus 300 keypoints of clutter, the vectorised search finds the
    matches and the in-view points of the rule written out with loops."""
    rng = np.random.default_rng(11)
    n = 300
    pose = _pose(0.05, 0.02)
    pose_cw = invert(pose)
    pc = np.c_[rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(1.0, 6.0, n)]
    pc[:10, 2] = -1.0  # behind
    points = pc @ pose[:3, :3].T + pose[:3, 3]
    map_ = Map()
    ids = map_.add_points(points, rng.integers(0, 256, (n, 32), dtype=np.uint8), 0)
    to_point = points - pose[:3, 3]
    dist = np.linalg.norm(to_point, axis=1)
    normal = to_point / dist[:, None] + rng.normal(0, 0.05, (n, 3))
    normal[10:30] = -normal[10:30]  # seen from behind
    map_.normals[:] = normal / np.linalg.norm(normal, axis=1)[:, None]
    map_.max_distance[:] = dist * 1.2 ** rng.integers(0, 5, n) * rng.uniform(0.9, 1.1, n)
    map_.max_distance[30:40] = dist[30:40] / 2  # too far for them
    map_.min_distance[:] = map_.max_distance / 1.2**7
    uv = np.c_[CAMERA.fx * pc[:, 0] / pc[:, 2] + CAMERA.cx, CAMERA.fy * pc[:, 1] / pc[:, 2] + CAMERA.cy]
    kp = np.r_[uv + rng.uniform(-8, 8, (n, 2)), rng.uniform(0, [640, 480], (n, 2))]
    level = predict_level(map_.max_distance, dist, 1.2, 8)
    octaves = np.r_[np.maximum(level - rng.integers(0, 3, n), 0), rng.integers(0, 5, n)]
    descriptors = np.r_[map_.descriptors.copy(), rng.integers(0, 256, (n, 32), dtype=np.uint8)]
    flips = rng.random((n, 256)) < rng.uniform(0, 0.5, n)[:, None]
    descriptors[:n] ^= np.packbits(flips, axis=1)
    depth = np.r_[np.abs(pc[:, 2]) * rng.uniform(0.9, 1.1, n), rng.uniform(0, 6, n)]
    depth[rng.random(2 * n) < 0.2] = 0.0
    frame = FrameFeatures(
        np.zeros((0, 0), np.uint8),
        kp.astype(np.float32),
        kp,
        octaves,
        descriptors,
        depth,
        np.zeros(2 * n),
    )
    usable = rng.random(2 * n) > 0.1
    exclude = rng.random(2 * n) < 0.1
    matcher = Matcher(TC, CAMERA)
    kps, pids, in_view = matcher.search_local_points(map_, ids, pose_cw, frame, usable, exclude, 3.0)
    expected, expected_in_view = _search_reference(map_, ids, pose_cw, frame, usable, exclude, 3.0)
    assert set(in_view.tolist()) == expected_in_view
    assert set(zip(kps.tolist(), pids.tolist(), strict=True)) == expected
    assert len(expected) > 50 and len(expected_in_view) < n - 40


# -- tracking against the reference keyframe ---------------------------------------------------


def test_reference_keyframe_search_equals_the_rule_written_out():
    """Each usable keypoint's closest keyframe point within TH_LOW (50) and under 0.7 times the
    second closest, one keypoint per point (the closest), then the 3 most common angle
    changes: against loops over every pair."""
    rng = np.random.default_rng(12)
    n_points, n_keypoints = 80, 200
    map_ = Map()
    ids = map_.add_points(np.zeros((n_points, 3)), rng.integers(0, 256, (n_points, 32), dtype=np.uint8), 0)
    descriptors = rng.integers(0, 256, (n_keypoints, 32), dtype=np.uint8)
    source = rng.integers(0, n_points, n_keypoints)
    near = rng.random(n_keypoints) < 0.7
    flips = rng.random((n_keypoints, 256)) < rng.uniform(0, 0.2, n_keypoints)[:, None]
    descriptors[near] = map_.descriptors[source[near]] ^ np.packbits(flips[near], axis=1)
    kf_angles = rng.uniform(0, 360, n_points)
    angles = np.where(near, kf_angles[source] + rng.choice([5.0, 5.0, 5.0, 100.0], n_keypoints), 0.0)
    frame = FrameFeatures(
        np.zeros((0, 0), np.uint8),
        np.zeros((n_keypoints, 2), np.float32),
        np.zeros((n_keypoints, 2)),
        np.zeros(n_keypoints, int),
        descriptors,
        np.zeros(n_keypoints),
        np.mod(angles, 360.0),
    )
    usable = rng.random(n_keypoints) > 0.1
    kps, pids = Matcher(TC, CAMERA).search_keyframe(map_, ids, kf_angles, frame, usable)
    best = {}
    for k in np.flatnonzero(usable):
        d = [int(np.unpackbits(descriptors[k] ^ map_.descriptors[p]).sum()) for p in ids]
        order = np.argsort(d, kind="stable")
        if d[order[0]] <= 50 and d[order[0]] < 0.7 * d[order[1]]:
            p = int(order[0])
            if p not in best or d[order[0]] < best[p][0]:
                best[p] = (d[order[0]], int(k))
    pairs = [(k, p) for p, (_, k) in best.items()]
    delta = np.array([frame.angles_deg[k] - kf_angles[p] for k, p in pairs])
    bins = (np.mod(delta, 360.0) // 12).astype(int)
    counts = np.bincount(bins, minlength=30)
    top = np.argsort(-counts, kind="stable")[:3]
    top = top[counts[top] >= 0.1 * counts[top[0]]]
    expected = {pair for pair, b in zip(pairs, bins, strict=True) if b in top}
    assert set(zip(kps.tolist(), pids.tolist(), strict=True)) == expected
    assert len(expected) > 20


@pytest.mark.render
def test_a_frame_the_motion_model_loses_is_tracked_against_the_reference_keyframe(tmp_path):
    """A static depot sequence tracked with a motion model that predicts a 0.5 m jump: the
    motion-model search finds too few matches, the reference keyframe's points give the pose
    (ORB-SLAM's TrackReferenceKeyFrame) and the frame stays OK, within 2 cm of where the
    unperturbed run puts it."""
    from depotbench.eval.run.harness import camera_of
    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.generate import generate
    from depotbench.sim.sequence import Sequence
    from depotbench.slam.config import SlamConfig
    from depotbench.slam.system import Slam
    from depotbench.slam.types import Frame, TrackingState

    spec = library.get("static_depot").model_copy(update={"frames": 8, "duration_s": None})
    seq = Sequence.open(generate(to_scenario(spec), tmp_path / "depot", progress=False))
    camera = camera_of(seq)
    frames = [Frame(seq.frames[i].timestamp_s, seq.rgb(i), seq.depth_m(i), camera) for i in range(8)]
    plain, jumped = Slam(SlamConfig(), camera), Slam(SlamConfig(), camera)
    for frame in frames[:7]:
        plain.process(frame)
        jumped.process(frame)
    jump = np.eye(4)
    jump[:3, 3] = (0.5, 0.0, 0.0)
    jumped.tracking._velocity = jump
    features = jumped.extract(frames[7])
    assert jumped.tracking._track_motion_model(features, np.ones(len(features), bool)) is None
    expected = plain.process(frames[7])
    got = jumped.process(frames[7])
    assert got.state == TrackingState.OK
    assert np.linalg.norm(got.world_from_camera[:3, 3] - expected.world_from_camera[:3, 3]) < 0.02


def test_a_keyframe_keeps_the_matches_its_frames_pose_optimisation_set_aside(tmp_path, monkeypatch):
    """ORB-SLAM3 passes a keyframe the matches its frame's last pose optimisation called
    outliers ("so that bundle adjustment will finally decide"; its local BA drops those it
    still finds outliers): the keyframe gets those points at those keypoints and makes no
    new point there. On walking_xyz (people close to
    the camera: outliers on most frames) every keyframe after the first gets exactly its
    frame's set-aside matches. (They were cleared before the keyframe was made, so keyframes
    made new points for them: 260 instead of ~190 a keyframe, one keyframe every 3 frames
    where ORB-SLAM3 makes one every 2.)"""
    from depotbench.eval.run.harness import camera_of
    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.generate import generate
    from depotbench.sim.sequence import Sequence
    from depotbench.slam.config import SlamConfig
    from depotbench.slam.system import Slam
    from depotbench.slam.tracking import Tracking
    from depotbench.slam.types import Frame

    spec = library.get("walking_xyz").model_copy(update={"frames": 10, "duration_s": None})
    seq = Sequence.open(generate(to_scenario(spec), tmp_path / "walk", progress=False))
    camera = camera_of(seq)
    set_aside, passed = [], []
    track, insert = Tracking._track, LocalMapping.insert_keyframe

    def recording_track(self, features, usable):
        tracked = track(self, features, usable)
        set_aside.append(tuple(a.copy() for a in self._outliers))
        return tracked

    def recording_insert(self, map_, features, usable, tracked, frame_index, outliers=None):
        made = insert(self, map_, features, usable, tracked, frame_index, outliers)
        if frame_index > 0:
            passed.append((frame_index, outliers, made))
        return made

    monkeypatch.setattr(Tracking, "_track", recording_track)
    monkeypatch.setattr(LocalMapping, "insert_keyframe", recording_insert)
    slam = Slam(SlamConfig(), camera)
    for i in range(10):
        slam.process(Frame(seq.frames[i].timestamp_s, seq.rgb(i), seq.depth_m(i), camera))
    assert len(passed) >= 3
    for frame_index, (keypoints, point_ids), made in passed:
        made_keypoints = np.flatnonzero(made)
        expected_keypoints, expected_ids = set_aside[frame_index - 1]  # frame 0 initialises
        assert len(expected_keypoints) > 10, frame_index
        np.testing.assert_array_equal(keypoints, expected_keypoints)
        np.testing.assert_array_equal(point_ids, expected_ids)
        assert not set(made_keypoints.tolist()) & set(keypoints.tolist())


def test_a_point_left_with_one_depth_observation_after_local_ba_is_culled():
    """ORB-SLAM3's MapPoint::EraseObservation: the local BA drops outlier observations, and a
    point then seen by at most one keyframe with depth (weight <= 2) is culled. Point 5 is seen
    by keyframes 1 and 2 only, 60 px off in keyframe 2: the BA drops its observations and the
    point goes with them (before, it stayed alive, seen by no keyframe). Every seen point
    left alive has weight over 2; the points no observation of which was off all stay."""
    visible = [np.arange(6, 80), np.arange(0, 80), np.arange(0, 80)]
    map_, _, _ = synthetic_map([0.0, 0.2, 0.4], visible)
    keypoint = map_.observations[5][2]
    map_.all_keyframes[2].features.undistorted_px[keypoint, 0] += 60.0
    LocalMapping(TrackingConfig(), CAMERA).local_bundle_adjustment(map_, 2)
    assert not map_.alive[5] and 5 not in map_.observations
    assert all((kf.point_ids != 5).all() for kf in map_.all_keyframes)
    alive = np.flatnonzero(map_.alive[:80])  # points 80-119 are seen by no keyframe
    assert (map_.observation_weight[alive] > 2).all()
    assert map_.alive[6:80].all()


def test_keypoint_values_gathers_each_keyframes_values_in_the_order_asked_and_none_for_none():
    """``Map.keypoint_values`` reads each keyframe's feature array at its keypoints, in the
    order the observations come (interleaved keyframes included), and an empty table gives
    an empty array: keyframe culling asks for none when a candidate's points have no other
    observer (the grouped version raised there, found by a 146-frame walking_static clip)."""
    from types import SimpleNamespace

    from depotbench.slam.map import Map

    octaves = [np.array([5, 6, 7]), np.array([0, 1, 2, 3]), np.array([9, 8])]
    map_ = Map()
    map_.all_keyframes = [SimpleNamespace(features=SimpleNamespace(octaves=o)) for o in octaves]
    kfs, kps = np.array([2, 0, 1, 2, 0, 1]), np.array([1, 2, 3, 0, 0, 1])
    expected = [octaves[kf][kp] for kf, kp in zip(kfs, kps, strict=True)]
    assert map_.keypoint_values("octaves", kfs, kps).tolist() == expected
    assert len(map_.keypoint_values("octaves", np.zeros(0, int), np.zeros(0, int))) == 0


def test_a_new_keyframe_becomes_the_reference_when_earlier_ones_were_culled():
    """ORB-SLAM's CreateNewKeyFrame makes the new keyframe the reference (mpReferenceKF =
    pKF). With keyframe 1 of 0-2 culled, the frame inserted next is keyframe 3; the
    reference was set to the count of live keyframes less one (2, an older keyframe, which
    TrackReferenceKeyFrame then matched against) before."""
    from depotbench.slam.tracking import Tracking

    visible = [np.arange(0, 100), np.arange(10, 110), np.arange(20, 120)]
    map_, _, poses = synthetic_map([0.0, 0.2, 0.4], visible)
    map_.set_bad(1)
    tracking = Tracking(TC, CAMERA)
    tracking.map = map_
    frame = map_.keyframe(2).features
    seen = np.arange(len(frame))
    tracked = Tracked(poses[2].copy(), seen, visible[2].copy(), len(seen))
    tracking._insert_keyframe(frame, np.ones(len(frame), bool), tracked)
    assert map_.all_keyframes[-1].id == 3 and not map_.keyframe(3).bad
    assert tracking._reference_keyframe == 3
