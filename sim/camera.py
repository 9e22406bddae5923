"""The TUM cameras' intrinsics, and the ORB-SLAM2/3 settings file.

The settings file is written so that ORB-SLAM2's and ORB-SLAM3's ``rgbd_tum``
binaries run on a generated sequence as they run on a real TUM one. A camera a user
gives for a real folder (``--camera FILE``) is read from the same kind of file: the
ORB-SLAM2 / old ORB-SLAM3 format that every sequence's camera.yaml is written in, or
ORB-SLAM3's ``File.version: "1.0"`` format (``Camera1.fx``, ``RGBD.DepthMapFactor``),
both through OpenCV's FileStorage, the reader ORB-SLAM itself uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from depotbench.core.camera import (
    DEPTH_FACTOR_RANGE,
    DISTORTION_LIMITS,
    DISTORTION_NAMES,
    FOCAL_RANGE_PX,
    CameraOverride,
    CameraProvenance,
    CameraSource,
    Intrinsics,
)
from depotbench.core.errors import FileError, SequenceFormatError
from depotbench.core.files import MAX_SPEC_BYTES, read_text

MAX_IMAGE_SIDE = 16384
"""Largest image width or height a settings file may declare."""
PLAUSIBLE = {
    "Camera.fx": FOCAL_RANGE_PX,
    "Camera.fy": FOCAL_RANGE_PX,
    "Camera.cx": (-1e5, 1e5),
    "Camera.cy": (-1e5, 1e5),
    "DepthMapFactor": DEPTH_FACTOR_RANGE,
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


def tum_camera_for(folder: Path) -> tuple[Intrinsics, CameraProvenance]:
    """TUM's calibration for a folder named like ``rgbd_dataset_freiburg2_desk``, and why.

    Falls back to the ROS default, as TUM's own tools do for unknown sensors. Either is a
    guess from the name, not this folder's calibration: a run says which it used.
    """
    name = folder.resolve().name
    for key, intrinsics in TUM_FREIBURG.items():
        if key in name.lower():
            why = f"TUM's {key} calibration, as the folder name {name!r} holds {key!r}"
            return intrinsics, CameraProvenance(CameraSource.TUM, why, CameraSource.TUM)
    why = (
        f"the ROS/Kinect default (fx=fy=525, cx=319.5, cy=239.5, no distortion), "
        f"as the folder name {name!r} names no TUM sensor (freiburg1/2/3)"
    )
    return TUM_DEFAULT, CameraProvenance(CameraSource.DEFAULT, why, CameraSource.DEFAULT)


def tum_intrinsics_for(folder: Path) -> Intrinsics:
    """The intrinsics of ``tum_camera_for``."""
    return tum_camera_for(folder)[0]


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


def _check_nesting(path: Path, text: str, error: type[FileError]) -> None:
    """Refuse deep nesting before OpenCV's recursive parser sees it (it overflows the C stack)."""
    codes = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    opens = np.isin(codes, (ord("["), ord("{"))).astype(np.int32)
    closes = np.isin(codes, (ord("]"), ord("}"))).astype(np.int32)
    depth = int(np.max(np.cumsum(opens - closes), initial=0))
    indent = max((len(line) - len(line.lstrip(" \t")) for line in text.splitlines()), default=0)
    if depth > MAX_SETTINGS_NESTING or indent > 2 * MAX_SETTINGS_NESTING:
        raise error(path, None, f"nested more than {MAX_SETTINGS_NESTING} levels deep")


@dataclass(frozen=True)
class _Settings:
    """An OpenCV YAML settings file's nodes, read once (``_read_settings``)."""

    path: Path
    numbers: dict[str, float]
    texts: dict[str, str]
    error: type[FileError]

    def number(self, key: str, required: bool = True) -> float | None:
        if key in self.numbers:
            return self.numbers[key]
        if key in self.texts:
            raise self.error(self.path, None, f"{key} must be a number, got {self.texts[key]!r}")
        if required:
            raise self.error(self.path, None, f"missing key {key}")
        return None


def _read_settings(path: Path, keys: tuple[str, ...], error: type[FileError]) -> _Settings:
    """The ``keys`` of an OpenCV YAML file (``%YAML:1.0``), numbers apart from text; a
    node that is neither (a sequence, a mapping) is refused naming the key."""
    try:
        text = read_text(path, MAX_SPEC_BYTES, "settings file")
    except FileError as exc:
        raise error(path, None, exc.problem) from None
    _check_nesting(path, text, error)
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:  # the binding wraps some parse errors in SystemError
        cause = exc.__cause__ if isinstance(exc, SystemError) and exc.__cause__ else exc
        problem = (getattr(cause, "err", None) or str(cause)).strip().splitlines()[0]
        raise error(path, None, f"not a readable OpenCV YAML file: {problem}") from None
    if not storage.isOpened():
        raise error(path, None, "not an OpenCV YAML file (it must start with %YAML:1.0)")
    numbers: dict[str, float] = {}
    texts: dict[str, str] = {}
    try:
        for key in keys:
            node = storage.getNode(key)
            if node.empty():
                continue
            if node.isReal() or node.isInt():
                numbers[key] = float(node.real())
            elif node.isString():
                texts[key] = node.string()
            else:
                raise error(path, None, f"{key} must be a number, not a list or a mapping")
    finally:
        storage.release()
    return _Settings(path, numbers, texts, error)


def _check_size(settings: _Settings) -> tuple[int, int]:
    size = []
    for key in ("Camera.width", "Camera.height"):
        value = settings.number(key)
        if not (value.is_integer() and 1 <= value <= MAX_IMAGE_SIDE):
            raise settings.error(settings.path, None, f"{key} must be a whole number in 1..{MAX_IMAGE_SIDE}")
        size.append(int(value))
    return size[0], size[1]


def _check_plausible(settings: _Settings, key: str, value: float | None, bounds: str) -> None:
    low, high = PLAUSIBLE[bounds]
    if value is not None and not low <= value <= high:
        raise settings.error(
            settings.path, None, f"{key} = {value:g} is outside the plausible {low:g}..{high:g}"
        )


def read_orbslam_yaml(path: Path) -> tuple[Intrinsics, float]:
    """Intrinsics and frame rate from an ORB-SLAM settings file (OpenCV YAML)."""
    keys = (*_REQUIRED_KEYS, *(f"Camera.{k}" for k in DISTORTION_NAMES), "Camera.fps")
    settings = _read_settings(path, keys, SequenceFormatError)
    values = {key: settings.number(key, key in _REQUIRED_KEYS) for key in keys}
    width, height = _check_size(settings)
    for key in PLAUSIBLE:
        _check_plausible(settings, key, values[key], key)
    fps = values["Camera.fps"] if values["Camera.fps"] is not None else 30.0
    try:
        intrinsics = Intrinsics(
            fx=values["Camera.fx"],
            fy=values["Camera.fy"],
            cx=values["Camera.cx"],
            cy=values["Camera.cy"],
            width=width,
            height=height,
            distortion=tuple(values[f"Camera.{k}"] or 0.0 for k in DISTORTION_NAMES),
            depth_scale=values["DepthMapFactor"],
        )
    except ValueError as exc:
        raise SequenceFormatError(path, None, str(exc)) from None
    return intrinsics, fps


NEW_FORMAT = "1.0"
"""ORB-SLAM3's ``File.version`` of its second settings format (``Camera1.fx``); a file
without it is read in the first (``Camera.fx``), as ORB-SLAM3's System.cc decides."""
CAMERA_TYPES = ("PinHole",)
"""``Camera.type`` values taken: a pinhole with OpenCV's k1 k2 p1 p2 k3, the bench's camera
(ORB-SLAM3's KannalaBrandt8 fisheye and stereo Rectified are other models)."""


def read_camera_file(path: Path) -> CameraOverride:
    """The camera of an ORB-SLAM settings file a user gives (``--camera FILE``): intrinsics,
    distortion, image size and depth factor; FileError names the file and the key.

    Both ORB-SLAM settings formats are read, as their users have one or the other: the first
    (``Camera.fx`` ... ``DepthMapFactor``; ORB-SLAM2, the bench's own camera.yaml) and
    ORB-SLAM3's ``File.version: "1.0"`` (``Camera1.fx`` ... ``RGBD.DepthMapFactor``).
    The depth factor is required, as ORB-SLAM's RGB-D mode requires it: a guessed one scales
    every depth reading.
    """
    try:
        head = _read_settings(path, ("File.version",), FileError)
    except FileNotFoundError:
        raise FileError(path, None, "no such camera file") from None
    version = head.texts.get("File.version")
    if version is None and "File.version" in head.numbers:
        version = f"{head.numbers['File.version']:g}"
    if version is not None and version != NEW_FORMAT:
        raise FileError(path, None, f'File.version {version!r} is not an ORB-SLAM3 settings format ("1.0")')
    cam, depth_key = ("Camera1", "RGBD.DepthMapFactor") if version else ("Camera", "DepthMapFactor")
    pinhole_keys = tuple(f"{cam}.{k}" for k in ("fx", "fy", "cx", "cy"))
    distortion_keys = tuple(f"{cam}.{k}" for k in DISTORTION_NAMES)
    resize = ("Camera.newWidth", "Camera.newHeight")
    keys = (
        *pinhole_keys,
        *distortion_keys,
        "Camera.width",
        "Camera.height",
        depth_key,
        "Camera.type",
        *resize,
    )
    settings = _read_settings(path, keys, FileError)
    kind = settings.texts.get("Camera.type", settings.numbers.get("Camera.type", CAMERA_TYPES[0]))
    if kind not in CAMERA_TYPES:
        raise FileError(
            path,
            None,
            f"Camera.type {kind!r} is not taken: the bench's camera is a PinHole with k1 k2 p1 p2 k3",
        )
    for key in resize:
        if key in settings.numbers or key in settings.texts:
            raise FileError(
                path, None, f"{key}: resizing is not taken; give the calibration of the images as stored"
            )
    pinhole = tuple(settings.number(key) for key in pinhole_keys)
    for key, value in zip(pinhole_keys, pinhole, strict=True):
        _check_plausible(settings, key, value, "Camera." + key.split(".")[1])
    given = [settings.number(key, required=False) for key in distortion_keys]
    for key, value in zip(distortion_keys, given, strict=True):
        if value is not None and not math.isfinite(value):
            raise FileError(path, None, f"{key} must be a finite number, got {value}")
        limit = DISTORTION_LIMITS[key.split(".")[1]]
        if value is not None and abs(value) > limit:
            raise FileError(path, None, f"{key} = {value:g} is outside the plausible {-limit:g}..{limit:g}")
    # A key left out is 0, as ORB-SLAM2 reads it (OpenCV's empty node) and as ORB-SLAM3 leaves k3.
    distortion = tuple(value or 0.0 for value in given) if any(v is not None for v in given) else None
    depth_factor = settings.number(depth_key)
    _check_plausible(settings, depth_key, depth_factor, "DepthMapFactor")
    try:
        return CameraOverride(
            pinhole, distortion, depth_factor, _check_size(settings), CameraSource.FILE, str(path)
        )
    except ValueError as exc:  # checked above key by key; this names the file all the same
        raise FileError(path, None, str(exc).removeprefix(f"{path}: ")) from None
