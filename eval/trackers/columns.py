"""A program's text files read in bounded memory: blocks of whole lines, split into fields
with NumPy instead of one Python string per field.

A keypoint file may be 1 GiB; read whole and split into strings, 330 MB of it cost 3.2 GB
of memory. Here a block of 1 MiB is held at a time, its fields located by byte arithmetic
and converted column by column, so the cost beyond the result is a few tens of MB.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from depotbench.core.errors import FileError

BLOCK_BYTES = 1 << 20
"""Bytes read at a time; the arrays made from one block take about 40 times that."""
MAX_LINE_BYTES = 1 << 16
"""A line longer than 64 KiB is refused (a data line of either file takes under 100 bytes)."""
MAX_FIELD_CHARS = 64
"""A field longer than this is refused: a double needs 24 characters, and a column is
converted as a fixed-width array whose width is its longest field."""
WHITESPACE = b" \t\r\x0b\x0c"
"""Field separators, as ``bytes.split()`` and C's ``isspace`` have them (``\\n`` ends a line)."""


class ColumnsError(FileError):
    """A line of a program's file that cannot be read: names the file and the line."""


def blocks(
    path: Path,
    limit: int,
    what: str,
    separators: bytes = WHITESPACE,
    start: tuple[int, int] = (0, 1),
) -> Iterator[Fields]:
    """The file's data lines (not blank, not starting with ``#``), a block at a time, from
    ``start`` (a byte offset and the number of the line there). The file must be a regular
    one of at most ``limit`` bytes (a FIFO or a device is refused without blocking).
    ``FileNotFoundError`` propagates, for the caller to say what the missing file was for."""
    from depotbench.core.files import open_regular

    with os.fdopen(open_regular(path, limit, what), "rb") as handle:
        handle.seek(start[0])
        carry, line, total = b"", start[1], start[0]
        while True:
            try:
                chunk = handle.read(BLOCK_BYTES)
            except OSError as exc:
                raise ColumnsError(path, None, f"cannot be read ({exc.strerror or exc})") from None
            total += len(chunk)
            if total > limit:
                raise ColumnsError(path, None, f"grew beyond the limit for a {what} while read")
            data = carry + chunk
            cut = data.rfind(b"\n") + 1 if chunk else len(data)  # the last line may lack its newline
            if cut:
                yield Fields(path, data[:cut], line, separators)
                line += data.count(b"\n", 0, cut)
            carry = data[cut:]
            if len(carry) > MAX_LINE_BYTES:
                raise ColumnsError(path, line, f"is longer than {MAX_LINE_BYTES} bytes")
            if not chunk:
                return


class Fields:
    """The data lines of one block: their line numbers, how many fields each has, and each
    column as an array. Lines are numbered from 1 in the file."""

    def __init__(self, path: Path, data: bytes, first_line: int, separators: bytes = WHITESPACE) -> None:
        self.path = path
        self.data = data
        table = np.zeros(256, bool)
        table[list(separators + b"\n")] = True
        raw = np.frombuffer(data, np.uint8)
        space = table[raw]
        # Bytes of a field: a start follows a separator (or the block's start), an end
        # precedes one. bytes.split() finds the same fields, one object each.
        starts = np.flatnonzero(~space & np.concatenate(([True], space[:-1])))
        ends = np.flatnonzero(~space & np.concatenate((space[1:], [True]))) + 1
        newlines = np.flatnonzero(raw == 10)
        field_line = np.searchsorted(newlines, starts)  # the newlines before a field: its line
        first = np.ones(len(field_line), bool)  # a line's first field
        first[1:] = field_line[1:] != field_line[:-1]
        comments = np.zeros(len(newlines) + 1, bool)
        comments[field_line[first & (raw[starts] == ord("#"))]] = True
        data_field = ~comments[field_line]
        self._raw = raw
        self._starts, self._ends = starts[data_field], ends[data_field]
        self._first = np.flatnonzero(first[data_field])
        """Index of each data line's first field (fields come in line order)."""
        self.counts = np.diff(np.append(self._first, len(self._starts)))
        self.lines = field_line[data_field][self._first] + first_line
        """(L,) the file's line number of each data line."""

    def __len__(self) -> int:
        return len(self.lines)

    def fail(self, row: int, problem: str) -> ColumnsError:
        return ColumnsError(self.path, int(self.lines[row]), problem)

    def text(self, column: int, rows: np.ndarray | None = None) -> np.ndarray:
        """The ``column``-th field of each line (of ``rows``; each has that many fields) as
        a fixed-width bytes array."""
        index = self._first + column if rows is None else self._first[rows] + column
        starts, ends = self._starts[index], self._ends[index]
        if not len(index):
            return np.zeros(0, "S1")
        widths = ends - starts
        longest = int(widths.argmax())
        if widths[longest] > MAX_FIELD_CHARS:
            row = longest if rows is None else int(rows[longest])
            raise self.fail(row, f"field {column + 1} is longer than {MAX_FIELD_CHARS} characters")
        width = max(int(widths[longest]), 1)
        offsets = np.arange(width)
        gathered = self._raw[np.minimum(starts[:, None] + offsets, len(self._raw) - 1)]
        gathered[offsets >= widths[:, None]] = 0
        return gathered.view(f"S{width}").ravel()

    def numbers(
        self, column: int, what: str, repeated: bool = False, rows: np.ndarray | None = None
    ) -> np.ndarray:
        """The ``column``-th field of every line (of ``rows``) as float64; the first that is
        not a number is named with its line. ``repeated``: a column of few distinct values (a
        frame's timestamp on each of its keypoints), converted once each."""
        text = self.text(column, rows)
        try:
            if repeated:
                distinct, inverse = np.unique(text, return_inverse=True)
                return distinct.astype(np.float64)[inverse]
            return text.astype(np.float64)
        except ValueError:
            for row, field in enumerate(text):
                try:
                    float(field)
                except ValueError:
                    raise self.fail(
                        row if rows is None else int(rows[row]),
                        f"{what} {field.decode('utf-8', 'replace')!r} is not a number",
                    ) from None
            raise
