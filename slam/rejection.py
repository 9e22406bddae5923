"""Dynamic-feature rejection strategies (design.md): which keypoints may be used.

``none``              ORB-SLAM2 stand-in: keep everything.
``box_rule``          method 2: reject inside a dynamic box unless also inside a static
                      or potential box.
``prior_flow``        method 1: sets Z (dynamic boxes, rejected), Q (potential boxes),
                      P (the rest); a Q point whose LK flow differs from P's mean flow
                      (U, V) by more than z = k |(U, V)| is dynamic; only P and static Q
                      points are kept.
``box_epipolar_flow`` method 3: dynamic boxes out; the rest tracked to the previous
                      frame, F by RANSAC, points farther than epsilon from their
                      epipolar line out; then the 2-sigma and L_thr1/L_thr2 flow tests.

Method 3's epipolar distances and flow test run compiled (``depotbench.slam.kernels.rejection``)
unless ``DEPOTBENCH_KERNELS=numpy``; ``epipolar_geometry_numpy`` and ``flow_outliers_numpy``
are the references.
"""

from __future__ import annotations

import cv2
import numpy as np
from depotbench.detectors.detection import Detection, Prior
from depotbench.slam import kernels
from depotbench.slam.config import RejectionConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.types import REJECTION_CODES, Rejection

STRATEGIES = ("none", "box_rule", "prior_flow", "box_epipolar_flow")


def inside(points: np.ndarray, detections: list[Detection], dilation: float) -> np.ndarray:
    """(N, D) bool: is point n inside (dilated) box d."""
    if not detections:
        return np.zeros((len(points), 0), dtype=bool)
    boxes = np.array([d.box_xyxy for d in detections], dtype=np.float64)
    boxes += np.array([-dilation, -dilation, dilation, dilation])
    x, y = points[:, 0:1], points[:, 1:2]
    return (x >= boxes[:, 0]) & (x < boxes[:, 2]) & (y >= boxes[:, 1]) & (y < boxes[:, 3])


def box_classes(points: np.ndarray, detections: list[Detection], dilation: float) -> tuple[str, ...]:
    """The class of the smallest box holding each point ('' for none): a diagnostic."""
    hits = inside(points, detections, dilation)
    if hits.shape[1] == 0:
        return ("",) * len(points)
    areas = np.array([(d.box_xyxy[2] - d.box_xyxy[0]) * (d.box_xyxy[3] - d.box_xyxy[1]) for d in detections])
    masked = np.where(hits, areas, np.inf)
    best = np.argmin(masked, axis=1)
    names = np.array([d.class_name for d in detections] + [""], dtype=object)
    best[~np.isfinite(masked.min(axis=1))] = len(detections)
    return tuple(names[best])


Flow = tuple[np.ndarray, np.ndarray]
"""LK flow of every keypoint of a frame into the previous one: (previous positions (N, 2), ok (N,)).
LK tracks each point on its own, so any subset of it equals LK run on that subset."""


def flow_to_previous(previous: FrameFeatures, current: FrameFeatures, config: RejectionConfig) -> Flow:
    """The flow stage: computed once per frame, it serves every flow-based strategy."""
    return track_to_previous(previous, current, current.keypoints_px, config)


def track_to_previous(
    previous: FrameFeatures, current: FrameFeatures, points: np.ndarray, config: RejectionConfig
) -> tuple[np.ndarray, np.ndarray]:
    """LK flow of current keypoints back into the previous frame: (previous positions, ok)."""
    if len(points) == 0:
        return np.zeros((0, 2), np.float32), np.zeros(0, bool)
    prev, status, _ = cv2.calcOpticalFlowPyrLK(
        current.grey,
        previous.grey,
        points.reshape(-1, 1, 2),
        None,
        winSize=(config.lk_window_px, config.lk_window_px),
        maxLevel=config.lk_levels,
    )
    h, w = previous.grey.shape
    prev = prev.reshape(-1, 2)
    ok = (
        status.ravel().astype(bool)
        & (prev[:, 0] >= 0)
        & (prev[:, 0] < w)
        & (prev[:, 1] >= 0)
        & (prev[:, 1] < h)
    )
    return prev, ok


def classify(
    strategy: str,
    current: FrameFeatures,
    previous: FrameFeatures | None,
    detections: tuple[Detection, ...],
    config: RejectionConfig,
    flow: Flow | None = None,
    memo: dict | None = None,
) -> np.ndarray:
    """A ``Rejection`` code per keypoint of ``current``; ``flow`` is the flow stage when cached.

    ``memo``, one dict per frame and set of boxes kept across calls, lets settings share
    what does not depend on them: the box tests, and the fundamental-matrix RANSAC with its
    epipolar distances for the same points (a sweep decides many settings of one frame; the
    RANSAC is seeded per frame, so its result is a function of its input)."""
    if strategy not in STRATEGIES:
        raise ValueError(f"unknown strategy {strategy!r}; choose one of {', '.join(STRATEGIES)}")
    n = len(current)
    codes = np.full(n, REJECTION_CODES[Rejection.KEPT], dtype=np.int8)
    if strategy == "none" or n == 0:
        return codes
    dets = [d for d in detections if d.confidence >= config.min_confidence]
    box_key = ("inside", config.min_confidence, config.box_dilation_px)
    if memo is not None and box_key in memo:
        hits = memo[box_key]
    else:
        hits = inside(current.keypoints_px, dets, config.box_dilation_px)
        if memo is not None:
            memo[box_key] = hits
    priors = np.array([d.prior for d in dets])
    in_dynamic = hits[:, priors == Prior.DYNAMIC].any(axis=1) if len(dets) else np.zeros(n, bool)
    in_other = hits[:, priors != Prior.DYNAMIC].any(axis=1) if len(dets) else np.zeros(n, bool)
    if strategy == "box_rule":
        codes[in_dynamic & ~in_other] = REJECTION_CODES[Rejection.DYNAMIC_BOX]
        return codes
    codes[in_dynamic] = REJECTION_CODES[Rejection.DYNAMIC_BOX]
    if previous is None:
        return codes
    if strategy == "prior_flow":
        return _prior_flow(codes, current, previous, in_dynamic, hits, priors, config, flow)
    return _epipolar_flow(codes, current, previous, in_dynamic, config, flow, memo)


def _prior_flow(
    codes: np.ndarray,
    current: FrameFeatures,
    previous: FrameFeatures,
    in_dynamic: np.ndarray,
    hits: np.ndarray,
    priors: np.ndarray,
    config: RejectionConfig,
    flow_stage: Flow | None = None,
) -> np.ndarray:
    in_potential = (
        hits[:, priors == Prior.POTENTIAL].any(axis=1) if hits.shape[1] else np.zeros(len(codes), bool)
    )
    q = in_potential & ~in_dynamic
    p = ~in_potential & ~in_dynamic
    if flow_stage is not None:
        prev, ok = flow_stage
    else:  # only P and Q are read: LK on them alone (it tracks each point on its own)
        needed = np.flatnonzero(~in_dynamic)
        prev, ok = np.zeros((len(codes), 2), np.float32), np.zeros(len(codes), bool)
        prev[needed], ok[needed] = track_to_previous(previous, current, current.keypoints_px[needed], config)
    flow = current.keypoints_px - prev
    if not (p & ok).any():
        codes[q] = REJECTION_CODES[Rejection.MOVING_FLOW]  # no camera-flow reference: Q stays unverified
        return codes
    mean = flow[p & ok].mean(axis=0)
    z = max(config.k * float(np.linalg.norm(mean)), config.z_min_px)
    moving = q & (~ok | (np.linalg.norm(flow - mean, axis=1) > z))
    codes[moving] = REJECTION_CODES[Rejection.MOVING_FLOW]
    return codes


def _epipolar_flow(
    codes: np.ndarray,
    current: FrameFeatures,
    previous: FrameFeatures,
    in_dynamic: np.ndarray,
    config: RejectionConfig,
    flow: Flow | None = None,
    memo: dict | None = None,
) -> np.ndarray:
    rest = np.flatnonzero(~in_dynamic)
    if len(rest) < 8:
        return codes
    if flow is not None:
        prev, ok = flow[0][rest], flow[1][rest]
    else:
        prev, ok = track_to_previous(previous, current, current.keypoints_px[rest], config)
    tracked = rest[ok]
    if len(tracked) < 8:
        return codes
    prev_pts = prev[ok]
    key = (tracked.tobytes(), prev_pts.tobytes(), config.fundamental_ransac_px)
    if memo is not None and key in memo:
        distance, magnitude = memo[key]
    else:
        distance, magnitude = _epipolar_geometry(current.keypoints_px[tracked], prev_pts, config)
        if memo is not None:
            memo[key] = (distance, magnitude)
    if distance is not None:
        off_line = distance > config.epsilon_px
        codes[tracked[off_line]] = REJECTION_CODES[Rejection.EPIPOLAR]
        tracked, magnitude = tracked[~off_line], magnitude[~off_line]
    if len(tracked) < 2:
        return codes
    codes[tracked[flow_outliers(magnitude, config)]] = REJECTION_CODES[Rejection.FLOW_OUTLIER]
    return codes


def flow_outliers(magnitude: np.ndarray, config: RejectionConfig) -> np.ndarray:
    """Method 3's flow test: a point is dynamic when |L_i - L_avg| > sigma_factor L_std, or
    > L_thr1 while L_std < L_thr2 (compiled unless ``DEPOTBENCH_KERNELS=numpy``)."""
    if not kernels.compiled():
        return flow_outliers_numpy(magnitude, config)
    from depotbench.slam.kernels import rejection as compiled

    return compiled.flow_outliers(
        np.ascontiguousarray(magnitude, np.float64),
        float(config.sigma_factor),
        float(config.l_thr1_px),
        float(config.l_thr2_px),
    )


def flow_outliers_numpy(magnitude: np.ndarray, config: RejectionConfig) -> np.ndarray:
    deviation = np.abs(magnitude - magnitude.mean())
    std = float(magnitude.std())
    return (deviation > config.sigma_factor * std) | (
        (deviation > config.l_thr1_px) & (std < config.l_thr2_px)
    )


def _epipolar_geometry(
    current_px: np.ndarray, previous_px: np.ndarray, config: RejectionConfig
) -> tuple[np.ndarray | None, np.ndarray]:
    """Each point's distance to its epipolar line under F from RANSAC (None when F fails)
    and its flow magnitude: what method 3's thresholds are then applied to."""
    cur_pts, prev_pts = current_px.astype(np.float64), previous_px.astype(np.float64)
    f, _ = cv2.findFundamentalMat(prev_pts, cur_pts, cv2.FM_RANSAC, config.fundamental_ransac_px, 0.99)
    if f is None or f.shape != (3, 3):
        f = None
    if not kernels.compiled():
        return epipolar_geometry_numpy(f, prev_pts, cur_pts)
    from depotbench.slam.kernels import rejection as compiled

    distance, magnitude = compiled.epipolar_geometry(np.zeros((0, 3)) if f is None else f, prev_pts, cur_pts)
    return (None if f is None else distance), magnitude


def epipolar_geometry_numpy(
    f: np.ndarray | None, prev_pts: np.ndarray, cur_pts: np.ndarray
) -> tuple[np.ndarray | None, np.ndarray]:
    """(distance of each current point to its epipolar line under ``f``, None without one;
    flow magnitude), in NumPy."""
    magnitude = np.linalg.norm(cur_pts - prev_pts, axis=1)
    if f is None:
        return None, magnitude
    lines = np.c_[prev_pts, np.ones(len(prev_pts))] @ f.T
    distance = np.abs(np.sum(lines * np.c_[cur_pts, np.ones(len(cur_pts))], axis=1)) / np.maximum(
        np.hypot(lines[:, 0], lines[:, 1]), 1e-12
    )
    return distance, magnitude
