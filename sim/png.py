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

Reading goes the other way for the RGB frames it writes (``decode_written_rgb``): libdeflate
inflates and NumPy undoes the Sub filter, 0.6-0.7 of libpng's time through OpenCV on a
640x480 frame (8.0 against 11.2 ms, the colour order already RGB: docs/performance.md). Depth
and instance frames stay with libpng, whose unfiltering in C beats NumPy's running sum
where inflating is cheap (a 2-byte instance frame: 3.7 ms here against 2.6). Every other PNG,
and any file whose chunks, checksums or rows are not what this writer makes, goes to libpng,
so a damaged frame is refused with libpng's own words and a real recording is read as before.
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
_RGB8 = (8, 2)
"""(bit depth, colour type) of the RGB frames ``decode_written_rgb`` reads."""
_MAX_RAW_BYTES = 1 << 28
"""Larger images (a 9,000 x 9,000 RGB frame) are left to libpng rather than inflated here in
one buffer: no camera this bench reads comes near it."""

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


def decode_written_rgb(data: bytes) -> np.ndarray | None:
    """The (H, W, 3) uint8 RGB image in ``data`` when the file is an 8-bit RGB PNG laid out as
    ``encode_png`` writes one (signature, IHDR, one IDAT, IEND, every CRC and the zlib checksum
    right, every row Sub-filtered). None for anything else, which is then libpng's to read or
    refuse: this never refuses a file, so it can only be faster."""
    if len(data) < 57 or data[:8] != PNG_SIGNATURE or data[8:16] != b"\x00\x00\x00\rIHDR":
        return None
    width, height, depth, colour, compression, filtering, interlace = struct.unpack(">IIBBBBB", data[16:29])
    if (depth, colour) != _RGB8 or compression or filtering or interlace or not width or not height:
        return None
    (size,) = struct.unpack(">I", data[33:37])
    end = 45 + size
    if (
        data[37:41] != b"IDAT"
        or len(data) != end + 12
        or data[end : end + 8] != b"\x00\x00\x00\x00IEND"
        or any(
            deflate.crc32(data[start:stop]) != struct.unpack(">I", data[stop : stop + 4])[0]
            for start, stop in ((12, 29), (37, end - 4), (end + 4, end + 8))
        )
    ):
        return None
    expected = height * (width * 3 + 1)
    if expected > _MAX_RAW_BYTES:
        return None
    try:
        raw = deflate.zlib_decompress(data[41 : end - 4], expected)
    except deflate.DeflateError:
        return None
    if len(raw) != expected:
        return None
    rows = np.frombuffer(raw, np.uint8).reshape(height, width * 3 + 1)
    if not (rows[:, 0] == _FILTER_SUB).all():
        return None
    # Sub: each byte is the difference to the same byte one pixel to its left, mod 256.
    return np.cumsum(rows[:, 1:].reshape(height, width, 3), axis=1, dtype=np.uint8)


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(body, zlib.crc32(kind)))
