"""Relocalisation: finding a lost frame's pose again against the keyframes.

Holds ORB-SLAM's Relocalization with a plain keyframe database: the candidates are the
``relocalize_keyframes`` (20) most recent keyframes, newest first, instead of a bag-of-words
query; each is matched by descriptor, and the first whose pose (PnP RANSAC, refined) keeps
``min_inliers`` inliers wins.
"""

from __future__ import annotations

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.slam.config import TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.geometry import invert
from depotbench.slam.map import Map
from depotbench.slam.matcher import Matcher
from depotbench.slam.pose import MIN_MATCHES, Tracked, solve_pose

RATIO_TEST = 0.8
"""Relocalisation's nearest/second-nearest test. It compares against every point of a keyframe
(ORB-SLAM: only within a vocabulary node), which is strict enough that TH_LOW (50) on top left
a prior_flow run on a 3-walker xyz scene lost for its last 92 of 200 frames; with TH_HIGH it
relocalised and tracked 152 of them (measured)."""


def relocalise(
    map_: Map,
    matcher: Matcher,
    tc: TrackingConfig,
    camera: Intrinsics,
    features: FrameFeatures,
    usable: np.ndarray,
) -> Tracked | None:
    """The frame's pose against the first recent keyframe it matches well enough, or None."""
    candidates = np.flatnonzero(usable)
    if len(candidates) < MIN_MATCHES:
        return None
    for keyframe in reversed(map_.keyframes[-tc.relocalize_keyframes :]):
        ids = keyframe.point_ids[keyframe.point_ids >= 0]
        ids = ids[map_.alive[ids]]
        if len(ids) < MIN_MATCHES:
            continue
        kp, pid = matcher.search_by_descriptor(map_, features, candidates, ids, RATIO_TEST)
        if len(kp) < MIN_MATCHES:
            continue
        solved = solve_pose(tc, camera, features, kp, map_.positions[pid], None)
        if solved is None:
            continue
        pose_cw, inl = solved
        if inl.sum() >= tc.min_inliers:
            return Tracked(invert(pose_cw), kp[inl], pid[inl], int(inl.sum()))
    return None
