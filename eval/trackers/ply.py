"""A program's map as a PLY point cloud (``{map}``), read in bounded memory.

A map may be 2 GiB. A general mesh reader (trimesh) holds the whole file, its parsed
table and the result at once: a 150 MB binary map of 10M points cost 0.9 GB. Here the
vertex element is read a chunk at a time into the result's arrays (binary: 1M vertices a
read; ASCII: blocks of lines, ``columns``), so the cost beyond the result is a chunk. The
layouts read so are those a SLAM program writes: vertices first, scalar properties. Any
other PLY (an element before the vertices, a list property among them) goes to trimesh.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depotbench.core.errors import FileError
from depotbench.core.files import open_regular
from depotbench.eval.trackers.columns import blocks

PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
"""PLY's scalar types (both spellings) as NumPy's, byte order left to the format."""
MAX_HEADER_BYTES = 64 * 1024
"""A PLY header is a few hundred bytes; one without ``end_header`` in 64 KiB is not PLY."""
CHUNK_VERTICES = 1 << 20
"""Vertices read at a time from a binary PLY: 15-27 MB of file, 24 MB of points."""
GREY = 160
"""The colour of points a map gives none for."""


class NotHere(Exception):
    """A valid PLY of a layout this reader leaves to the general one."""


@dataclass(frozen=True)
class Header:
    format: str
    """``ascii``, ``binary_little_endian`` or ``binary_big_endian``."""
    vertices: int
    properties: tuple[tuple[str, str], ...]
    """The vertex element's (name, NumPy type) in file order."""
    data_offset: int
    """The byte where the vertex data begins."""
    lines: int
    """Lines of the header (ASCII data begins on the next)."""

    def dtype(self) -> np.dtype:
        order = ">" if self.format == "binary_big_endian" else "<"
        return np.dtype([(name, order + kind) for name, kind in self.properties])


def read_ply_points(path: Path, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """(points (N, 3) float64, colours (N, 3) uint8) of the vertex element; ``FileError``
    for a file that is not a PLY point cloud or is cut short; ``NotHere`` for a layout left
    to the general reader."""
    fd = open_regular(path, limit, "map")
    with os.fdopen(fd, "rb") as handle:
        size = os.fstat(handle.fileno()).st_size
        header = _header(path, handle.read(MAX_HEADER_BYTES))
        if header.format == "ascii":
            return _ascii(path, header, limit)
        itemsize = header.dtype().itemsize
        if size < header.data_offset + header.vertices * itemsize:
            raise FileError(
                path,
                None,
                f"is cut short: {header.vertices} vertices of {itemsize} bytes need "
                f"{header.data_offset + header.vertices * itemsize} bytes, the file has {size}",
            )
        handle.seek(header.data_offset)
        points, colours = _arrays(header)
        for begin in range(0, header.vertices, CHUNK_VERTICES):
            count = min(CHUNK_VERTICES, header.vertices - begin)
            chunk = np.fromfile(handle, header.dtype(), count)
            _fill(points, colours, begin, {name: chunk[name] for name in chunk.dtype.names})
        return points, colours


def _header(path: Path, head: bytes) -> Header:
    def bad(problem: str) -> FileError:
        return FileError(path, None, f"not a readable PLY point cloud ({problem})")

    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise bad("no PLY header ending in end_header")
    stop = head.find(b"\n", end)
    if stop < 0:
        raise bad("no PLY header ending in end_header")
    lines = head[:stop].decode("ascii", "replace").splitlines()
    form, elements = None, []
    for line in lines[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info", "end_header"):
            continue
        if words[0] == "format" and len(words) == 3:
            form = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) >= 3:
            elements[-1][2].append(words[1:])
        else:
            raise bad(f"header line {line.strip()[:60]!r}")
    if form not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise bad(f"format {form!r}")
    if not elements or elements[0][0] != "vertex":
        if any(name == "vertex" for name, _, _ in elements):
            raise NotHere
        raise bad("no vertex element")
    _, count, properties = elements[0]
    if any(p[0] == "list" or p[0] not in PLY_TYPES or len(p) != 2 for p in properties):
        raise NotHere
    typed = tuple((p[1], PLY_TYPES[p[0]]) for p in properties)
    names = [name for name, _ in typed]
    if not {"x", "y", "z"} <= set(names) or len(set(names)) != len(names):
        raise bad("the vertices have no x, y and z, or a property twice")
    return Header(form, count, typed, stop + 1, len(lines))


def _arrays(header: Header) -> tuple[np.ndarray, np.ndarray]:
    return np.empty((header.vertices, 3)), np.full((header.vertices, 3), GREY, np.uint8)


def _fill(points: np.ndarray, colours: np.ndarray, begin: int, columns: dict[str, np.ndarray]) -> None:
    end = begin + len(columns["x"])
    for axis, name in enumerate("xyz"):
        points[begin:end, axis] = columns[name]
    if all(name in columns for name in ("red", "green", "blue")):
        for channel, name in enumerate(("red", "green", "blue")):
            colours[begin:end, channel] = np.clip(np.nan_to_num(columns[name]), 0, 255)


def _ascii(path: Path, header: Header, limit: int) -> tuple[np.ndarray, np.ndarray]:
    points, colours = _arrays(header)
    names = [name for name, _ in header.properties]
    wanted = [n for n in ("x", "y", "z", "red", "green", "blue") if n in names]
    done = 0
    start = (header.data_offset, header.lines + 1)
    for fields in blocks(path, limit, "map", start=start):
        if done == header.vertices:
            break
        rows = np.arange(min(len(fields), header.vertices - done))
        wrong = np.flatnonzero(fields.counts[rows] != len(names))
        if wrong.size:
            found = fields.counts[wrong[0]]
            raise fields.fail(int(wrong[0]), f"a vertex has {len(names)} properties, this line {found}")
        columns = {n: fields.numbers(names.index(n), n, rows=rows) for n in wanted}
        _fill(points, colours, done, columns)
        done += len(rows)
    if done < header.vertices:
        raise FileError(path, None, f"is cut short: {header.vertices} vertices declared, {done} found")
    return points, colours
