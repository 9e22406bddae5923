"""What crosses into and out of SLAM: frames in, poses and diagnostics out."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.detectors.detection import Detection


@dataclass(frozen=True, eq=False)
class Frame:
    """One RGB-D frame with its detections. Depth is z-depth in metres, 0 = no reading."""

    timestamp_s: float
    rgb: np.ndarray
    depth_m: np.ndarray
    camera: Intrinsics
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
