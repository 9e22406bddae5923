"""The PNG writer (sim/png.py) against two independent decoders: libpng (through OpenCV),
which checks every chunk's CRC and the zlib stream's checksum, and Pillow's own parser."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from depotbench.sim.png import encode_png
from PIL import Image

SHAPES = [(1, 1), (3, 7), (48, 64), (480, 640)]


def _images(shape: tuple[int, int]) -> list[np.ndarray]:
    rng = np.random.default_rng(sum(shape))
    h, w = shape
    smooth = np.add.outer(np.arange(h), 3 * np.arange(w))  # what filters and deflate are made for
    return [
        rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
        (smooth[:, :, None] + np.array([0, 50, 100])).astype(np.uint8),
        rng.integers(0, 65536, (h, w), dtype=np.uint16),
        (smooth * 97).astype(np.uint16),
        rng.integers(0, 256, (h, w), dtype=np.uint8),
    ]


@pytest.mark.parametrize("level", [0, 1, 2, 3, 6, 9])
@pytest.mark.parametrize("shape", SHAPES, ids=str)
def test_written_pngs_decode_to_the_same_pixels_in_libpng_and_pillow(shape, level):
    for image in _images(shape):
        data = encode_png(image, level)
        back = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        assert back is not None and back.dtype == image.dtype
        if image.ndim == 3:
            back = back[:, :, ::-1]  # OpenCV decodes to BGR
        assert np.array_equal(back.reshape(image.shape), image)
        pil = Image.open(io.BytesIO(data))
        pil.load()
        decoded = np.asarray(pil)
        assert np.array_equal(decoded.astype(image.dtype).reshape(image.shape), image), pil.mode


def test_smooth_frames_compress_and_the_same_image_gives_the_same_bytes():
    image = _images((480, 640))[1]
    data = encode_png(image, 1)
    assert len(data) < image.nbytes / 10
    assert encode_png(image.copy(), 1) == data
    assert len(encode_png(image, 0)) > image.nbytes  # level 0 stores


def test_an_image_gives_the_same_bytes_from_any_writer_thread_whatever_it_wrote_before():
    """A sequence's bytes are its spec and seed's, and its writer deflates in a pool of
    threads, each after whatever it drew before. ISA-L, the deflate used before, once wrote
    one depth frame as 6232 and 6233 bytes in one long-lived test process (the same pixels);
    libdeflate keeps no state between calls. Eight threads write the frames of a small
    sequence in shuffled orders, after large and small images of their own."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(5)
    frames = [image for shape in ((48, 64), (120, 160)) for image in _images(shape)]
    expected = [encode_png(image, 1) for image in frames]
    noise = [rng.integers(0, 256, (int(rng.integers(1, 480)), 640, 3), dtype=np.uint8) for _ in range(8)]
    with ThreadPoolExecutor(8) as pool:
        for _ in range(20):
            list(pool.map(lambda image: encode_png(image, 1), noise))
            order = rng.permutation(len(frames))
            written = dict(zip(order, pool.map(lambda k: encode_png(frames[k], 1), order), strict=True))
            assert [written[k] for k in range(len(frames))] == expected


@pytest.mark.parametrize(
    ("image", "level", "message"),
    [
        (np.zeros((4, 4, 3), np.uint16), 1, "cannot write"),
        (np.zeros((4, 4, 4), np.uint8), 1, "cannot write"),
        (np.zeros((4, 4), np.float32), 1, "cannot write"),
        (np.zeros((4, 4), np.uint8), 10, "zlib level 0-9"),
        (np.zeros((4, 4), np.uint8), True, "zlib level 0-9"),
    ],
)
def test_images_and_levels_png_cannot_hold_are_refused(image, level, message):
    with pytest.raises(ValueError, match=message):
        encode_png(image, level)
