"""The files an external tracker reads and writes besides its trajectory
(docs/external-trackers.md): the detections the bench hands it, the keypoint
decisions it may hand back to be scored against the exact ground truth, and the time
it may say each frame took.

All are plain text a C++ program reads or writes with ``sscanf`` and ``<<``: one box or
one keypoint a line, the frame named by its RGB timestamp as in ``associations.txt``.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depotbench.core.errors import FileError
from depotbench.core.files import MAX_TEXT_BYTES, MIB, read_text
from depotbench.detectors.detection import Detection, Prior
from depotbench.eval.trackers.columns import WHITESPACE, Fields, blocks
from depotbench.sim.sequence import Sequence, timestamp_name
from depotbench.sim.tum_files import MAX_ABS_POSITION_M, QUATERNION_NORM_TOLERANCE
from scipy.spatial.transform import Rotation

DETECTIONS_HEADER = "# depotbench detections 1\n# timestamp x0 y0 x1 y1 prior confidence class\n"
KEYPOINTS_HEADER = "# depotbench keypoints 1\n# timestamp x y kept [reason]\n"
MAX_KEYPOINTS_BYTES = 1024 * MIB
"""A keypoint file: 300 frames of 1000 keypoints take about 9 MB, so 1 GiB is 30,000
frames of them; a larger file is refused before it is read."""
MAX_DETECTIONS_BYTES = 256 * MIB
TIMES_HEADER = "# depotbench times 1\n# timestamp ms\n"
MAX_TIMES_BYTES = 32 * MIB
"""A times file: a line takes about 30 bytes, so 32 MiB holds a million frames."""
MAX_FRAME_MS = 3_600_000.0
"""A frame's time may be up to an hour: more is a unit mistake (microseconds, say)."""
TIMESTAMP_TOLERANCE_S = 1e-3
"""How far a line's timestamp may be from its frame's (trajectories are matched alike)."""


class ProtocolError(FileError):
    """A file of the external-tracker protocol that cannot be read: names the file and line."""


@contextlib.contextmanager
def _protocol_file(path: Path, missing: str):
    """Any failure to read ``path`` as one ``ProtocolError`` naming it (``missing`` when it is
    not there), so that a program's file is its failure, not the reader's."""
    try:
        yield
    except FileNotFoundError:
        raise ProtocolError(path, None, missing) from None
    except ProtocolError:
        raise
    except FileError as exc:
        raise ProtocolError(path, exc.line, exc.problem) from None


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
    """Per frame, (N, 2) pixel positions (x right, y down; pixel centres at integers), as
    float32: a step of 0.001 px at 8192 px, finer than any detector, and half of float64's
    200 MB for the 12.7M keypoints of a 330 MB file."""
    kept: tuple[np.ndarray, ...]
    reason_codes: tuple[np.ndarray, ...]
    """Per frame, each keypoint's reason as an index into ``reason_names``: a code of 2
    bytes where a string object per keypoint took 8 bytes more and a 330 MB file holds 10M."""
    reason_names: tuple[str, ...] = ("",)
    """The reason words; the first, ``""``, is "none given"."""

    @property
    def reasons(self) -> tuple[tuple[str, ...], ...]:
        """Per frame, each keypoint's reason word (``""`` for none)."""
        return tuple(tuple(self.reason_names[c] for c in codes.tolist()) for codes in self.reason_codes)


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
    """A keypoint file, each line checked: the header line first, then per line a timestamp
    of a frame, a finite position inside the image, a kept flag of 0 or 1. A frame with no
    line has no keypoints.

    The file may be 1 GiB: it is read a block at a time (``columns``), twice. The first
    pass counts each frame's keypoints, so the second fills arrays made at their final
    size: gathered in pieces and joined, 12M keypoints left 150 MB of freed pieces in the
    process beside their 230 MB of arrays."""
    index = _frame_index(sequence)
    with _protocol_file(path, "the keypoint file is missing"):
        counts = _count_keypoints(path, index, len(sequence))
        points = [np.empty((n, 2), np.float32) for n in counts.tolist()]
        kept = [np.empty(n, bool) for n in counts.tolist()]
        codes = [np.empty(n, np.uint16) for n in counts.tolist()]
        filled = np.zeros(len(sequence), np.int64)
        names: dict[bytes, int] = {b"": 0}
        for fields in blocks(path, MAX_KEYPOINTS_BYTES, "keypoint file"):
            if len(fields):
                _keypoint_block(fields, sequence, index, names, (points, kept, codes), filled)
    if not np.array_equal(filled, counts):
        raise ProtocolError(path, None, "changed while it was read")
    reason_names = tuple(word.decode("utf-8") for word in sorted(names, key=names.__getitem__))
    return KeypointDecisions(tuple(points), tuple(kept), tuple(codes), reason_names)


def _count_keypoints(path: Path, index: tuple[np.ndarray, np.ndarray], frames: int) -> np.ndarray:
    """Each frame's number of keypoint lines, the header and each line's fields and
    timestamp checked on the way."""
    counts = np.zeros(frames, np.int64)
    header = False
    for fields in blocks(path, MAX_KEYPOINTS_BYTES, "keypoint file"):
        if not header:
            _check_header(path, fields.data)
            header = True
        if len(fields):
            bad = np.flatnonzero((fields.counts < 4) | (fields.counts > 5))
            if bad.size:
                found = fields.counts[bad[0]]
                raise fields.fail(bad[0], f"expected timestamp x y kept [reason], found {found} fields")
            counts += np.bincount(_frames_of(fields, index), minlength=frames)
    if not header:
        first = KEYPOINTS_HEADER.splitlines()[0]
        raise ProtocolError(path, None, f"is empty: a keypoint file begins with {first!r}")
    return counts


def _check_header(
    path: Path, data: bytes, header: str = KEYPOINTS_HEADER, what: str = "keypoint file"
) -> None:
    """The first line names the format and its version: a file of another version (or
    none) read as this one would be scored wrong without a word."""
    end = data.find(b"\n")
    first = data[: end if end >= 0 else len(data)].decode("utf-8", "replace").strip()
    expected = header.splitlines()[0]
    if first == expected:
        return
    words = first.split()
    if words[:3] == expected.split()[:3]:
        version = " ".join(words[3:]) or "(none)"
        raise ProtocolError(path, 1, f"{what} version {version} is unknown: this bench reads {expected!r}")
    raise ProtocolError(path, 1, f"the first line must be {expected!r}, not {first[:60]!r}")


def _keypoint_block(
    fields: Fields,
    sequence: Sequence,
    index: tuple[np.ndarray, np.ndarray],
    names: dict[bytes, int],
    slots: tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]],
    filled: np.ndarray,
) -> None:
    """One block's lines checked and written into their frames' arrays (``slots``: points,
    kept flags, reason codes), each filled up to ``filled``."""
    width, height = sequence.intrinsics.width, sequence.intrinsics.height
    if ((fields.counts < 4) | (fields.counts > 5)).any():
        raise fields.fail(0, "changed while it was read")
    frames = _frames_of(fields, index)
    x, y = fields.numbers(1, "x"), fields.numbers(2, "y")
    with np.errstate(invalid="ignore"):
        inside = np.isfinite(x) & np.isfinite(y) & (x >= -0.5) & (x < width - 0.5)
        inside &= (y >= -0.5) & (y < height - 0.5)
    if not inside.all():
        row = int(np.flatnonzero(~inside)[0])
        shown = " ".join(fields.text(j)[row].decode("utf-8", "replace") for j in (1, 2))
        raise fields.fail(
            row, f"keypoint ({shown.replace(' ', ', ')}) is not inside the {width}x{height} image"
        )
    flag = fields.text(3)
    kept = flag == b"1"
    wrong = ~kept & (flag != b"0")
    if wrong.any():
        row = int(np.flatnonzero(wrong)[0])
        raise fields.fail(row, f"kept must be 1 or 0, got {flag[row].decode('utf-8', 'replace')!r}")
    codes = np.zeros(len(fields), np.uint16)
    worded = np.flatnonzero(fields.counts == 5)
    if worded.size:
        words, inverse = np.unique(fields.text(4, worded), return_inverse=True)
        for word in words.tolist():
            if word not in names:
                try:
                    word.decode("utf-8")
                except UnicodeDecodeError:
                    row = int(worded[np.flatnonzero(fields.text(4, worded) == word)[0]])
                    raise fields.fail(row, "the reason is not UTF-8 text") from None
                if len(names) > MAX_REASONS:
                    raise fields.fail(int(worded[0]), f"more than {MAX_REASONS} different reasons")
                names[word] = len(names)
        codes[worded] = np.array([names[w] for w in words.tolist()], np.uint16)[inverse]
    order = np.argsort(frames, kind="stable")
    sorted_frames = frames[order]
    cuts = np.flatnonzero(np.diff(sorted_frames)) + 1
    for run in np.split(np.arange(len(order)), cuts):
        rows, frame = order[run], int(sorted_frames[run[0]])
        begin, end = int(filled[frame]), int(filled[frame]) + len(rows)
        if end > len(slots[1][frame]):
            raise fields.fail(int(rows[0]), "changed while it was read")
        slots[0][frame][begin:end, 0], slots[0][frame][begin:end, 1] = x[rows], y[rows]
        slots[1][frame][begin:end], slots[2][frame][begin:end] = kept[rows], codes[rows]
        filled[frame] = end


MAX_REASONS = 65535
"""Different reason words in one file: a reason's code is 2 bytes."""


def write_times(path: Path, timestamps_s: list[float], times_ms: list[float]) -> Path:
    """Per-frame times as the protocol's file (what a Python tracker writes): the header,
    then a frame's RGB timestamp and the milliseconds it took, one frame a line."""
    lines = [TIMES_HEADER]
    lines += [f"{timestamp_name(t)} {float(ms)!r}\n" for t, ms in zip(timestamps_s, times_ms, strict=True)]
    path.write_text("".join(lines), encoding="utf-8")
    return path


def read_times(path: Path, sequence: Sequence) -> np.ndarray:
    """The time (ms) a program says each frame took, NaN for a frame it gave none, each line
    checked: the header line first, then a timestamp of a frame (within
    ``TIMESTAMP_TOLERANCE_S``), one line a frame, and a finite time in [0, ``MAX_FRAME_MS``]."""
    index = _frame_index(sequence)
    line_of_frame = np.zeros(len(sequence), np.int64)
    times = np.full(len(sequence), np.nan)
    header = False
    with _protocol_file(path, "the times file is missing"):
        for fields in blocks(path, MAX_TIMES_BYTES, "times file"):
            if not header:
                _check_header(path, fields.data, TIMES_HEADER, "times file")
                header = True
            if len(fields):
                _times_block(fields, index, line_of_frame, times)
    if not header:
        raise ProtocolError(
            path, None, f"is empty: a times file begins with {TIMES_HEADER.splitlines()[0]!r}"
        )
    return times


def _times_block(
    fields: Fields, index: tuple[np.ndarray, np.ndarray], line_of_frame: np.ndarray, times: np.ndarray
) -> None:
    bad = np.flatnonzero(fields.counts != 2)
    if bad.size:
        raise fields.fail(bad[0], f"expected 2 fields (timestamp ms), found {fields.counts[bad[0]]}")
    frames = _frames_of(fields, index)
    ms = fields.numbers(1, "time")
    with np.errstate(invalid="ignore"):
        wrong = ~((ms >= 0.0) & (ms <= MAX_FRAME_MS))
    if wrong.any():
        row = int(np.flatnonzero(wrong)[0])
        text = fields.text(1)[row].decode("utf-8", "replace")
        raise fields.fail(row, f"time {text} ms is not a finite number in [0, {MAX_FRAME_MS:.0f}]")
    _one_line_a_frame(fields, frames, line_of_frame, "time")
    times[frames] = ms


def _one_line_a_frame(fields: Fields, frames: np.ndarray, line_of_frame: np.ndarray, what: str) -> None:
    """Refuse a line for a frame that has one already (in an earlier block, or earlier in
    this one), naming both lines; then note this block's lines as their frames'."""
    earlier = line_of_frame[frames].copy()
    order = np.argsort(frames, kind="stable")
    same = frames[order[1:]] == frames[order[:-1]]
    later, before = order[1:][same], order[:-1][same]
    earlier[later] = np.where(earlier[later] > 0, earlier[later], fields.lines[before])
    if (earlier > 0).any():
        row = int(np.flatnonzero(earlier > 0)[0])
        text = fields.text(0)[row].decode("utf-8", "replace")
        raise fields.fail(
            row,
            f"timestamp {text} is frame {int(frames[row])}'s again, whose {what} is on line "
            f"{int(earlier[row])} (one {what} a frame)",
        )
    line_of_frame[frames] = fields.lines


def _frame_index(sequence: Sequence) -> tuple[np.ndarray, np.ndarray]:
    stamps = sequence.timestamps_s
    order = np.argsort(stamps)
    return stamps[order], order


def _frames_of(fields: Fields, index: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Each line's frame, from its timestamp (within ``TIMESTAMP_TOLERANCE_S``); the first
    that is not finite or no frame's is named."""
    stamps, order = index
    t = fields.numbers(0, "timestamp", repeated=True)
    k = np.searchsorted(stamps, t)
    below, above = np.clip(k - 1, 0, len(stamps) - 1), np.clip(k, 0, len(stamps) - 1)
    with np.errstate(invalid="ignore"):
        near_below = (k >= 1) & (np.abs(stamps[below] - t) <= TIMESTAMP_TOLERANCE_S)
        near_above = (k < len(stamps)) & (np.abs(stamps[above] - t) <= TIMESTAMP_TOLERANCE_S)
    unmatched = ~(near_below | near_above)
    if unmatched.any():
        row = int(np.flatnonzero(unmatched)[0])
        text = fields.text(0)[row].decode("utf-8", "replace")
        if not np.isfinite(t[row]):
            raise fields.fail(row, f"timestamp {text!r} is not a finite number")
        raise fields.fail(row, f"timestamp {text} is no frame's (within {TIMESTAMP_TOLERANCE_S} s)")
    return order[np.where(near_below, below, above)]


def _frame_of(path: Path, number: int, text: str, index: tuple[np.ndarray, np.ndarray]) -> int:
    """One line's frame (the detections file, which the bench writes, is read line by line)."""
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


def read_trajectory(path: Path, sequence: Sequence) -> tuple[np.ndarray | None, ...]:
    """A program's TUM trajectory as each frame's pose (``world_from_camera``, None where it
    has none), each line checked as the protocol says: 8 finite fields, a timestamp of a
    frame (within ``TIMESTAMP_TOLERANCE_S``), one pose a frame, a unit quaternion (within
    ``QUATERNION_NORM_TOLERANCE``). A pose at no frame's time or a second one for a frame
    would be dropped or chosen between without a word, and a quaternion far from unit
    length is no rotation the program meant. Ground truth and evo's inputs are read by
    ``read_tum``, which keeps TUM's and evo's leniency."""
    index = _frame_index(sequence)
    line_of_frame = np.zeros(len(sequence), np.int64)  # 0: no pose yet
    poses = np.tile(np.eye(4), (len(sequence), 1, 1))
    with _protocol_file(path, "the trajectory is missing"):
        # Commas separate fields too, as in TUM's own tools.
        for fields in blocks(path, MAX_TEXT_BYTES, "trajectory", WHITESPACE + b","):
            if len(fields):
                _trajectory_block(fields, index, line_of_frame, poses)
    return tuple(None if line == 0 else poses[i] for i, line in enumerate(line_of_frame.tolist()))


def _trajectory_block(
    fields: Fields, index: tuple[np.ndarray, np.ndarray], line_of_frame: np.ndarray, poses: np.ndarray
) -> None:
    bad = np.flatnonzero(fields.counts != 8)
    if bad.size:
        raise fields.fail(
            bad[0], f"expected 8 fields (timestamp tx ty tz qx qy qz qw), found {fields.counts[bad[0]]}"
        )
    frames = _frames_of(fields, index)
    values = np.stack([fields.numbers(j, "field") for j in range(1, 8)], axis=1)
    with np.errstate(invalid="ignore", over="ignore"):
        norms = np.linalg.norm(values[:, 3:], axis=1)
        checks = (
            (~np.isfinite(values).all(axis=1), lambda r: "pose holds NaN or infinity"),
            (
                np.abs(values[:, :3]).max(axis=1) > MAX_ABS_POSITION_M,
                lambda r: f"position is beyond +-{MAX_ABS_POSITION_M:g} m",
            ),
            (
                ~(np.abs(norms - 1.0) <= QUATERNION_NORM_TOLERANCE),
                lambda r: (
                    f"quaternion (qx qy qz qw) has norm {norms[r]:.6g}, not 1 "
                    f"(within {QUATERNION_NORM_TOLERANCE:g})"
                ),
            ),
        )
    for wrong, problem in checks:
        if wrong.any():
            row = int(np.flatnonzero(wrong)[0])
            raise fields.fail(row, problem(row))
    _one_line_a_frame(fields, frames, line_of_frame, "pose")
    quats = values[:, 3:] / norms[:, None]
    poses[frames, :3, :3] = Rotation.from_quat(quats).as_matrix()
    poses[frames, :3, 3] = values[:, :3]


def _data_lines(path: Path, limit: int, what: str, maxsplit: int):
    """(line number, fields) of each data line; comments and blank lines skipped."""
    with _protocol_file(path, f"the {what} is missing"):
        text = read_text(path, limit, what)
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            yield number, stripped.split(maxsplit=maxsplit)


MAX_MAP_BYTES = 2048 * MIB
"""A program's map: 2 GiB is some 90M points of binary PLY, far above a dense map of a hall."""


def read_map(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The point cloud a program wrote at ``{map}``: a PLY (ASCII or binary) of points in the
    frame of its trajectory, with or without colours; (points (N, 3), colours (N, 3) uint8,
    grey where it gave none). Read in chunks (``ply``); a layout that reader leaves aside
    goes to trimesh, and whatever that cannot read is this file's problem, named (it raises
    all sorts on a damaged file)."""
    from depotbench.eval.trackers.ply import NotHere, read_ply_points

    with _protocol_file(path, "the map is missing (a link to nothing?)"):
        try:
            points, colours = read_ply_points(path, MAX_MAP_BYTES)
        except NotHere:
            points = colours = None
    if points is None:  # a layout the chunked reader leaves aside
        points, colours = _read_map_whole(path)
    if not len(points):
        raise ProtocolError(path, None, "holds no points")
    if not np.isfinite(points).all():
        raise ProtocolError(path, None, "holds a point that is not finite")
    return points, colours


def _read_map_whole(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    try:
        cloud = trimesh.load(path, file_type="ply", process=False)
    except Exception as exc:  # noqa: BLE001 - any reader failure is the file's, said in one line
        raise ProtocolError(
            path, None, f"not a readable PLY point cloud ({type(exc).__name__}: {exc})"
        ) from None
    points = np.asarray(getattr(cloud, "vertices", np.zeros((0, 3))), dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ProtocolError(path, None, "holds no points")
    colours = np.asarray(getattr(cloud, "colors", []))
    if colours.shape[:1] != (len(points),) or colours.ndim != 2 or colours.shape[1] < 3:
        colours = np.full((len(points), 3), 160, np.uint8)
    return points, colours[:, :3].astype(np.uint8)
