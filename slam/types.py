"""What crosses into and out of SLAM: frames in, poses and diagnostics out."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import cv2
import numpy as np
from depotbench.detectors.detection import Detection

UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-9)
"""OpenCV's default 5 iterations leave ~0.5 px at the corners of a TUM fr1 image; 30 leave < 0.01."""


@dataclass(frozen=True)
class PinholeCamera:
    """Pinhole intrinsics plus OpenCV's (k1, k2, p1, p2, k3) lens distortion (TUM fr1/fr2 have it)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    @property
    def distorted(self) -> bool:
        return any(self.distortion)

    def undistort(self, points_px: np.ndarray) -> np.ndarray:
        """Where image points (N, 2) would lie through a distortion-free lens (ORB-SLAM's mvKeysUn)."""
        if not self.distorted or len(points_px) == 0:
            return np.asarray(points_px, dtype=np.float64)
        points = np.asarray(points_px, dtype=np.float64).reshape(-1, 1, 2)
        distortion = np.array(self.distortion)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4; 5 took the criteria into undistortPoints
            undistorted = cv2.undistortPointsIter(
                points, self.matrix, distortion, None, self.matrix, UNDISTORT_CRITERIA
            )
        else:
            undistorted = cv2.undistortPoints(
                points, self.matrix, distortion, R=None, P=self.matrix, criteria=UNDISTORT_CRITERIA
            )
        return undistorted.reshape(-1, 2)


@dataclass(frozen=True, eq=False)
class Frame:
    """One RGB-D frame with its detections. Depth is z-depth in metres, 0 = no reading."""

    timestamp_s: float
    rgb: np.ndarray
    depth_m: np.ndarray
    camera: PinholeCamera
    detections: tuple[Detection, ...] = ()

    def __post_init__(self) -> None:
        h, w = self.camera.height, self.camera.width
        if self.rgb.shape[:2] != (h, w) or self.depth_m.shape != (h, w):
            raise ValueError(
                f"frame {self.timestamp_s:.6f}: images must be {w}x{h}, got RGB "
                f"{self.rgb.shape[1]}x{self.rgb.shape[0]}, depth "
                f"{self.depth_m.shape[1]}x{self.depth_m.shape[0]}"
            )


class TrackingState(StrEnum):
    NOT_INITIALIZED = "not_initialized"
    OK = "ok"
    RELOCALIZED = "relocalized"
    LOST = "lost"


class Rejection(StrEnum):
    """Why a keypoint was not used (``kept`` when it was)."""

    KEPT = "kept"
    DYNAMIC_BOX = "dynamic_box"
    MOVING_FLOW = "moving_flow"
    EPIPOLAR = "epipolar"
    FLOW_OUTLIER = "flow_outlier"


REJECTION_CODES = {r: i for i, r in enumerate(Rejection)}


@dataclass(frozen=True, eq=False)
class FrameDiagnostics:
    """Per-keypoint and per-stage facts of one tracked frame."""

    timestamp_s: float
    state: TrackingState
    keypoints_px: np.ndarray
    keypoint_classes: tuple[str, ...]
    rejection: np.ndarray
    """Codes of ``Rejection`` per keypoint (``REJECTION_CODES``)."""
    inlier: np.ndarray
    """True where the keypoint ended an inlier of the final pose estimate."""
    stage_ms: dict[str, float] = field(default_factory=dict)
    keyframe: bool = False


@dataclass(frozen=True, eq=False)
class FrameResult:
    timestamp_s: float
    world_from_camera: np.ndarray | None
    """None while not initialised or lost."""
    state: TrackingState
    diagnostics: FrameDiagnostics
