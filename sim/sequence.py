"""The sequence on disk: a TUM RGB-D folder plus exact ground truth (design.md).

``Sequence.open`` reads a generated sequence or a real TUM RGB-D folder;
``SequenceWriter`` writes one atomically. Neither imports MuJoCo or OpenGL.
"""

from __future__ import annotations

import io
import json
import math
import posixpath
import zipfile
import zlib
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np
from depotbench.core.camera import CameraOverride, CameraProvenance, CameraSource, Intrinsics
from depotbench.core.errors import FileError, InputError, SequenceFormatError
from depotbench.core.files import (
    DEFAULT_PNG_COMPRESSION,
    MAX_META_BYTES,
    MAX_RECORD_BYTES,
    decode_png,
    open_regular,
    png_header,
    read_bytes,
    read_text,
)
from depotbench.core.output import OutputKind, StagedOutput
from depotbench.core.version import FORMAT_VERSION, SUPPORTED_FORMAT_VERSIONS, generator_version
from depotbench.sim.camera import (
    OrbSlamSettings,
    orbslam_yaml,
    read_orbslam_yaml,
    tum_camera_for,
)
from depotbench.sim.ground_truth import ObjectState
from depotbench.sim.png import assemble_png, decode_written_rgb, sub_filtered
from depotbench.sim.tum_files import (
    FrameList,
    PoseTable,
    check_increasing,
    parse_timestamp,
    read_frame_list,
    read_pose_file,
    read_rows,
    write_frame_list,
    write_pose_file,
)
from scipy.spatial.transform import Rotation

PNG_WRITER_THREADS = 2
ASSOCIATION_MAX_DIFF_S = 0.02
TEXT_FILES = ("associations.txt", "rgb.txt", "depth.txt", "groundtruth.txt", "camera.yaml", "meta.json")
"""The text files of the format at a sequence's root (design.md)."""
"""Largest RGB/depth timestamp gap paired when a folder has no associations.txt (TUM)."""


def timestamp_name(timestamp_s: float) -> str:
    """The file stem of a frame: seconds with 6 decimals, as in TUM."""
    return f"{timestamp_s:.6f}"


@dataclass(frozen=True)
class FrameRef:
    """Where one RGB-D frame lives, and which list line named it."""

    timestamp_s: float
    rgb_path: Path
    depth_timestamp_s: float
    depth_path: Path
    list_path: Path
    list_line: int


@dataclass(frozen=True, eq=False)
class Sequence:
    """An opened sequence. Frames are decoded on demand and checked as they are."""

    root: Path
    intrinsics: Intrinsics
    fps: float
    frames: tuple[FrameRef, ...]
    groundtruth: PoseTable | None
    meta: dict[str, Any] | None
    camera_source: CameraProvenance = CameraProvenance(
        CameraSource.SEQUENCE, "camera.yaml", CameraSource.SEQUENCE
    )
    """Where ``intrinsics`` came from (metrics.json's ``camera``)."""
    camera_given: CameraOverride | None = None
    """The camera it was opened with (``Sequence.open(camera=...)``), if any."""

    @property
    def is_generated(self) -> bool:
        """True for depotbench sequences, which carry ``meta.json`` and ``gt/``."""
        return self.meta is not None

    @property
    def timestamps_s(self) -> np.ndarray:
        return np.array([f.timestamp_s for f in self.frames])

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def camera_warning(self) -> str | None:
        """One line naming the guessed camera a real folder is read with, or None where the
        camera is the folder's own or was given: a wrong one biases every pose silently
        (TUM's fr1 against the ROS default: 16 px in cy, 8 px in fx, and a k1 of 0.26)."""
        if not self.camera_source.fallback:
            return None
        return (
            f"{self.root}: no camera given (--camera FILE, or --intrinsics FX FY CX CY) and no "
            f"camera.yaml; using {self.camera_source.detail}; depth factor {self.intrinsics.depth_scale:g}"
        )

    @classmethod
    def open(
        cls,
        root: Path | str,
        intrinsics: Intrinsics | None = None,
        max_diff_s: float = ASSOCIATION_MAX_DIFF_S,
        camera: CameraOverride | None = None,
    ) -> Sequence:
        """Open and check a sequence folder.

        A real TUM folder needs no ``camera.yaml``: ``camera`` (or a whole ``intrinsics``)
        replaces what its camera.yaml or its name gives; without any, TUM's calibration is
        chosen from the folder name (freiburg1/2/3), else the ROS default, and
        ``camera_source`` says it was a guess. A generated sequence keeps its own camera
        (its ground truth was rendered through it): a camera given for one is refused.
        """
        if intrinsics is not None:
            if camera is not None:
                raise ValueError("give intrinsics or camera, not both")
            camera = CameraOverride.of(intrinsics)
        root = Path(root)
        if not root.is_dir():
            raise SequenceFormatError(root, None, "is not a sequence folder (no such directory)")
        meta = _read_meta(root / "meta.json")
        camera_path = root / "camera.yaml"
        fps = 30.0
        if camera_path.exists():
            intrinsics, fps = read_orbslam_yaml(camera_path)
            provenance = CameraProvenance(CameraSource.SEQUENCE, "camera.yaml", CameraSource.SEQUENCE)
        elif meta is not None:
            raise SequenceFormatError(camera_path, None, "file is missing (required with meta.json)")
        else:
            intrinsics, provenance = tum_camera_for(root)
        if camera is not None and meta is not None:
            raise InputError(
                f"{root}: a generated sequence keeps its own camera (camera.yaml), the one its ground "
                f"truth was rendered with; {camera.origin} is for real TUM folders"
            )
        if meta is not None and "fps" in meta:
            fps = meta["fps"]
            if isinstance(fps, bool) or not isinstance(fps, int | float) or not 0 < fps < math.inf:
                raise SequenceFormatError(root / "meta.json", None, f"fps must be a number > 0, got {fps!r}")
        frames = _read_frames(root, max_diff_s)
        if camera is not None or provenance.fallback:
            intrinsics, provenance = _chosen_camera(frames[0], intrinsics, provenance, camera)
        gt_path = root / "groundtruth.txt"
        groundtruth = None
        if gt_path.exists():
            groundtruth = read_pose_file(gt_path, strict=True)
        elif meta is not None:
            raise SequenceFormatError(gt_path, None, "file is missing (required with meta.json)")
        sequence = cls(root, intrinsics, fps, frames, groundtruth, meta, provenance, camera)
        if meta is not None:
            sequence._check_generated()
        return sequence

    def _check_generated(self) -> None:
        """Generated sequences have one ground-truth pose and gt record per frame, and a
        camera.yaml that agrees with meta.json."""
        assert self.groundtruth is not None and self.meta is not None
        k = self.intrinsics
        for key, stored, here in (
            ("image_size", self.meta.get("image_size"), [k.width, k.height]),
            ("depth_scale", self.meta.get("depth_scale"), k.depth_scale),
            ("frames", self.meta.get("frames"), len(self.frames)),
        ):
            if stored is not None and stored != here:
                raise SequenceFormatError(
                    self.root / "meta.json", None, f"{key} is {stored!r} but the sequence has {here!r}"
                )
        gt_path = self.root / "groundtruth.txt"
        if len(self.groundtruth.timestamps_s) != len(self.frames):
            raise SequenceFormatError(
                gt_path,
                None,
                f"holds {len(self.groundtruth.timestamps_s)} poses for {len(self.frames)} frames",
            )
        mismatch = np.flatnonzero(np.abs(self.groundtruth.timestamps_s - self.timestamps_s) > 1e-6)
        if mismatch.size:
            i = int(mismatch[0])
            raise SequenceFormatError(
                gt_path,
                self.groundtruth.lines[i],
                f"timestamp {self.groundtruth.timestamps_s[i]:.6f} differs from frame {i} "
                f"({self.frames[i].timestamp_s:.6f})",
            )
        objects_path = self.root / "gt" / "objects.jsonl"
        if not objects_path.exists():
            raise SequenceFormatError(objects_path, None, "file is missing")
        real_root = self.root.resolve()
        _check_inside(real_root, objects_path)
        for frame in self.frames:
            mask = self._instance_path(frame)
            if not mask.exists():
                raise SequenceFormatError(mask, None, "instance image is missing")
            _check_inside(real_root, mask)
        for sub, suffix in (("depth", ".png"), ("flow", ".npz")):  # optional, read on demand
            for path in (self.root / "gt" / sub).glob(f"*{suffix}"):
                _check_inside(real_root, path)

    # -- frames ---------------------------------------------------------------

    def rgb(self, index: int) -> np.ndarray:
        """Frame ``index`` as 8-bit RGB, shape (H, W, 3)."""
        frame = self.frames[index]
        image = _read_png(frame.rgb_path, frame, self._size, decode_written_rgb)
        if image.dtype != np.uint8:
            raise SequenceFormatError(frame.rgb_path, None, f"RGB must be 8-bit, got {image.dtype}")
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
        elif image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_RGBA2RGB)
        return image

    def depth_raw(self, index: int) -> np.ndarray:
        """Frame ``index``'s depth PNG as stored: uint16, metres x depth_scale, 0 = none."""
        frame = self.frames[index]
        depth = _read_png(frame.depth_path, frame, self._size)
        if depth.dtype != np.uint16 or depth.ndim != 2:
            channels = 1 if depth.ndim == 2 else depth.shape[2]
            raise SequenceFormatError(
                frame.depth_path,
                None,
                f"depth must be a 16-bit single-channel PNG, got {depth.dtype} x{channels}",
            )
        return depth

    def depth_m(self, index: int) -> np.ndarray:
        """Frame ``index``'s z-depth in metres (float32), 0 where there is no reading."""
        return self.depth_raw(index).astype(np.float32) / np.float32(self.intrinsics.depth_scale)

    def world_from_camera(self, index: int) -> np.ndarray:
        """True 4x4 pose of frame ``index`` at its capture (generated sequences): exact. Where
        groundtruth.txt is a simulated motion capture's record, gt/camera_poses.txt holds it."""
        if self.groundtruth is None or not self.is_generated:
            raise ValueError(f"{self.root}: per-frame ground truth needs a generated sequence")
        poses = self._exact_poses
        return pose_matrix(poses.positions_m[index], poses.quats_xyzw[index])

    @cached_property
    def _exact_poses(self) -> PoseTable:
        path = self.root / "gt" / "camera_poses.txt"
        if not path.exists():
            assert self.groundtruth is not None
            return self.groundtruth
        poses = read_pose_file(path, strict=True)
        if len(poses.timestamps_s) != len(self.frames) or np.any(
            np.abs(poses.timestamps_s - self.timestamps_s) > 1e-6
        ):
            raise SequenceFormatError(path, None, f"does not hold one pose per frame ({len(self.frames)})")
        return poses

    # -- ground-truth extras ---------------------------------------------------

    def _instance_path(self, frame: FrameRef) -> Path:
        return self.root / "gt" / "instances" / f"{timestamp_name(frame.timestamp_s)}.png"

    def instances(self, index: int) -> np.ndarray:
        """Instance id per pixel (uint16, 0 = static world)."""
        self._require_generated()
        frame = self.frames[index]
        path = self._instance_path(frame)
        mask = _read_png(path, frame, self._size)
        if mask.dtype != np.uint16 or mask.ndim != 2:
            raise SequenceFormatError(path, None, "instance image must be a 16-bit single-channel PNG")
        return mask

    def objects(self) -> list[tuple[ObjectState, ...]]:
        """Every frame's object states, read from ``gt/objects.jsonl``."""
        self._require_generated()
        path = self.root / "gt" / "objects.jsonl"
        records: list[tuple[ObjectState, ...]] = []
        fd = open_regular(path, 2**62, "JSON-lines file")
        with open(fd, encoding="utf-8", errors="strict") as handle:
            for line_number, line in enumerate(_bounded_lines(path, handle), start=1):
                try:
                    data = json.loads(line)
                    states = tuple(ObjectState.from_json(o) for o in data["objects"])
                    timestamp = float(data["timestamp"])
                except (ValueError, KeyError, TypeError, AttributeError, RecursionError) as exc:
                    raise SequenceFormatError(path, line_number, f"bad record: {exc}") from None
                self._check_boxes(path, line_number, states)
                if line_number > len(self.frames):
                    raise SequenceFormatError(path, line_number, "more records than frames")
                expected = self.frames[line_number - 1].timestamp_s
                if abs(timestamp - expected) > 1e-6:
                    raise SequenceFormatError(
                        path, line_number, f"timestamp {timestamp:.6f}, frame has {expected:.6f}"
                    )
                records.append(states)
        if len(records) != len(self.frames):
            raise SequenceFormatError(
                path, None, f"holds {len(records)} records for {len(self.frames)} frames"
            )
        return records

    def _check_boxes(self, path: Path, line: int, states: tuple[ObjectState, ...]) -> None:
        width, height = self._size
        for state in states:
            box = state.box_xyxy
            if box is not None and (box[2] > width or box[3] > height):
                raise SequenceFormatError(
                    path,
                    line,
                    f"box {list(box)} of instance {state.instance_id} exceeds the {width}x{height} frame",
                )

    def clean_depth_m(self, index: int) -> np.ndarray:
        """Noise-free depth (gt/depth) where a sensor model was applied, else the depth."""
        self._require_generated()
        frame = self.frames[index]
        path = self.root / "gt" / "depth" / f"{timestamp_name(frame.timestamp_s)}.png"
        if not path.exists():
            return self.depth_m(index)
        depth = _read_png(path, frame, self._size)
        return depth.astype(np.float32) / np.float32(self.intrinsics.depth_scale)

    def flow(self, index: int) -> np.ndarray | None:
        """Exact optical flow (H, W, 2) to the next frame, if the sequence stores it."""
        self._require_generated()
        path = self.root / "gt" / "flow" / f"{timestamp_name(self.frames[index].timestamp_s)}.npz"
        if not path.exists():
            return None
        h, w = self.intrinsics.height, self.intrinsics.width
        limit = h * w * 2 * 4 + 4096  # float32 (H, W, 2) and the .npy header
        try:  # read bounded (a FIFO refused, not waited on), then opened from memory
            data = read_bytes(path, limit + 65536, "flow archive")
            with zipfile.ZipFile(io.BytesIO(data)) as archive:
                size = archive.getinfo("flow.npy").file_size
            if size > limit:
                raise SequenceFormatError(path, None, f"flow.npy holds {size} bytes, too many for {w}x{h}")
            with np.load(io.BytesIO(data)) as archive_data:
                flow = archive_data["flow"]
        except FileError:
            raise
        except (zipfile.BadZipFile, KeyError, ValueError, OSError, EOFError, zlib.error) as exc:
            raise SequenceFormatError(path, None, f"not a flow archive ({exc})") from None
        if flow.shape != (h, w, 2):
            raise SequenceFormatError(path, None, f"flow has shape {flow.shape}, expected {(h, w, 2)}")
        return flow

    def verify(self) -> None:
        """Decode every image, so a corrupt file is found before a long run."""
        for i in range(len(self.frames)):
            self.rgb(i)
            self.depth_raw(i)
            if self.is_generated:
                self.instances(i)
        if self.is_generated:
            self.objects()

    def files(self) -> list[Path]:
        """Every file of the sequence format this folder holds, in a fixed order: the lists,
        camera, meta and ground-truth files, then each frame's RGB, depth, instance, clean
        depth and flow files. What any reader of the sequence may read is here, so a key
        built on these files changes whenever a result could."""
        root = self.root
        names = (*TEXT_FILES, "gt/objects.jsonl")
        paths = [root / name for name in names if (root / name).is_file()]
        for frame in self.frames:
            paths += [frame.rgb_path, frame.depth_path]
            stem = timestamp_name(frame.timestamp_s)
            extras = (f"gt/instances/{stem}.png", f"gt/depth/{stem}.png", f"gt/flow/{stem}.npz")
            paths += [root / name for name in extras if (root / name).is_file()]
        return paths

    def _require_generated(self) -> None:
        if not self.is_generated:
            raise ValueError(f"{self.root}: not a generated sequence (no meta.json, no gt/)")

    @property
    def _size(self) -> tuple[int, int]:
        return (self.intrinsics.width, self.intrinsics.height)


def _chosen_camera(
    first: FrameRef, base: Intrinsics, provenance: CameraProvenance, camera: CameraOverride | None
) -> tuple[Intrinsics, CameraProvenance]:
    """A real folder's camera: ``base`` (its camera.yaml's, or the fallback its name gives)
    with what ``camera`` gives replaced, and where each part came from; checked against the
    size of its first image, where a camera that gives no size takes it from."""
    try:
        width, height, _, _ = png_header(first.rgb_path)
    except FileNotFoundError:
        raise SequenceFormatError(
            first.list_path, first.list_line, f"frame file {first.rgb_path} is missing"
        ) from None
    except FileError as exc:
        raise SequenceFormatError(first.rgb_path, None, exc.problem) from None
    if camera is None:
        intrinsics = base
    else:
        intrinsics = camera.applied(base, (width, height))
        if camera.pinhole is not None:
            depth_source = (
                camera.source if camera.depth_factor is not None else provenance.depth_factor_source
            )
            provenance = CameraProvenance(camera.source, camera.origin, depth_source)
        else:
            provenance = CameraProvenance(provenance.source, provenance.detail, camera.source)
    if (intrinsics.width, intrinsics.height) != (width, height):
        size = f"{intrinsics.width}x{intrinsics.height}"
        if provenance.fallback:
            raise SequenceFormatError(
                first.rgb_path,
                None,
                f"image is {width}x{height}, but the camera guessed for the folder is {size} "
                f"({provenance.detail}); give the camera (--camera FILE, or --intrinsics FX FY CX CY)",
            )
        raise InputError(
            f"{provenance.detail}: the camera is {size}, but {first.rgb_path} is {width}x{height}"
        )
    return intrinsics, provenance


def pose_matrix(position: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """4x4 rigid transform from a position and a (normalised) xyzw quaternion."""
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    pose[:3, 3] = position
    return pose


def _read_meta(path: Path) -> dict[str, Any] | None:
    if not (path.exists() or path.is_symlink()):
        return None
    try:
        meta = json.loads(read_text(path, MAX_META_BYTES, "meta.json"))
    except FileNotFoundError:
        raise SequenceFormatError(path, None, "is a broken link") from None
    except FileError as exc:
        raise SequenceFormatError(path, None, exc.problem) from None
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, or an integer too long to convert
        line = getattr(exc, "lineno", None)
        problem = str(getattr(exc, "msg", exc)).split(";")[0]
        raise SequenceFormatError(path, line, f"not valid JSON: {problem}") from None
    if not isinstance(meta, dict):
        raise SequenceFormatError(path, None, "must hold a JSON object")
    version = meta.get("format_version")
    if type(version) is not int or version not in SUPPORTED_FORMAT_VERSIONS:
        raise SequenceFormatError(
            path,
            None,
            f"format_version {version!r} is not supported (this reader knows "
            f"{', '.join(map(str, SUPPORTED_FORMAT_VERSIONS))}); upgrade depotbench",
        )
    return meta


def _read_frames(root: Path, max_diff_s: float) -> tuple[FrameRef, ...]:
    assoc_path = root / "associations.txt"
    if assoc_path.exists():
        rows = read_rows(assoc_path, 4)
        if not rows:
            raise SequenceFormatError(assoc_path, None, "lists no frames")
        stamps = np.array([parse_timestamp(assoc_path, r, 0) for r in rows])
        check_increasing(assoc_path, stamps, [r.line for r in rows])
        frames = [
            FrameRef(
                float(stamps[k]),
                _inside(root, r.fields[1], assoc_path, r.line),
                parse_timestamp(assoc_path, r, 2),
                _inside(root, r.fields[3], assoc_path, r.line),
                assoc_path,
                r.line,
            )
            for k, r in enumerate(rows)
        ]
        for frame in frames:
            gap = abs(frame.depth_timestamp_s - frame.timestamp_s)
            if not gap <= max_diff_s:
                raise SequenceFormatError(
                    assoc_path,
                    frame.list_line,
                    f"depth is {gap:.6f} s from its RGB frame (at most {max_diff_s} s, as TUM's associate)",
                )
    else:
        rgb = read_frame_list(root / "rgb.txt")
        depth = read_frame_list(root / "depth.txt")
        frames = [
            FrameRef(
                float(rgb.timestamps_s[i]),
                _inside(root, rgb.filenames[i], root / "rgb.txt", rgb.lines[i]),
                float(depth.timestamps_s[j]),
                _inside(root, depth.filenames[j], root / "depth.txt", depth.lines[j]),
                root / "rgb.txt",
                rgb.lines[i],
            )
            for i, j in associate_lists(rgb, depth, max_diff_s)
        ]
        if not frames:
            raise SequenceFormatError(
                root / "depth.txt", None, f"no depth frame within {max_diff_s} s of any RGB frame"
            )
    seen: dict[Path, int] = {}
    real_root = root.resolve()
    for frame in frames:
        for path in (frame.rgb_path, frame.depth_path):
            _check_contained(real_root, path, root, frame)
            if path in seen:
                raise SequenceFormatError(
                    frame.list_path,
                    frame.list_line,
                    f"frame file {path.relative_to(root)} is listed again (first on line {seen[path]})",
                )
            seen[path] = frame.list_line
            if not path.is_file():
                raise SequenceFormatError(
                    frame.list_path,
                    frame.list_line,
                    f"frame file {path.relative_to(root)} is missing",
                )
    return tuple(frames)


def _inside(root: Path, name: str, list_path: Path, line: int) -> Path:
    """``root / name``, refused when ``name`` is absolute or climbs out of the sequence."""
    if "\0" in name:
        raise SequenceFormatError(list_path, line, f"path {name!r} holds a NUL character")
    normal = posixpath.normpath(name.replace("\\", "/"))
    if posixpath.isabs(normal) or normal == ".." or normal.startswith("../"):
        raise SequenceFormatError(list_path, line, f"path {name!r} points outside the sequence folder")
    return root / normal


def _check_inside(real_root: Path, path: Path) -> None:
    """Refuse a ground-truth file that a link leads out of the sequence folder."""
    real = path.resolve()
    if real_root not in real.parents:
        raise SequenceFormatError(path, None, f"is a link out of the sequence folder (to {real})")


def _check_contained(real_root: Path, path: Path, root: Path, frame: FrameRef) -> None:
    """Refuse a frame file that a link leads out of the sequence folder.

    The lists' text is checked by ``_inside``; links are checked here, on the resolved
    path, so a sequence from someone else cannot make depotbench read (and an export
    copy) ``/etc/passwd`` through ``x/root -> /``. A whole folder that is a link is fine.
    """
    real = path.resolve()
    if real != real_root and real_root not in real.parents:
        raise SequenceFormatError(
            frame.list_path,
            frame.list_line,
            f"frame file {path.relative_to(root)} is a link out of the sequence folder (to {real}); "
            "copy the file into the folder",
        )


def associate_lists(rgb: FrameList, depth: FrameList, max_diff_s: float) -> list[tuple[int, int]]:
    """Pair RGB and depth frames as TUM's associate.py does.

    All pairs closer than ``max_diff_s`` are taken greedily, closest first, each
    frame used once; the result is sorted by RGB time.
    """
    a, b = rgb.timestamps_s, depth.timestamps_s
    lo = np.searchsorted(b, a - max_diff_s, side="left")
    hi = np.searchsorted(b, a + max_diff_s, side="right")
    candidates = [
        (abs(a[i] - b[j]), i, j)
        for i in range(len(a))
        for j in range(lo[i], hi[i])
        if abs(a[i] - b[j]) < max_diff_s
    ]
    candidates.sort()
    used_a: set[int] = set()
    used_b: set[int] = set()
    pairs = []
    for _, i, j in candidates:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    pairs.sort()
    return pairs


def _read_png(
    path: Path,
    frame: FrameRef,
    size: tuple[int, int],
    own: Callable[[bytes], np.ndarray | None] | None = None,
) -> np.ndarray:
    """Decode a frame's PNG after its header says it has the camera's ``(width, height)``;
    ``own`` decodes the files it knows (``decode_png``)."""
    try:
        width, height, _, _ = png_header(path)
    except FileNotFoundError:
        raise SequenceFormatError(frame.list_path, frame.list_line, f"frame file {path} is missing") from None
    except FileError as exc:
        raise SequenceFormatError(path, None, exc.problem) from None
    if (width, height) != size:
        raise SequenceFormatError(path, None, f"image is {width}x{height}, the camera is {size[0]}x{size[1]}")
    try:
        return decode_png(path, own)
    except FileError as exc:
        raise SequenceFormatError(path, None, exc.problem) from None


def _bounded_lines(path: Path, handle: Any) -> Iterator[str]:
    """The lines of a text file, refusing one longer than ``MAX_RECORD_BYTES``."""
    number = 0
    while True:
        try:
            line = handle.readline(MAX_RECORD_BYTES + 1)
        except UnicodeDecodeError as exc:
            raise SequenceFormatError(path, number + 1, f"not UTF-8 text ({exc.reason})") from None
        if not line:
            return
        number += 1
        if len(line) > MAX_RECORD_BYTES:
            raise SequenceFormatError(path, number, f"line is longer than {MAX_RECORD_BYTES} bytes")
        yield line


# -- writer --------------------------------------------------------------------


class SequenceWriter:
    """Write a sequence into a temporary folder and rename it into place when complete.

    Use as a context manager; an exception inside the block leaves nothing behind.
    """

    def __init__(
        self,
        root: Path | str,
        intrinsics: Intrinsics,
        *,
        fps: float,
        meta: dict[str, Any],
        overwrite: bool = False,
        png_compression: int = DEFAULT_PNG_COMPRESSION,
        orbslam: OrbSlamSettings | None = None,
        content_key: str | None = None,
        inputs: tuple[Path, ...] = (),
    ) -> None:
        self.root = Path(root)
        self.intrinsics = intrinsics
        self.fps = fps
        self.meta = dict(meta)
        if isinstance(png_compression, bool) or png_compression not in range(10):
            raise ValueError(f"png_compression must be a zlib level 0-9, got {png_compression!r}")
        self.png_level = int(png_compression)
        self._output = StagedOutput(
            self.root, OutputKind.SEQUENCE, overwrite=overwrite, inputs=inputs, content_key=content_key
        )
        self._pool: ThreadPoolExecutor | None = None
        self._pending: list[Future[None]] = []
        self.orbslam = orbslam or OrbSlamSettings(fps=fps)
        self._tmp: Path | None = None
        self._timestamps: list[float] = []
        self._depth_timestamps: list[float] = []
        self._positions: list[np.ndarray] = []
        self._quats: list[np.ndarray] = []
        self._recorded: list[np.ndarray] = []
        self._objects: list[str] = []

    def __enter__(self) -> SequenceWriter:
        """Check and lock the output, and stage it: a place that cannot be written fails here."""
        self._output.__enter__()
        self._tmp = self._output.path
        for sub in ("rgb", "depth", "gt/instances"):
            (self._tmp / sub).mkdir(parents=True)
        # The deflate releases the GIL: encoding overlaps with rendering the next frame.
        self._pool = ThreadPoolExecutor(max_workers=PNG_WRITER_THREADS)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        assert self._pool is not None
        raised = exc
        try:
            self._pool.shutdown(wait=True, cancel_futures=exc_type is not None)
            for future in self._pending:
                if exc_type is None:
                    future.result()  # re-raises a failed write
            if exc_type is None:
                self._finish()
                self._output.commit()
        except BaseException as error:
            raised = error  # a failed write (a full disk): the output names itself in the error
            raise
        finally:
            self._output.__exit__(type(raised) if raised else None, raised, tb)

    def add_frame(
        self,
        timestamp_s: float,
        rgb: np.ndarray,
        depth_m: np.ndarray,
        world_from_camera: np.ndarray,
        instances: np.ndarray,
        objects: tuple[ObjectState, ...] | list[ObjectState],
        flow: np.ndarray | None = None,
        clean_depth_m: np.ndarray | None = None,
        depth_timestamp_s: float | None = None,
        recorded_pose: np.ndarray | None = None,
    ) -> None:
        """Add one frame: RGB, metric z-depth, true camera pose (optical frame), ground truth.

        ``clean_depth_m`` is the noise-free depth, kept under gt/depth when a sensor
        model altered ``depth_m``. ``depth_timestamp_s`` is the depth map's own stamp
        (default: the RGB's). ``recorded_pose`` is what groundtruth.txt holds for the frame
        where a motion capture's noise and timing are simulated; the exact pose then goes
        to gt/camera_poses.txt. Give it for every frame or for none.
        """
        if self._tmp is None:
            raise RuntimeError("SequenceWriter must be used as a context manager")
        index = len(self._timestamps)
        h, w = self.intrinsics.height, self.intrinsics.width
        if self._timestamps and timestamp_s <= self._timestamps[-1]:
            raise ValueError(f"frame {index}: timestamp {timestamp_s} does not increase")
        if index and timestamp_name(timestamp_s) == timestamp_name(self._timestamps[-1]):
            raise ValueError(f"frame {index}: timestamp {timestamp_s} collides at 6 decimals")
        depth_stamp = timestamp_s if depth_timestamp_s is None else float(depth_timestamp_s)
        if self._depth_timestamps and round(depth_stamp, 6) <= round(self._depth_timestamps[-1], 6):
            raise ValueError(f"frame {index}: depth timestamp {depth_stamp} does not increase at 6 decimals")
        if index and (recorded_pose is None) != (not self._recorded):
            raise ValueError(f"frame {index}: a recorded pose is given for every frame or for none")
        _check_array(f"frame {index} rgb", rgb, (h, w, 3), np.uint8)
        _check_array(f"frame {index} depth_m", depth_m, (h, w), None)
        _check_array(f"frame {index} instances", instances, (h, w), np.uint16)
        pose = np.asarray(world_from_camera, dtype=np.float64)
        _check_pose(f"frame {index} world_from_camera", pose)
        name = timestamp_name(timestamp_s)
        tmp = self._tmp
        self._write_png(tmp / "rgb" / f"{name}.png", rgb)
        depth_name = timestamp_name(depth_stamp)
        self._write_png(
            tmp / "depth" / f"{depth_name}.png", encode_depth(depth_m, self.intrinsics.depth_scale)
        )
        self._write_png(tmp / "gt" / "instances" / f"{name}.png", instances)
        if clean_depth_m is not None:
            _check_array(f"frame {index} clean_depth_m", clean_depth_m, (h, w), None)
            (tmp / "gt" / "depth").mkdir(exist_ok=True)
            self._write_png(
                tmp / "gt" / "depth" / f"{name}.png",
                encode_depth(clean_depth_m, self.intrinsics.depth_scale),
            )
        if flow is not None:
            _check_array(f"frame {index} flow", flow, (h, w, 2), np.float32)
            (tmp / "gt" / "flow").mkdir(exist_ok=True)
            np.savez_compressed(tmp / "gt" / "flow" / f"{name}.npz", flow=flow)
        self._timestamps.append(float(timestamp_s))
        self._depth_timestamps.append(depth_stamp)
        if recorded_pose is not None:
            recorded = np.asarray(recorded_pose, dtype=np.float64)
            _check_pose(f"frame {index} recorded_pose", recorded)
            self._recorded.append(recorded)
        self._positions.append(pose[:3, 3].copy())
        self._quats.append(Rotation.from_matrix(pose[:3, :3]).as_quat(canonical=True))
        record = {"timestamp": name, "objects": [o.to_json() for o in objects]}
        self._objects.append(json.dumps(record, separators=(",", ":")))

    def _write_png(self, path: Path, image: np.ndarray) -> None:
        """Filter ``image``'s rows here (a copy: the caller may change the array once this
        returns), then deflate and write them in a writer thread."""
        assert self._pool is not None
        self._pending = [f for f in self._pending if not f.done() or f.exception()]
        rows = sub_filtered(image)
        self._pending.append(
            self._pool.submit(_write_rows, path, image.shape, image.dtype, rows, self.png_level)
        )

    def _finish(self) -> None:
        assert self._tmp is not None
        if not self._timestamps:
            raise ValueError(f"{self.root}: a sequence needs at least one frame")
        tmp = self._tmp
        stamps = np.array(self._timestamps)
        depth_stamps = np.array(self._depth_timestamps)
        names = [timestamp_name(t) for t in stamps]
        depth_names = [timestamp_name(t) for t in depth_stamps]
        write_frame_list(tmp / "rgb.txt", "color images", stamps, [f"rgb/{n}.png" for n in names])
        write_frame_list(
            tmp / "depth.txt", "depth maps", depth_stamps, [f"depth/{n}.png" for n in depth_names]
        )
        (tmp / "associations.txt").write_text(
            "".join(f"{n} rgb/{n}.png {d} depth/{d}.png\n" for n, d in zip(names, depth_names, strict=True)),
            encoding="utf-8",
        )
        exact = (np.array(self._positions), np.array(self._quats))
        if self._recorded:
            recorded = np.array(self._recorded)
            write_pose_file(
                tmp / "gt" / "camera_poses.txt",
                stamps,
                *exact,
                header="exact camera poses (world_from_camera, optical frame) at each frame's capture",
            )
            write_pose_file(
                tmp / "groundtruth.txt",
                stamps,
                recorded[:, :3, 3],
                Rotation.from_matrix(recorded[:, :3, :3]).as_quat(canonical=True),
                header="ground truth as a motion capture records it (noise, clock offset, sample rate)",
            )
        else:
            write_pose_file(
                tmp / "groundtruth.txt",
                stamps,
                *exact,
                header="ground truth trajectory (world_from_camera, optical frame)",
            )
        (tmp / "camera.yaml").write_text(orbslam_yaml(self.intrinsics, self.orbslam), encoding="utf-8")
        (tmp / "gt" / "objects.jsonl").write_text("\n".join(self._objects) + "\n", encoding="utf-8")
        meta = {
            **self.meta,
            "format_version": FORMAT_VERSION,
            "generator": f"depotbench {generator_version()}",
            "fps": self.fps,
            "frames": len(stamps),
            "image_size": [self.intrinsics.width, self.intrinsics.height],
            "depth_scale": self.intrinsics.depth_scale,
        }
        (tmp / "meta.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8")


def _write_rows(path: Path, shape: tuple[int, ...], dtype: np.dtype, rows: np.ndarray, level: int) -> None:
    path.write_bytes(assemble_png(shape, dtype, rows, level))


def encode_depth(depth_m: np.ndarray, depth_scale: float) -> np.ndarray:
    """Metric depth to TUM's uint16 PNG units; no reading (0) where out of range or invalid."""
    scaled = np.asarray(depth_m).astype(np.float64)  # a copy, worked on in place
    np.multiply(scaled, depth_scale, out=scaled)
    np.rint(scaled, out=scaled)
    scaled[~((scaled > 0) & (scaled <= np.iinfo(np.uint16).max))] = 0  # NaN compares false
    return scaled.astype(np.uint16)


def _check_array(what: str, array: np.ndarray, shape: tuple[int, ...], dtype: type | None) -> None:
    if not isinstance(array, np.ndarray) or array.shape != shape:
        got = getattr(array, "shape", type(array).__name__)
        raise ValueError(f"{what}: expected shape {shape}, got {got}")
    if dtype is not None and array.dtype != dtype:
        raise ValueError(f"{what}: expected dtype {np.dtype(dtype)}, got {array.dtype}")


def _check_pose(what: str, pose: np.ndarray) -> None:
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise ValueError(f"{what}: must be a finite 4x4 matrix")
    rotation = pose[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
        raise ValueError(f"{what}: rotation block is not a proper rotation")
    if not np.allclose(pose[3], [0, 0, 0, 1]):
        raise ValueError(f"{what}: last row must be 0 0 0 1")
