"""The one camera type: a pinhole in OpenCV's convention with its lens distortion and depth scale.

The simulator writes it into every sequence, the sequence format reads it back, the
built-in tracker projects with it and the external trackers' settings files are written
from it. It imports nothing from the project, so that ``slam`` may depend on it alone.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-9)
"""OpenCV's default 5 iterations leave ~0.5 px at the corners of a TUM fr1 image; 30 leave < 0.01."""


TUM_DEPTH_SCALE = 5000.0
"""Depth PNG units per metre (TUM RGB-D)."""
FOCAL_RANGE_PX = (1.0, 1e5)
DEPTH_FACTOR_RANGE = (1e-3, 1e6)
"""Focal lengths and depth factors outside which a given camera is a mistake (a 640-pixel image
at fx = 1 sees 175 degrees); they keep the arithmetic finite."""


DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3")
"""OpenCV's radial-tangential coefficients, in the order ``Intrinsics.distortion`` holds them."""
DISTORTION_LIMITS = {"k1": 10.0, "k2": 10.0, "p1": 1.0, "p2": 1.0, "k3": 10.0}
"""Largest magnitude of each given coefficient: calibrated lenses in this model have radial
k of a few at most (TUM fr1: k1 0.26, k2 -0.95, k3 1.16) and tangential p of hundredths. At
an image corner (r^2 about 0.6 at fx 525) k = 10 already scales a point's radius by 7 and
p = 1 moves it by hundreds of pixels; 1e30 gave an ATE of 4e12 m and exit 0."""


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

    @property
    def distortion_by_name(self) -> dict[str, float]:
        """The coefficients by OpenCV's names, as settings templates and metrics.json give them."""
        return dict(zip(DISTORTION_NAMES, self.distortion, strict=True))

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


class CameraSource(enum.Enum):
    """Where a sequence's camera came from (metrics.json's ``camera.source``)."""

    SEQUENCE = "sequence"
    """The folder's own camera.yaml (every generated sequence has one)."""
    FILE = "file"
    """A settings file the user gave (``--camera FILE``)."""
    FLAGS = "flags"
    """Numbers the user gave (``--intrinsics``, ``--distortion``, ``--depth-factor``)."""
    GIVEN = "given"
    """A camera given in Python (``depotbench.api.run(camera=...)``)."""
    TUM = "tum"
    """TUM's published calibration, chosen by the folder's name (freiburg1/2/3)."""
    DEFAULT = "default"
    """The ROS/Kinect default: the folder names no TUM sensor and no camera was given."""


FALLBACKS = (CameraSource.TUM, CameraSource.DEFAULT)
"""Sources that are a guess, not a calibration of this folder: a run warns that it used one."""


@dataclass(frozen=True)
class CameraOverride:
    """A camera given for a real TUM-layout folder, replacing what the folder's name suggests.

    Each part may be left out: ``pinhole`` (fx, fy, cx, cy) replaces the calibration, with
    ``distortion`` (k1, k2, p1, p2, k3; none when left out, as a calibration's distortion
    belongs with its focal lengths) and ``size`` (width, height; the images' own when left
    out); ``depth_factor`` (depth PNG units per metre, TUM's 5000) may be given alone.
    ``source`` and ``origin`` (the file, or the flags) say where it came from, for
    metrics.json and for messages.
    """

    pinhole: tuple[float, float, float, float] | None = None
    distortion: tuple[float, float, float, float, float] | None = None
    depth_factor: float | None = None
    size: tuple[int, int] | None = None
    source: CameraSource = CameraSource.GIVEN
    origin: str = "camera"

    def __post_init__(self) -> None:
        """Each number checked where it is given, so a message names the part that is wrong."""
        if self.pinhole is None and self.distortion is None and self.depth_factor is None:
            raise ValueError(f"{self.origin}: give the intrinsics (fx fy cx cy) or the depth factor")
        if self.pinhole is not None:
            if len(self.pinhole) != 4:
                given = len(self.pinhole)
                raise ValueError(f"{self.origin}: intrinsics are fx fy cx cy, got {given} numbers")
            for name, value in zip(("fx", "fy", "cx", "cy"), self.pinhole, strict=True):
                _finite(self.origin, name, value)
            for name, value in zip(("fx", "fy"), self.pinhole[:2], strict=True):
                _within(self.origin, name, value, FOCAL_RANGE_PX, "px")
        elif self.distortion is not None or self.size is not None:
            raise ValueError(
                f"{self.origin}: distortion and image size belong with the intrinsics; give fx fy cx cy too"
            )
        if self.distortion is not None:
            if len(self.distortion) != 5:
                raise ValueError(
                    f"{self.origin}: distortion is k1 k2 p1 p2 k3, got {len(self.distortion)} numbers"
                )
            for name, value in zip(DISTORTION_NAMES, self.distortion, strict=True):
                _finite(self.origin, name, value)
                if abs(value) > DISTORTION_LIMITS[name]:
                    limit = DISTORTION_LIMITS[name]
                    raise ValueError(
                        f"{self.origin}: distortion {name} = {value:g} is outside the plausible "
                        f"{-limit:g}..{limit:g} of a real lens"
                    )
        if self.depth_factor is not None:
            _finite(self.origin, "depth factor", self.depth_factor)
            unit = "per metre (TUM: 5000)"
            _within(self.origin, "depth factor", self.depth_factor, DEPTH_FACTOR_RANGE, unit)
        if self.size is not None and not all(isinstance(n, int) and n > 0 for n in self.size):
            raise ValueError(f"{self.origin}: the image size must be two whole numbers > 0, got {self.size}")

    @classmethod
    def of(
        cls, intrinsics: Intrinsics, source: CameraSource = CameraSource.GIVEN, origin: str = "camera"
    ) -> CameraOverride:
        """A whole camera, as given."""
        k = intrinsics
        return cls((k.fx, k.fy, k.cx, k.cy), k.distortion, k.depth_scale, (k.width, k.height), source, origin)

    def applied(self, base: Intrinsics, image_size: tuple[int, int]) -> Intrinsics:
        """``base`` (the folder's camera.yaml or its fallback) with what this gives replaced; the
        image size is this camera's, or the images' (``image_size``) where it gives none."""
        depth_factor = base.depth_scale if self.depth_factor is None else self.depth_factor
        if self.pinhole is None:
            return replace(base, depth_scale=depth_factor)
        width, height = self.size or image_size
        fx, fy, cx, cy = self.pinhole
        distortion = self.distortion or (0.0, 0.0, 0.0, 0.0, 0.0)
        return Intrinsics(fx, fy, cx, cy, width, height, distortion, depth_factor)


def _finite(origin: str, name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{origin}: {name} must be a finite number, got {value!r}")


def _within(origin: str, name: str, value: float, bounds: tuple[float, float], unit: str) -> None:
    low, high = bounds
    if not value > 0:
        raise ValueError(f"{origin}: {name} must be > 0, got {value:g}")
    if not low <= value <= high:
        raise ValueError(f"{origin}: {name} = {value:g} is outside the plausible {low:g}..{high:g} {unit}")


@dataclass(frozen=True)
class CameraProvenance:
    """Where a sequence's camera came from: the intrinsics (with distortion) and, apart, the
    depth factor (``--depth-factor`` alone keeps the folder's calibration)."""

    source: CameraSource
    detail: str
    """The file, the flags, or why a fallback was chosen (the folder name that names a sensor)."""
    depth_factor_source: CameraSource

    @property
    def fallback(self) -> bool:
        return self.source in FALLBACKS


def camera_json(intrinsics: Intrinsics, provenance: CameraProvenance) -> dict:
    """The camera a run used, as metrics.json records it."""
    k = intrinsics
    return {
        "fx": k.fx,
        "fy": k.fy,
        "cx": k.cx,
        "cy": k.cy,
        "width": k.width,
        "height": k.height,
        "distortion": k.distortion_by_name,
        "depth_factor": k.depth_scale,
        "source": provenance.source.value,
        "detail": provenance.detail,
        "depth_factor_source": provenance.depth_factor_source.value,
    }
