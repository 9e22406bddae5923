"""Reading and writing TUM RGB-D text files (frame lists and pose files).

Parsing follows TUM's own tools (``associate.py``): ``#`` starts a comment
line, and commas, tabs and repeated spaces all separate fields. Every error
names the file and the 1-based line.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depotbench.core.errors import FileError, SequenceFormatError
from depotbench.core.files import MAX_TEXT_BYTES, MAX_TEXT_LINES, read_text

MAX_ABS_POSITION_M = 1e9
"""Positions beyond this are refused: their squares would overflow the error statistics."""
QUATERNION_NORM_TOLERANCE = 1e-3
"""How far from 1 a stored quaternion's norm may be (TUM files keep 4 decimals)."""


@dataclass(frozen=True)
class Row:
    line: int
    fields: tuple[str, ...]


def read_rows(path: Path, n_fields: int) -> list[Row]:
    """The data rows of a TUM text file, each checked to hold ``n_fields`` fields."""
    return [Row(number, fields) for number, fields in _rows(_text_lines(path), path, n_fields)]


def _text_lines(path: Path) -> list[str]:
    try:
        text = read_text(path, MAX_TEXT_BYTES, "TUM text file")
    except FileNotFoundError:
        raise SequenceFormatError(path, None, "file is missing") from None
    except FileError as exc:
        raise SequenceFormatError(path, None, exc.problem) from None
    if text.count("\n") > MAX_TEXT_LINES:
        raise SequenceFormatError(path, None, f"has more than the limit of {MAX_TEXT_LINES} lines")
    return text.splitlines()


def _rows(lines: list[str], path: Path, n_fields: int) -> Iterator[tuple[int, list[str]]]:
    """(1-based line, fields) of each data row, one at a time: a caller that keeps numbers
    keeps no strings (a Row of 8 field strings costs ~700 bytes, 280 MB for 400,000 poses)."""
    for number, raw in enumerate(lines, start=1):
        stripped = raw.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = stripped.replace(",", " ").replace("\t", " ").split()
        if len(fields) != n_fields:
            raise SequenceFormatError(
                path, number, f"expected {n_fields} fields, found {len(fields)}: {stripped!r}"
            )
        yield number, fields


def parse_float(path: Path, row: Row, index: int, what: str) -> float:
    try:
        return float(row.fields[index])
    except ValueError:
        raise SequenceFormatError(path, row.line, f"{what} {row.fields[index]!r} is not a number") from None


def parse_timestamp(path: Path, row: Row, index: int) -> float:
    """A timestamp field: a finite number (``nan`` would pass every order check, as any
    comparison with NaN is false, and ``inf`` cannot be paired with a frame)."""
    value = parse_float(path, row, index, "timestamp")
    if not np.isfinite(value):
        raise SequenceFormatError(path, row.line, f"timestamp {row.fields[index]!r} is not a finite number")
    return value


def check_increasing(path: Path, timestamps: np.ndarray, lines: list[int]) -> None:
    """Refuse unsorted, duplicate or non-finite timestamps, naming the offending line."""
    finite = np.isfinite(timestamps)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise SequenceFormatError(path, lines[i], f"timestamp {timestamps[i]} is not a finite number")
    bad = np.flatnonzero(~(np.diff(timestamps) > 0))
    if bad.size:
        i = int(bad[0])
        kind = "duplicates" if timestamps[i + 1] == timestamps[i] else "is earlier than"
        raise SequenceFormatError(
            path,
            lines[i + 1],
            f"timestamp {timestamps[i + 1]:.6f} {kind} {timestamps[i]:.6f} on line {lines[i]}"
            " (timestamps must increase)",
        )


@dataclass(frozen=True, eq=False)
class FrameList:
    """A ``# timestamp filename`` list (rgb.txt, depth.txt)."""

    timestamps_s: np.ndarray
    filenames: tuple[str, ...]
    lines: tuple[int, ...]


def read_frame_list(path: Path) -> FrameList:
    rows = read_rows(path, 2)
    if not rows:
        raise SequenceFormatError(path, None, "lists no frames")
    stamps = np.array([parse_timestamp(path, r, 0) for r in rows])
    lines = [r.line for r in rows]
    check_increasing(path, stamps, lines)
    return FrameList(stamps, tuple(r.fields[1] for r in rows), tuple(lines))


def write_frame_list(path: Path, title: str, timestamps_s: np.ndarray, filenames: list[str]) -> None:
    header = f"# {title}\n# file: 'depotbench'\n# timestamp filename\n"
    body = "".join(f"{t:.6f} {name}\n" for t, name in zip(timestamps_s, filenames, strict=True))
    path.write_text(header + body, encoding="utf-8")


@dataclass(frozen=True, eq=False)
class PoseTable:
    """Rows of a TUM pose file: ``timestamp tx ty tz qx qy qz qw``."""

    timestamps_s: np.ndarray
    positions_m: np.ndarray
    quats_xyzw: np.ndarray
    lines: tuple[int, ...]


def read_pose_file(path: Path, *, strict: bool) -> PoseTable:
    """Read a TUM pose file.

    ``strict`` (sequence ground truth) also refuses unsorted or duplicate
    timestamps and quaternions whose norm is off 1 by more than
    ``QUATERNION_NORM_TOLERANCE``. Otherwise (SLAM estimates) quaternions are
    only required to have a norm in (1e-9, 1e9); they are normalised by the
    consumer, as evo does. Non-finite values are always refused.
    """
    text_lines = _text_lines(path)
    values = np.empty((len(text_lines), 8), dtype=np.float64)  # rows fill it, numbers only
    numbers: list[int] = []
    for k, (number, fields) in enumerate(_rows(text_lines, path, 8)):
        for i, field in enumerate(fields):
            try:
                values[k, i] = float(field)
            except ValueError:
                raise SequenceFormatError(path, number, f"field {field!r} is not a number") from None
        numbers.append(number)
    del text_lines
    if not numbers:
        raise SequenceFormatError(path, None, "holds no poses")
    values = values[: len(numbers)].copy()
    lines = tuple(numbers)
    finite = np.isfinite(values).all(axis=1)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise SequenceFormatError(path, lines[i], "pose holds NaN or infinity")
    large = np.abs(values[:, 1:4]).max(axis=1) > MAX_ABS_POSITION_M
    if large.any():
        i = int(np.flatnonzero(large)[0])
        raise SequenceFormatError(path, lines[i], f"position is beyond +-{MAX_ABS_POSITION_M:g} m")
    with np.errstate(over="ignore"):
        norms = np.linalg.norm(values[:, 4:8], axis=1)
    if strict:
        check_increasing(path, values[:, 0], list(lines))
        off = np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE
    else:
        off = ~((norms > 1e-9) & (norms < 1e9))  # normalisable without overflow
    if off.any():
        i = int(np.flatnonzero(off)[0])
        raise SequenceFormatError(path, lines[i], f"quaternion (qx qy qz qw) has norm {norms[i]:.6g}, not 1")
    return PoseTable(values[:, 0], values[:, 1:4], values[:, 4:8], lines)


def write_pose_file(
    path: Path,
    timestamps_s: np.ndarray,
    positions_m: np.ndarray,
    quats_xyzw: np.ndarray,
    header: str = "trajectory",
) -> None:
    """Write a TUM pose file; fixed formatting keeps output byte-reproducible."""
    lines = [f"# {header}", "# timestamp tx ty tz qx qy qz qw"]
    for t, p, q in zip(timestamps_s, positions_m, quats_xyzw, strict=True):
        lines.append(f"{t:.6f} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
