"""The dense map of the "YOLOv5s-MobileNetV3 box rule" method: keyframe depth as a coloured point cloud.

Each keyframe's valid depth is back-projected (through the lens model, distortion included),
moved into the world by the keyframe's pose and merged into a voxel grid: one point per occupied
voxel, the mean position and mean colour of all that fell in it, so memory grows with the
occupied voxels, not with the keyframes.

What a keyframe leaves out (``exclusion_mask``) follows the run's own rejection decisions,
keypoint by keypoint, so each strategy's map differs as its decisions do:

* a keypoint rejected for lying in a dynamic box (``dynamic_box``) takes out the pixels of every
  confident dynamic box that holds it (the same inside test as the rejection, over pixel
  positions; boxes grown by ``box_dilation_px``). Under ``box_rule``, which keeps a point that
  is also inside a static or potential box, the pixels inside those boxes stay in, as their
  keypoints did. A dynamic box with no rejected keypoint inside stays in the map;
* a keypoint rejected by a flow or epipolar test (``moving_flow``, ``epipolar``,
  ``flow_outlier``) takes out a disk of radius ``keypoint_radius_px`` = 15 px around it
  (pixels with (u - x)^2 + (v - y)^2 <= r^2): the half-side of ORB's 31x31 descriptor patch,
  the image area that made the decision;
* ``none`` rejects nothing and leaves nothing out; ``box_rule`` leaves out boxes only;
  ``prior_flow`` its dynamic boxes (set Z) and disks round its moving Q points;
  ``box_epipolar_flow`` the union of its boxes and its disks.

Pixel (u, v) sits at integer coordinates, where a keypoint found on it would (OpenCV's
convention, pixel centres at integers), so a box (x0, y0, x1, y1) holds the pixels with
x0 <= u < x1 and y0 <= v < y1: (x1 - x0)(y1 - y0) of them for an integer box.
"""

from __future__ import annotations

import math
import os
import secrets
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.detectors.detection import Detection, Prior
from depotbench.slam.config import ConfigError, RejectionConfig
from depotbench.slam.rejection import STRATEGIES, inside
from depotbench.slam.types import REJECTION_CODES, FrameDiagnostics, Rejection

FLOW_REJECTIONS = (Rejection.MOVING_FLOW, Rejection.EPIPOLAR, Rejection.FLOW_OUTLIER)
"""Rejections by a flow or epipolar test: they leave out a disk round the keypoint."""

ALLOWED_REJECTIONS: dict[str, frozenset[Rejection]] = {
    "none": frozenset({Rejection.KEPT}),
    "box_rule": frozenset({Rejection.KEPT, Rejection.DYNAMIC_BOX}),
    "prior_flow": frozenset({Rejection.KEPT, Rejection.DYNAMIC_BOX, Rejection.MOVING_FLOW}),
    "box_epipolar_flow": frozenset(
        {Rejection.KEPT, Rejection.DYNAMIC_BOX, Rejection.EPIPOLAR, Rejection.FLOW_OUTLIER}
    ),
}
"""The codes each strategy can give (slam/rejection.py): others mean diagnostics of another run."""

_KEY_BITS = 21
_KEY_OFFSET = 1 << (_KEY_BITS - 1)
_KEY_MASK = (1 << _KEY_BITS) - 1


@dataclass(frozen=True)
class DenseMapConfig:
    voxel_m: float = 0.02
    """2 cm: a Kinect-class sensor's depth noise at about 3 m (Khoshelham & Elberink 2012), so one
    voxel merges repeated readings of one surface patch and keeps the detail the sensor resolves."""
    min_depth_m: float = 0.1
    """Readings nearer than this are left out (the tracker's own min_depth_m)."""
    max_depth_m: float = 5.0
    """Readings farther than this are left out: a Kinect's specified range, where its error reaches 4 cm."""
    keypoint_radius_px: float = 15.0
    """Radius of the disk a flow- or epipolar-rejected keypoint leaves out: half ORB's 31 px patch."""
    box_dilation_px: float = 0.0
    """A dynamic box that rejected a keypoint leaves out its pixels grown by this much on every side
    (0: the box as the detector drew it, as the rejection's own default)."""

    def __post_init__(self) -> None:
        limits = {
            "voxel_m": (1e-4, 10.0),
            "min_depth_m": (0.0, 100.0),
            "max_depth_m": (0.01, 1000.0),
            "keypoint_radius_px": (0.0, 1000.0),
            "box_dilation_px": (0.0, 1000.0),
        }
        for name, (low, high) in limits.items():
            value = getattr(self, name)
            if not (math.isfinite(value) and low <= value <= high):
                raise ConfigError(f"{name} = {value} is out of range [{low}, {high}]")
        if self.min_depth_m >= self.max_depth_m:
            raise ConfigError(
                f"min_depth_m = {self.min_depth_m} must be below max_depth_m = {self.max_depth_m}"
            )


def _box_slices(box: tuple[float, float, float, float], dilation: float, width: int, height: int):
    """The pixels with x0 - d <= u < x1 + d and y0 - d <= v < y1 + d, clipped to the image."""
    x0, y0, x1, y1 = box
    u0, u1 = (min(max(math.ceil(x), 0), width) for x in (x0 - dilation, x1 + dilation))
    v0, v1 = (min(max(math.ceil(y), 0), height) for y in (y0 - dilation, y1 + dilation))
    return slice(v0, v1), slice(u0, u1)


def _disk(mask: np.ndarray, x: float, y: float, r: float) -> None:
    """Set the pixels with (u - x)^2 + (v - y)^2 <= r^2."""
    h, w = mask.shape
    rows = slice(min(max(math.ceil(y - r), 0), h), min(max(math.floor(y + r) + 1, 0), h))
    cols = slice(min(max(math.ceil(x - r), 0), w), min(max(math.floor(x + r) + 1, 0), w))
    v, u = np.ogrid[rows, cols]
    mask[rows, cols] |= (u - x) ** 2 + (v - y) ** 2 <= r * r


def exclusion_mask(
    strategy: str,
    diagnostics: FrameDiagnostics,
    detections: Sequence[Detection],
    camera: Intrinsics,
    config: DenseMapConfig | None = None,
    rejection: RejectionConfig | None = None,
) -> np.ndarray:
    """(H, W) bool: the pixels this keyframe leaves out of the dense map (the module's rule).

    ``diagnostics`` and ``detections`` are the keyframe's as tracking saw them; ``rejection``
    is the run's rejection settings (which boxes count, how far the inside test reached)."""
    config = config or DenseMapConfig()
    rejection = rejection or RejectionConfig()
    if strategy not in STRATEGIES:
        raise ValueError(f"unknown strategy {strategy!r}; choose one of {', '.join(STRATEGIES)}")
    h, w = camera.height, camera.width
    mask = np.zeros((h, w), dtype=bool)
    points = np.asarray(diagnostics.keypoints_px, dtype=np.float64).reshape(-1, 2)
    codes = np.asarray(diagnostics.rejection)
    if len(codes) != len(points):
        raise ValueError(f"{len(points)} keypoints but {len(codes)} rejection codes")
    known = {code: r for r, code in REJECTION_CODES.items()}
    found = {known.get(int(c), int(c)) for c in np.unique(codes)}
    if not found <= ALLOWED_REJECTIONS[strategy]:
        raise ValueError(f"rejection codes {sorted(map(str, found))} are not all {strategy}'s")

    boxed = codes == REJECTION_CODES[Rejection.DYNAMIC_BOX]
    if boxed.any():
        dets = [d for d in detections if d.confidence >= rejection.min_confidence]
        dynamic = [d for d in dets if d.prior == Prior.DYNAMIC]
        hits = inside(points[boxed], dynamic, rejection.box_dilation_px)
        for d, hit in zip(dynamic, hits.T, strict=True):
            if hit.any():
                mask[_box_slices(d.box_xyxy, config.box_dilation_px, w, h)] = True
        if strategy == "box_rule":
            for d in dets:
                if d.prior != Prior.DYNAMIC:
                    mask[_box_slices(d.box_xyxy, config.box_dilation_px, w, h)] = False

    flowed = np.isin(codes, [REJECTION_CODES[r] for r in FLOW_REJECTIONS])
    for x, y in points[flowed]:
        _disk(mask, float(x), float(y), config.keypoint_radius_px)
    return mask


def pixel_rays(camera: Intrinsics) -> np.ndarray:
    """(H, W, 2) normalised image coordinates (x/z, y/z) of every pixel through the lens model:
    the pixel grid undistorted by ``camera.undistort`` where the camera has distortion."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    if camera.distorted:
        undistorted = camera.undistort(np.stack([u.ravel(), v.ravel()], axis=1))
        u = undistorted[:, 0].reshape(u.shape)
        v = undistorted[:, 1].reshape(v.shape)
    return np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy], axis=-1)


def back_project(depth_m: np.ndarray, rays: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(N, 3) camera-frame points of the ``valid`` pixels (row-major order); depth is z-depth."""
    z = depth_m[valid].astype(np.float64)
    xy = rays[valid] * z[:, None]
    return np.column_stack([xy, z])


def _pack(index: np.ndarray) -> np.ndarray:
    """One int64 per voxel index row (21 bits an axis)."""
    if len(index) and (index.min() < -_KEY_OFFSET or index.max() >= _KEY_OFFSET):
        raise ValueError(
            f"a point lies beyond {_KEY_OFFSET} voxels from the world origin: the pose or depth is wrong"
        )
    shifted = index + _KEY_OFFSET
    return (shifted[:, 0] << (2 * _KEY_BITS)) | (shifted[:, 1] << _KEY_BITS) | shifted[:, 2]


def _unpack(keys: np.ndarray) -> np.ndarray:
    cols = [(keys >> (2 * _KEY_BITS)) & _KEY_MASK, (keys >> _KEY_BITS) & _KEY_MASK, keys & _KEY_MASK]
    return np.stack(cols, axis=1) - _KEY_OFFSET


class DenseMap:
    """Keyframes merged into a voxel grid: per occupied voxel, the sums of position and colour
    and a count (64 bytes), kept sorted by voxel so that a keyframe merges in O(N log N)."""

    def __init__(self, config: DenseMapConfig | None = None) -> None:
        self.config = config or DenseMapConfig()
        self.keyframes = 0
        self._keys = np.zeros(0, dtype=np.int64)
        self._position_sum = np.zeros((0, 3), dtype=np.float64)
        self._colour_sum = np.zeros((0, 3), dtype=np.float64)
        self._count = np.zeros(0, dtype=np.int64)
        self._rays: dict[Intrinsics, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self._keys)

    @property
    def nbytes(self) -> int:
        """Bytes held by the voxel grid (the per-camera ray tables aside)."""
        return sum(a.nbytes for a in (self._keys, self._position_sum, self._colour_sum, self._count))

    def rays(self, camera: Intrinsics) -> np.ndarray:
        """``pixel_rays(camera)``, computed once per camera."""
        if camera not in self._rays:
            self._rays[camera] = pixel_rays(camera)
        return self._rays[camera]

    def add_keyframe(
        self,
        world_from_camera: np.ndarray,
        rgb: np.ndarray,
        depth_m: np.ndarray,
        camera: Intrinsics,
        exclude: np.ndarray | None = None,
    ) -> int:
        """Merge one keyframe; returns how many of its pixels went in (valid depth, in range,
        not excluded). Depth is z-depth in metres, 0 (or not finite) = no reading."""
        pose = np.asarray(world_from_camera, dtype=np.float64)
        if pose.shape != (4, 4) or not np.isfinite(pose).all():
            raise ValueError(f"world_from_camera must be a finite 4x4 matrix, got shape {pose.shape}")
        h, w = camera.height, camera.width
        if rgb.shape != (h, w, 3) or depth_m.shape != (h, w):
            raise ValueError(
                f"images must be {w}x{h}: RGB {rgb.shape}, depth {depth_m.shape} (RGB must be HxWx3)"
            )
        with np.errstate(invalid="ignore"):
            low, high = self.config.min_depth_m, self.config.max_depth_m
            valid = (depth_m > 0) & (depth_m >= low) & (depth_m <= high)
        if exclude is not None:
            if exclude.shape != (h, w):
                raise ValueError(f"exclude must be {w}x{h}, got {exclude.shape}")
            valid &= ~exclude.astype(bool)
        self.keyframes += 1
        camera_points = back_project(depth_m, self.rays(camera), valid)
        if len(camera_points) == 0:
            return 0
        world = camera_points @ pose[:3, :3].T + pose[:3, 3]
        keys = _pack(np.floor(world / self.config.voxel_m).astype(np.int64))
        unique, inverse = np.unique(keys, return_inverse=True)
        count = np.bincount(inverse, minlength=len(unique))
        colour = rgb[valid].astype(np.float64)
        position_sum = np.column_stack([np.bincount(inverse, world[:, i], len(unique)) for i in range(3)])
        colour_sum = np.column_stack([np.bincount(inverse, colour[:, i], len(unique)) for i in range(3)])
        self._merge(unique, position_sum, colour_sum, count)
        return len(world)

    def _merge(self, keys: np.ndarray, position: np.ndarray, colour: np.ndarray, count: np.ndarray) -> None:
        at = np.searchsorted(self._keys, keys)
        old = at < len(self._keys)
        old[old] = self._keys[at[old]] == keys[old]
        self._position_sum[at[old]] += position[old]
        self._colour_sum[at[old]] += colour[old]
        self._count[at[old]] += count[old]
        new = ~old
        if new.any():
            where = at[new]
            self._keys = np.insert(self._keys, where, keys[new])
            self._position_sum = np.insert(self._position_sum, where, position[new], axis=0)
            self._colour_sum = np.insert(self._colour_sum, where, colour[new], axis=0)
            self._count = np.insert(self._count, where, count[new])

    def points(self) -> np.ndarray:
        """(N, 3) float64: each occupied voxel's mean position, in voxel order."""
        return self._position_sum / self._count[:, None]

    def colours(self) -> np.ndarray:
        """(N, 3) uint8: each occupied voxel's mean RGB colour, rounded."""
        return np.rint(self._colour_sum / self._count[:, None]).astype(np.uint8)

    def voxels(self) -> np.ndarray:
        """(N, 3) int64: each occupied voxel's index, floor(position / voxel_m)."""
        return _unpack(self._keys)

    def counts(self) -> np.ndarray:
        """(N,) how many readings each voxel merged."""
        return self._count.copy()


def write_ply(path: str | Path, points: np.ndarray, colours: np.ndarray, overwrite: bool = False) -> Path:
    """Binary little-endian PLY of the points (float32 x, y, z) with per-vertex colour (uchar red,
    green, blue, alpha), written by trimesh beside ``path`` and renamed into place. An existing
    ``path`` is refused (FileExistsError) unless ``overwrite``."""
    import trimesh

    path = Path(path)
    points = np.asarray(points, dtype=np.float64)
    colours = np.asarray(colours)
    if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
        raise ValueError(f"points must be finite (N, 3), got shape {points.shape}")
    if colours.shape != points.shape or colours.dtype != np.uint8:
        raise ValueError(f"colours must be uint8 {points.shape}, got {colours.dtype} {colours.shape}")
    if not len(points):
        raise ValueError("no points to write")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists (pass overwrite=True to replace it)")
    data = trimesh.PointCloud(points, colors=colours).export(file_type="ply", encoding="binary")
    # Opened as any new file is (0666 less the umask: readable as the run's other files), not
    # as mkstemp's private 0600; the random name keeps two writers apart.
    aside = str(path.parent / f".{path.name}.{secrets.token_hex(6)}.part")
    fd = os.open(aside, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        if overwrite:
            os.replace(aside, path)
        else:
            try:
                os.link(aside, path)  # fails if path appeared meanwhile: never replaces a file
            except FileExistsError:
                raise FileExistsError(f"{path} exists (pass overwrite=True to replace it)") from None
            except OSError:  # a file system without hard links
                if path.exists():
                    raise FileExistsError(f"{path} exists (pass overwrite=True to replace it)") from None
                os.replace(aside, path)
            Path(aside).unlink(missing_ok=True)
    except BaseException:
        Path(aside).unlink(missing_ok=True)
        raise
    return path
