"""Reading user files within bounds, and writing JSON that every JSON reader accepts.

Every file a user hands in is checked before it is read: it must be a regular
file (``/dev/zero`` or a FIFO would be read forever) no larger than the limit
for its kind, and an image's header is read before its pixels. Each limit, when
hit, is named in the error.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import stat
import struct
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from depotbench.core.errors import FileError

DEFAULT_PNG_COMPRESSION = 1
"""zlib level (0-9) of the PNGs a sequence is written with (libdeflate, sim/png.py). Level 1
makes a frame's files about 0.3 of level 0's size and encodes nearly as fast; higher
levels are slower for a few percent less."""
KIB = 1024
MIB = 1024 * KIB

MAX_TEXT_BYTES = 32 * MIB
"""TUM lists and pose files: 100,000 frames of poses take about 11 MB."""
MAX_TEXT_LINES = 500_000
"""Lines of a TUM list or pose file (TUM's longest ground truth has about 16,000)."""
MAX_SPEC_BYTES = 1 * MIB
"""Scenario, suite and settings files (YAML or JSON)."""
MAX_META_BYTES = 16 * MIB
"""A sequence's meta.json (it holds the scenario and the instance table)."""
MAX_RECORD_BYTES = 4 * MIB
"""One line of gt/objects.jsonl (one frame's objects)."""
MAX_IMAGE_BYTES = 64 * MIB
"""One PNG frame; its decoded size is bounded by the header check."""


def _limit_text(limit: int) -> str:
    return f"{limit // MIB} MiB" if limit >= MIB else f"{limit // KIB} KiB"


def open_regular(path: Path, limit: int, what: str) -> int:
    """A file descriptor on ``path``, refused unless it is a regular file of at most ``limit`` bytes.

    ``O_NONBLOCK`` keeps a FIFO from blocking the open; ``FileNotFoundError`` propagates so
    that callers can say what the missing file was for.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise FileError(path, None, f"is a directory, not a {what}")
        if not stat.S_ISREG(info.st_mode):
            raise FileError(path, None, f"is not a regular file (a device, pipe or socket), not a {what}")
        if info.st_size > limit:
            raise FileError(
                path,
                None,
                f"is {info.st_size} bytes, more than the {_limit_text(limit)} limit for a {what}",
            )
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_bytes(path: Path, limit: int, what: str) -> bytes:
    """The whole file, size-checked before it is read (and again while, should it grow).

    The first read asks for the size ``fstat`` gave, not the limit: a buffered read of ``n``
    bytes allocates ``n`` up front, so a 1 TiB limit would cost 1 TiB for a 10-byte file."""
    fd = open_regular(path, limit, what)
    try:
        with os.fdopen(fd, "rb") as handle:
            size = os.fstat(handle.fileno()).st_size
            data = handle.read(size + 1)
            if (len(data) > size or size == 0) and len(data) <= limit:  # it grew (or says 0
                data += handle.read(limit + 1 - len(data))  # bytes, as /proc files do): read on
    except OSError as exc:  # /proc/self/mem says it is a file of 0 bytes, then refuses to be read
        raise FileError(path, None, f"cannot be read ({exc.strerror or exc})") from None
    if len(data) > limit:
        raise FileError(path, None, f"grew beyond the {_limit_text(limit)} limit for a {what} while read")
    return data


def file_digest(path: Path, what: str, limit: int = 1 << 40) -> bytes:
    """SHA-256 of a regular file's bytes, read in blocks (a device or pipe is refused).

    Cache and row keys hash content, not stat: two writes of the same size inside one
    kernel clock tick (4 ms here) leave the size and mtime unchanged.
    """
    fd = open_regular(path, limit, what)
    try:
        with os.fdopen(fd, "rb") as handle:
            return hashlib.file_digest(handle, "sha256").digest()
    except OSError as exc:
        raise FileError(path, None, f"cannot be read ({exc.strerror or exc})") from None


def read_text(path: Path, limit: int, what: str) -> str:
    data = read_bytes(path, limit, what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FileError(path, None, f"not a text file ({exc.reason} at byte {exc.start})") from None


def read_json(path: Path, limit: int, what: str) -> Any:
    """A JSON file's value, read as ``read_text`` reads (a regular file, bounded, UTF-8);
    malformed or too deeply nested JSON (a few thousand ``[``, which CPython's parser
    recurses on) is a ``FileError`` naming the file, as a refused file is."""
    text = read_text(path, limit, what)
    try:
        return json.loads(text)
    except RecursionError:
        raise FileError(path, None, f"is nested too deeply to be a {what}") from None
    except ValueError as exc:
        raise FileError(path, None, f"is not a {what} (not valid JSON: {exc})") from None


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_COLOR_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}


def png_header(path: Path) -> tuple[int, int, int, int]:
    """(width, height, bit depth, channels) read from the IHDR chunk, before any pixel."""
    fd = open_regular(path, MAX_IMAGE_BYTES, "PNG image")
    try:
        with os.fdopen(fd, "rb") as handle:
            head = handle.read(33)
    except OSError as exc:
        raise FileError(path, None, f"cannot be read ({exc.strerror or exc})") from None
    if len(head) < 33 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise FileError(path, None, "is not a PNG image (no PNG signature and IHDR header)")
    width, height, depth, color = struct.unpack(">IIBB", head[16:26])
    if color not in PNG_COLOR_CHANNELS or width == 0 or height == 0:
        raise FileError(path, None, f"has a malformed PNG header ({width}x{height}, colour type {color})")
    return width, height, depth, PNG_COLOR_CHANNELS[color]


class _StderrCapture:
    """Catch what C libraries print on file descriptor 2 while a call runs (libpng prints its
    errors there), so that it can go into our own one-line message instead."""

    def __init__(self) -> None:
        self._fd: int | None = None

    def run(self, call: Callable[[], Any]) -> tuple[Any, str]:
        if self._fd is None:
            self._fd = os.memfd_create("stderr") if hasattr(os, "memfd_create") else _temporary_fd()
        os.ftruncate(self._fd, 0)
        os.lseek(self._fd, 0, os.SEEK_SET)
        sys.stderr.flush()
        saved = os.dup(2)
        try:
            os.dup2(self._fd, 2)
            result = call()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        os.lseek(self._fd, 0, os.SEEK_SET)
        text = os.read(self._fd, 4096).decode("utf-8", "replace")
        return result, " ".join(text.split())


def _temporary_fd() -> int:
    import tempfile

    with tempfile.TemporaryFile() as handle:
        return os.dup(handle.fileno())  # the file lives on in the duplicate


_CAPTURE = _StderrCapture()


def decode_png(path: Path, own: Callable[[bytes], np.ndarray | None] | None = None) -> np.ndarray:
    """Decode a PNG (whose header was checked) as stored, colour in RGB(A) order. ``own``
    decodes the files it knows faster (None for any other: sim/png.py's for the bench's own
    frames); libpng the rest, its complaints becoming the error."""
    import cv2  # only readers of images pay for it

    data = read_bytes(path, MAX_IMAGE_BYTES, "PNG image")
    image = None if own is None else own(data)
    if image is not None:
        return image
    image, complaint = _CAPTURE.run(
        lambda: cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    )
    if image is None:
        detail = complaint.removeprefix("libpng error: ") or "corrupt or truncated"
        raise FileError(path, None, f"cannot be decoded as a PNG image ({detail})")
    if image.ndim == 3:  # OpenCV's BGR(A)
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB if image.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)
    return image


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON has no NaN or Infinity)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


def dumps_json(value: Any, *, indent: int | None = 2) -> str:
    """Strict JSON: non-finite numbers become null, keys are sorted (byte-reproducible)."""
    return json.dumps(json_safe(value), indent=indent, sort_keys=True, allow_nan=False)
