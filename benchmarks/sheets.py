"""Contact sheets for the benchmarks' pictures: crops fitted to a square tile, laid out
in a grid, written whole or not at all."""

from __future__ import annotations

from pathlib import Path

# depotbench first: numpy then runs the bench's code for the CPU (core/numerics.py)
import depotbench  # isort: skip  # noqa: F401
import cv2
import numpy as np
from depotbench.core.output import write_bytes_atomic


def fit(image: np.ndarray, side: int) -> np.ndarray:
    """``image`` scaled so that its longer side is ``side`` pixels."""
    scale = side / max(image.shape[:2])
    size = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
    return cv2.resize(image, size)


def crop_around(image: np.ndarray, box, margin: int) -> np.ndarray:
    """The part of ``image`` inside ``box`` (x0, y0, x1, y1) grown by ``margin`` pixels
    on each side, clipped to the image."""
    x0, y0, x1, y1 = (int(v) for v in box)
    h, w = image.shape[:2]
    return image[max(0, y0 - margin) : min(h, y1 + margin), max(0, x0 - margin) : min(w, x1 + margin)]


def grid(tiles: list[np.ndarray], columns: int) -> np.ndarray:
    """Equal-sized tiles, row by row, ``columns`` to a row; the last row padded white."""
    height, width = tiles[0].shape[:2]
    rows = -(-len(tiles) // columns)
    sheet = np.full((rows * height, columns * width, 3), 255, np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, columns)
        sheet[r * height : (r + 1) * height, c * width : (c + 1) * width] = tile
    return sheet


def write_png(path: Path, image: np.ndarray) -> None:
    """Write ``image`` (BGR) to ``path`` whole or not at all (``write_bytes_atomic``)."""
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise OSError(f"{path}: could not encode the picture")
    write_bytes_atomic(path, data.tobytes())
