"""The one camera type: a pinhole in OpenCV's convention with its lens distortion and depth scale.

The simulator writes it into every sequence, the sequence format reads it back, the
built-in tracker projects with it and the external trackers' settings files are written
from it. It imports nothing from the project, so that ``slam`` may depend on it alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-9)
"""OpenCV's default 5 iterations leave ~0.5 px at the corners of a TUM fr1 image; 30 leave < 0.01."""


TUM_DEPTH_SCALE = 5000.0
"""Depth PNG units per metre (TUM RGB-D)."""


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera in the OpenCV convention (pixel centres at integers).

    ``distortion`` holds OpenCV's (k1, k2, p1, p2, k3); generated sequences have
    none, real TUM fr1/fr2 sequences do.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    depth_scale: float = TUM_DEPTH_SCALE

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy", "depth_scale"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"intrinsics {name} must be finite, got {value}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx} fy={self.fy}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if self.depth_scale <= 0:
            raise ValueError(f"depth_scale must be positive, got {self.depth_scale}")
        if len(self.distortion) != 5:
            raise ValueError("distortion must hold (k1, k2, p1, p2, k3)")
        if not all(math.isfinite(k) for k in self.distortion):
            raise ValueError(f"distortion coefficients must be finite, got {self.distortion}")

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64)

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

    @classmethod
    def from_fovy(cls, fovy_deg: float, width: int, height: int) -> Intrinsics:
        """Intrinsics of a MuJoCo camera: square pixels, centre at ((W-1)/2, (H-1)/2)."""
        f = (height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)
        return cls(fx=f, fy=f, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, width=width, height=height)

    def fovy_deg(self) -> float:
        """Vertical field of view that a MuJoCo camera needs to reproduce ``fy``."""
        return math.degrees(2.0 * math.atan((self.height / 2.0) / self.fy))
