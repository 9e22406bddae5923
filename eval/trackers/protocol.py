"""The files an external tracker reads and writes besides its trajectory
(docs/external-trackers.md): the detections the bench hands it, and the keypoint
decisions it may hand back to be scored against the exact ground truth.

Both are plain text a C++ program reads or writes with ``sscanf`` and ``<<``: one box or
one keypoint a line, the frame named by its RGB timestamp as in ``associations.txt``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depotbench.core.errors import FileError
from depotbench.core.files import MIB, read_text
from depotbench.detectors.detection import Detection, Prior
from depotbench.sim.sequence import Sequence, timestamp_name

DETECTIONS_HEADER = "# depotbench detections 1\n# timestamp x0 y0 x1 y1 prior confidence class\n"
KEYPOINTS_HEADER = "# depotbench keypoints 1\n# timestamp x y kept [reason]\n"
MAX_KEYPOINTS_BYTES = 1024 * MIB
"""A keypoint file: 300 frames of 1000 keypoints take about 9 MB, so 1 GiB is 30,000
frames of them; a larger file is refused before it is read."""
MAX_DETECTIONS_BYTES = 256 * MIB
TIMESTAMP_TOLERANCE_S = 1e-3
"""How far a line's timestamp may be from its frame's (trajectories are matched alike)."""


class ProtocolError(FileError):
    """A file of the external-tracker protocol that cannot be read: names the file and line."""


def write_detections(
    path: Path, sequence: Sequence, per_frame: tuple[tuple[Detection, ...], ...] | None
) -> Path:
    """The run's boxes, faults applied, one a line (none at all for ``--detector none``)."""
    lines = [DETECTIONS_HEADER]
    for frame, boxes in zip(sequence.frames, per_frame or [()] * len(sequence), strict=True):
        stamp = timestamp_name(frame.timestamp_s)
        for box in boxes:
            # float(): faulted boxes hold NumPy floats, whose repr is 'np.float64(...)'
            x0, y0, x1, y1 = (float(v) for v in box.box_xyxy)
            confidence = float(box.confidence)
            lines.append(
                f"{stamp} {x0!r} {y0!r} {x1!r} {y1!r} {box.prior.value} {confidence!r} {box.class_name}\n"
            )
    path.write_text("".join(lines), encoding="utf-8")
    return path


def read_detections(path: Path, sequence: Sequence) -> tuple[tuple[Detection, ...], ...]:
    """A detections file back as per-frame boxes (what a Python tracker reads it into);
    floats are written with ``repr``, so the boxes come back bit for bit."""
    index = _frame_index(sequence)
    per_frame: list[list[Detection]] = [[] for _ in sequence.frames]
    for number, fields in _data_lines(path, MAX_DETECTIONS_BYTES, "detections file", maxsplit=7):
        if len(fields) != 8:
            raise ProtocolError(
                path,
                number,
                f"expected 8 fields (timestamp x0 y0 x1 y1 prior confidence class), found {len(fields)}",
            )
        frame = _frame_of(path, number, fields[0], index)
        try:
            x0, y0, x1, y1, confidence = (float(v) for v in (*fields[1:5], fields[6]))
            detection = Detection((x0, y0, x1, y1), fields[7], Prior(fields[5]), confidence)
        except ValueError as exc:
            raise ProtocolError(path, number, f"bad box: {exc}") from None
        per_frame[frame].append(detection)
    return tuple(tuple(boxes) for boxes in per_frame)


@dataclass(frozen=True, eq=False)
class KeypointDecisions:
    """Per frame, the keypoints a tracker extracted and whether it kept each."""

    keypoints_px: tuple[np.ndarray, ...]
    """Per frame, (N, 2) pixel positions (x right, y down; pixel centres at integers)."""
    kept: tuple[np.ndarray, ...]
    reasons: tuple[tuple[str, ...], ...]


def write_keypoints(
    path: Path,
    timestamps_s: list[float],
    keypoints_px: list[np.ndarray],
    kept: list[np.ndarray],
    reasons: list[list[str]] | None = None,
) -> Path:
    """Keypoint decisions as the protocol's file (what a Python tracker writes; C++ ones
    print the same lines): per frame, each keypoint's position, 1 if kept, and a reason
    word (none, or one without spaces)."""
    lines = [KEYPOINTS_HEADER]
    for k, (stamp, points, flags) in enumerate(zip(timestamps_s, keypoints_px, kept, strict=True)):
        name = timestamp_name(stamp)
        why = reasons[k] if reasons is not None else [""] * len(points)
        for (x, y), flag, reason in zip(points, flags, why, strict=True):
            if reason and len(reason.split()) != 1:
                raise ValueError(f"a keypoint's reason is one word, not {reason!r}")
            lines.append(
                f"{name} {float(x)!r} {float(y)!r} {int(bool(flag))}{' ' + reason if reason else ''}\n"
            )
    path.write_text("".join(lines), encoding="utf-8")
    return path


def read_keypoints(path: Path, sequence: Sequence) -> KeypointDecisions:
    """A keypoint file, each line checked: a timestamp of a frame, a finite position inside
    the image, a kept flag of 0 or 1. A frame with no line has no keypoints."""
    index = _frame_index(sequence)
    width, height = sequence.intrinsics.width, sequence.intrinsics.height
    points: list[list[tuple[float, float]]] = [[] for _ in sequence.frames]
    flags: list[list[bool]] = [[] for _ in sequence.frames]
    reasons: list[list[str]] = [[] for _ in sequence.frames]
    for number, fields in _data_lines(path, MAX_KEYPOINTS_BYTES, "keypoint file", maxsplit=4):
        if len(fields) not in (4, 5):
            raise ProtocolError(
                path, number, f"expected timestamp x y kept [reason], found {len(fields)} fields"
            )
        frame = _frame_of(path, number, fields[0], index)
        try:
            x, y = float(fields[1]), float(fields[2])
        except ValueError:
            raise ProtocolError(
                path, number, f"position {fields[1]!r} {fields[2]!r} is not two numbers"
            ) from None
        if not (
            math.isfinite(x) and math.isfinite(y) and -0.5 <= x < width - 0.5 and -0.5 <= y < height - 0.5
        ):
            raise ProtocolError(
                path, number, f"keypoint ({fields[1]}, {fields[2]}) is not inside the {width}x{height} image"
            )
        if fields[3] not in ("0", "1"):
            raise ProtocolError(path, number, f"kept must be 1 or 0, got {fields[3]!r}")
        points[frame].append((x, y))
        flags[frame].append(fields[3] == "1")
        reasons[frame].append(fields[4].strip() if len(fields) == 5 else "")
    return KeypointDecisions(
        tuple(np.array(p, np.float64).reshape(-1, 2) for p in points),
        tuple(np.array(f, bool) for f in flags),
        tuple(tuple(r) for r in reasons),
    )


def _frame_index(sequence: Sequence) -> tuple[np.ndarray, np.ndarray]:
    stamps = sequence.timestamps_s
    order = np.argsort(stamps)
    return stamps[order], order


def _frame_of(path: Path, number: int, text: str, index: tuple[np.ndarray, np.ndarray]) -> int:
    stamps, order = index
    try:
        t = float(text)
    except ValueError:
        raise ProtocolError(path, number, f"timestamp {text!r} is not a number") from None
    if not math.isfinite(t):
        raise ProtocolError(path, number, f"timestamp {text!r} is not a finite number")
    k = int(np.searchsorted(stamps, t))
    for j in (k - 1, k):
        if 0 <= j < len(stamps) and abs(stamps[j] - t) <= TIMESTAMP_TOLERANCE_S:
            return int(order[j])
    raise ProtocolError(path, number, f"timestamp {text} is no frame's (within {TIMESTAMP_TOLERANCE_S} s)")


def _data_lines(path: Path, limit: int, what: str, maxsplit: int):
    """(line number, fields) of each data line; comments and blank lines skipped."""
    try:
        text = read_text(path, limit, what)
    except FileNotFoundError:
        raise ProtocolError(path, None, f"the {what} is missing") from None
    except FileError as exc:
        raise ProtocolError(path, exc.line, exc.problem) from None
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            yield number, stripped.split(maxsplit=maxsplit)


MAX_MAP_BYTES = 2048 * MIB
"""A program's map: 2 GiB is some 90M points of binary PLY, far above a dense map of a hall."""


def read_map(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The point cloud a program wrote at ``{map}``: a PLY (ASCII or binary) of points in the
    frame of its trajectory, with or without colours; (points (N, 3), colours (N, 3) uint8,
    grey where it gave none). Whatever the PLY reader cannot read is this file's problem,
    named (the reader raises all sorts on a damaged file)."""
    import os

    import trimesh
    from depotbench.core.files import open_regular

    os.close(open_regular(path, MAX_MAP_BYTES, "map"))
    try:
        cloud = trimesh.load(path, file_type="ply", process=False)
    except Exception as exc:  # noqa: BLE001 - any reader failure is the file's, said in one line
        raise ProtocolError(
            path, None, f"not a readable PLY point cloud ({type(exc).__name__}: {exc})"
        ) from None
    points = np.asarray(getattr(cloud, "vertices", np.zeros((0, 3))), dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or not len(points):
        raise ProtocolError(path, None, "holds no points")
    if not np.isfinite(points).all():
        raise ProtocolError(path, None, "holds a point that is not finite")
    colours = np.asarray(getattr(cloud, "colors", []))
    if colours.shape[:1] != (len(points),) or colours.ndim != 2 or colours.shape[1] < 3:
        colours = np.full((len(points), 3), 160, np.uint8)
    return points, colours[:, :3].astype(np.uint8)
