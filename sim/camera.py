"""The TUM cameras' intrinsics, and the ORB-SLAM2/3 settings file.

The settings file is written so that ORB-SLAM2's and ORB-SLAM3's ``rgbd_tum``
binaries run on a generated sequence as they run on a real TUM one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.core.errors import FileError, SequenceFormatError
from depotbench.core.files import MAX_SPEC_BYTES, read_text

MAX_IMAGE_SIDE = 16384
"""Largest image width or height a settings file may declare."""
PLAUSIBLE = {
    "Camera.fx": (1.0, 1e5),
    "Camera.fy": (1.0, 1e5),
    "Camera.cx": (-1e5, 1e5),
    "Camera.cy": (-1e5, 1e5),
    "DepthMapFactor": (1e-3, 1e6),
    "Camera.fps": (0.1, 10_000.0),
}
"""Ranges outside which a settings file's number is a mistake (they keep the arithmetic finite)."""
TUM_DEFAULT = Intrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
"""The ROS/Kinect default intrinsics used by TUM's tools and by generated sequences."""

TUM_FREIBURG: dict[str, Intrinsics] = {
    "freiburg1": Intrinsics(517.3, 516.5, 318.6, 255.3, 640, 480, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "freiburg2": Intrinsics(
        520.9, 521.0, 325.1, 249.7, 640, 480, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)
    ),
    "freiburg3": Intrinsics(535.4, 539.2, 320.1, 247.6, 640, 480),
}
"""Calibrated intrinsics of the TUM RGB-D sensors, as published with the benchmark."""


def tum_intrinsics_for(folder: Path) -> Intrinsics:
    """TUM's calibration for a folder named like ``rgbd_dataset_freiburg2_desk``.

    Falls back to the ROS default, as TUM's own tools do for unknown sensors.
    """
    name = folder.resolve().name.lower()
    for key, intrinsics in TUM_FREIBURG.items():
        if key in name:
            return intrinsics
    return TUM_DEFAULT


@dataclass(frozen=True)
class OrbSlamSettings:
    """Non-camera fields that ORB-SLAM2/3 require in an RGB-D settings file."""

    fps: float = 30.0
    baseline_times_fx: float = 40.0
    close_depth_threshold: float = 40.0
    n_features: int = 1000
    scale_factor: float = 1.2
    n_levels: int = 8
    ini_th_fast: int = 20
    min_th_fast: int = 7
    viewer: dict[str, float] = field(
        default_factory=lambda: {
            "KeyFrameSize": 0.05,
            "KeyFrameLineWidth": 1.0,
            "GraphLineWidth": 0.9,
            "PointSize": 2.0,
            "CameraSize": 0.08,
            "CameraLineWidth": 3.0,
            "ViewpointX": 0.0,
            "ViewpointY": -0.7,
            "ViewpointZ": -1.8,
            "ViewpointF": 500.0,
        }
    )


def _real(value: float) -> str:
    """A number OpenCV's YAML reads as a real: ORB-SLAM3 refuses ``525`` where it wants a real
    (it checks ``isReal()``), so a whole number is written ``525.0``."""
    text = f"{value:.9g}"
    return text if any(c in text for c in ".eEn") else f"{text}.0"


def orbslam_yaml(intrinsics: Intrinsics, settings: OrbSlamSettings | None = None) -> str:
    """The camera as an ORB-SLAM2/3 (old-format) RGB-D settings file."""
    s = settings or OrbSlamSettings()
    k1, k2, p1, p2, k3 = intrinsics.distortion
    lines = [
        "%YAML:1.0",
        "# Written by depotbench. ORB-SLAM2/3 RGB-D settings (TUM style).",
        'Camera.type: "PinHole"',
        f"Camera.fx: {_real(intrinsics.fx)}",
        f"Camera.fy: {_real(intrinsics.fy)}",
        f"Camera.cx: {_real(intrinsics.cx)}",
        f"Camera.cy: {_real(intrinsics.cy)}",
        f"Camera.k1: {_real(k1)}",
        f"Camera.k2: {_real(k2)}",
        f"Camera.p1: {_real(p1)}",
        f"Camera.p2: {_real(p2)}",
        f"Camera.k3: {_real(k3)}",
        f"Camera.width: {intrinsics.width}",
        f"Camera.height: {intrinsics.height}",
        f"Camera.fps: {_real(s.fps)}",
        f"Camera.bf: {_real(s.baseline_times_fx)}",
        "Camera.RGB: 1",
        f"ThDepth: {_real(s.close_depth_threshold)}",
        f"DepthMapFactor: {_real(intrinsics.depth_scale)}",
        f"ORBextractor.nFeatures: {s.n_features}",
        f"ORBextractor.scaleFactor: {_real(s.scale_factor)}",
        f"ORBextractor.nLevels: {s.n_levels}",
        f"ORBextractor.iniThFAST: {s.ini_th_fast}",
        f"ORBextractor.minThFAST: {s.min_th_fast}",
    ]
    lines += [f"Viewer.{key}: {_real(value)}" for key, value in s.viewer.items()]
    return "\n".join(lines) + "\n"


_REQUIRED_KEYS = (
    "Camera.fx",
    "Camera.fy",
    "Camera.cx",
    "Camera.cy",
    "Camera.width",
    "Camera.height",
    "DepthMapFactor",
)


MAX_SETTINGS_NESTING = 16
"""Bracket depth and indentation (in levels of two spaces) a settings file may have."""


def _check_nesting(path: Path, text: str) -> None:
    """Refuse deep nesting before OpenCV's recursive parser sees it (it overflows the C stack)."""
    codes = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    opens = np.isin(codes, (ord("["), ord("{"))).astype(np.int32)
    closes = np.isin(codes, (ord("]"), ord("}"))).astype(np.int32)
    depth = int(np.max(np.cumsum(opens - closes), initial=0))
    indent = max((len(line) - len(line.lstrip(" \t")) for line in text.splitlines()), default=0)
    if depth > MAX_SETTINGS_NESTING or indent > 2 * MAX_SETTINGS_NESTING:
        raise SequenceFormatError(path, None, f"nested more than {MAX_SETTINGS_NESTING} levels deep")


def read_orbslam_yaml(path: Path) -> tuple[Intrinsics, float]:
    """Intrinsics and frame rate from an ORB-SLAM settings file (OpenCV YAML)."""
    try:
        text = read_text(path, MAX_SPEC_BYTES, "settings file")
    except FileError as exc:
        raise SequenceFormatError(path, None, exc.problem) from None
    _check_nesting(path, text)
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:  # the binding wraps some parse errors in SystemError
        cause = exc.__cause__ if isinstance(exc, SystemError) and exc.__cause__ else exc
        problem = (getattr(cause, "err", None) or str(cause)).strip().splitlines()[0]
        raise SequenceFormatError(path, None, f"not a readable OpenCV YAML file: {problem}") from None
    if not storage.isOpened():
        raise SequenceFormatError(path, None, "not an OpenCV YAML file (it must start with %YAML:1.0)")
    try:
        values: dict[str, float] = {}
        for key in (
            *_REQUIRED_KEYS,
            "Camera.k1",
            "Camera.k2",
            "Camera.p1",
            "Camera.p2",
            "Camera.k3",
            "Camera.fps",
        ):
            node = storage.getNode(key)
            if node.empty():
                if key in _REQUIRED_KEYS:
                    raise SequenceFormatError(path, None, f"missing key {key}")
                continue
            if not node.isReal() and not node.isInt():
                raise SequenceFormatError(path, None, f"{key} must be a number")
            values[key] = float(node.real())
    finally:
        storage.release()
    for key in ("Camera.width", "Camera.height"):
        if not (values[key].is_integer() and 1 <= values[key] <= MAX_IMAGE_SIDE):
            raise SequenceFormatError(path, None, f"{key} must be a whole number in 1..{MAX_IMAGE_SIDE}")
    for key, (low, high) in PLAUSIBLE.items():
        if key in values and not low <= values[key] <= high:
            raise SequenceFormatError(
                path, None, f"{key} = {values[key]:g} is outside the plausible {low:g}..{high:g}"
            )
    fps = values.get("Camera.fps", 30.0)
    if not (math.isfinite(fps) and fps > 0):
        raise SequenceFormatError(path, None, f"Camera.fps must be a positive number, got {fps}")
    try:
        intrinsics = Intrinsics(
            fx=values["Camera.fx"],
            fy=values["Camera.fy"],
            cx=values["Camera.cx"],
            cy=values["Camera.cy"],
            width=int(values["Camera.width"]),
            height=int(values["Camera.height"]),
            distortion=tuple(values.get(f"Camera.{k}", 0.0) for k in ("k1", "k2", "p1", "p2", "k3")),
            depth_scale=values["DepthMapFactor"],
        )
    except ValueError as exc:
        raise SequenceFormatError(path, None, str(exc)) from None
    return intrinsics, fps
