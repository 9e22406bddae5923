"""PNG encoding of the frames a sequence writes, with libdeflate.

libpng (through OpenCV) compresses with zlib, which on this bench's machines takes
about 12 ms for a 640x480 RGB frame at level 1. libdeflate (the ``deflate`` package)
takes 4.4 ms and writes files 3-4 % smaller; it compresses each image in one call, with
no state carried between calls, and releases the GIL, so writer threads run beside
rendering. No maintained PNG writer on PyPI uses it, so the container is written here;
it is the small part: a signature, IHDR, one IDAT and IEND, each with its CRC. Rows use
PNG's Sub filter, as the libpng writer did.

The same image gives the same bytes in every process and thread: a sequence's bytes are
its spec and seed's, and libdeflate's output is fixed for a given version (a faster
deflate that kept state between calls wrote one frame two ways: docs/performance.md).
"""

from __future__ import annotations

import struct
import zlib

import deflate
import numpy as np
from depotbench.core.files import PNG_SIGNATURE

_COLOR_TYPE = {1: 0, 3: 2}
"""PNG colour type for a number of channels: grey, RGB."""
_FILTER_SUB = 1

FASTEST = 1


def encode_png(image: np.ndarray, level: int = FASTEST) -> bytes:
    """An 8-bit RGB (H, W, 3), or 8- or 16-bit grey (H, W), image as PNG bytes.

    RGB is in RGB order (not OpenCV's BGR). ``level`` is a zlib level, 0-9."""
    if image.ndim == 2:
        image = image[:, :, None]
    height, width, channels = image.shape
    if (
        channels not in _COLOR_TYPE
        or image.dtype not in (np.uint8, np.uint16)
        or (channels == 3 and image.dtype != np.uint8)
    ):
        raise ValueError(f"cannot write a {image.shape} {image.dtype} image as PNG")
    if isinstance(level, bool) or level not in range(10):
        raise ValueError(f"PNG level must be a zlib level 0-9, got {level!r}")
    return assemble_png(image.shape, image.dtype, sub_filtered(image), level)


def assemble_png(shape: tuple[int, ...], dtype: np.dtype, rows: np.ndarray, level: int = FASTEST) -> bytes:
    """The PNG of an image of ``shape`` and ``dtype`` from its ``sub_filtered`` rows: the
    deflate, the slow part, releases the GIL, so writer threads run it beside rendering."""
    height, width = shape[:2]
    channels = shape[2] if len(shape) == 3 else 1
    header = struct.pack(
        ">IIBBBBB", width, height, np.dtype(dtype).itemsize * 8, _COLOR_TYPE[channels], 0, 0, 0
    )
    idat = _deflate(rows, level)
    return b"".join((PNG_SIGNATURE, _chunk(b"IHDR", header), _chunk(b"IDAT", idat), _chunk(b"IEND", b"")))


def sub_filtered(image: np.ndarray) -> np.ndarray:
    """The image's rows as PNG stores them with the Sub filter: a filter-type byte, then
    each byte minus the same byte of the pixel to its left (mod 256), big-endian samples."""
    height = image.shape[0]
    raw = image.astype(image.dtype.newbyteorder(">"), copy=False).view(np.uint8).reshape(height, -1)
    step = raw.shape[1] // image.shape[1]  # bytes per pixel
    rows = np.empty((height, raw.shape[1] + 1), np.uint8)
    rows[:, 0] = _FILTER_SUB
    rows[:, 1 : 1 + step] = raw[:, :step]
    np.subtract(raw[:, step:], raw[:, :-step], out=rows[:, 1 + step :])
    return rows


def _deflate(data: np.ndarray, level: int) -> bytes:
    """A zlib stream of ``data`` at libdeflate's ``level`` (0 stores, 1-9 as zlib's)."""
    return deflate.zlib_compress(data, level)


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(body, zlib.crc32(kind)))
