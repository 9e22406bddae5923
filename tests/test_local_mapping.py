"""Local mapping as ORB-SLAM builds it (issue 40), each rule against something independent.

- The keyframe decision against ORB-SLAM3's NeedNewKeyFrame written out on plain counts.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from depotbench.core.camera import Intrinsics
from depotbench.slam.config import TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.local_mapping import CLOSE_DEPTH_FACTOR, LocalMapping
from depotbench.slam.map import KeyFrame, Map
from depotbench.slam.pose import Tracked

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
