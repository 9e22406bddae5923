"""The PNG writer (sim/png.py) against two independent decoders: libpng (through OpenCV),
which checks every chunk's CRC and the zlib stream's checksum, and Pillow's own parser; and
its reader against libpng, on the writer's files, on other writers' and on damaged ones."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from depotbench.sim.png import decode_written_rgb, encode_png
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


def _libpng(data: bytes) -> np.ndarray | None:
    """libpng's reading of ``data`` (through OpenCV), colour in RGB order; None where it refuses."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    return image if image is None or image.ndim == 2 else image[:, :, ::-1]


@pytest.mark.parametrize("level", [0, 1, 9])
@pytest.mark.parametrize("shape", SHAPES, ids=str)
def test_the_reader_gives_libpngs_pixels_for_every_rgb_frame_the_writer_makes(shape, level):
    """RGB frames are read here, to libpng's pixels; grey ones (depth, instances) are left to
    libpng, whose C unfiltering is the faster there."""
    for image in _images(shape):
        data = encode_png(image, level)
        decoded = decode_written_rgb(data)
        if image.ndim == 2:
            assert decoded is None
            continue
        assert decoded is not None
        assert decoded.dtype == image.dtype and decoded.shape == image.shape
        assert decoded.flags.writeable and decoded.flags.c_contiguous
        assert np.array_equal(decoded, _libpng(data))


def test_other_writers_pngs_are_read_as_libpng_reads_them(tmp_path):
    """Files of other writers: one laid out as this writer's (OpenCV's libpng writes a
    smooth image with Sub rows, one IDAT) is read here to libpng's pixels; formats this writer
    never makes (RGBA, 16-bit RGB, a palette, interlacing) and rows under other filters
    (Pillow's adaptive choice on a noisy image) are left to libpng. Either way ``decode_png``
    gives libpng's image, colour in RGB order."""
    from depotbench.core.files import decode_png

    smooth, noisy = _images((48, 64))[1], _images((48, 64))[0]
    alpha = np.dstack([smooth, smooth[:, :, :1]])
    same_layout = cv2.imencode(".png", smooth[:, :, ::-1])[1].tobytes()
    others = [
        cv2.imencode(".png", alpha[:, :, [2, 1, 0, 3]])[1].tobytes(),
        cv2.imencode(".png", (smooth.astype(np.uint16) * 257)[:, :, ::-1])[1].tobytes(),
    ]
    for image, options in (
        (noisy, {}),
        (smooth, {"interlace": 1}),
        (Image.fromarray(smooth).convert("P"), {}),
    ):
        buffer = io.BytesIO()
        (image if isinstance(image, Image.Image) else Image.fromarray(image)).save(
            buffer, format="PNG", **options
        )
        others.append(buffer.getvalue())
    assert np.array_equal(decode_written_rgb(same_layout), smooth)
    assert [decode_written_rgb(data) for data in others] == [None] * len(others)
    for number, (data, expected) in enumerate(
        [
            (same_layout, smooth),
            (others[0], alpha),
            (others[1], smooth.astype(np.uint16) * 257),
            (others[2], noisy),
            (encode_png(_images((48, 64))[2]), _images((48, 64))[2]),  # the writer's depth: libpng's
        ]
    ):
        (tmp_path / f"{number}.png").write_bytes(data)
        assert np.array_equal(decode_png(tmp_path / f"{number}.png"), expected), number


def test_a_damaged_file_is_never_read_here_to_other_pixels_than_libpngs():
    """Every single-byte change and every truncation of two written RGB frames:
    the reader returns None (libpng then reads or refuses it, with its own words) or exactly
    libpng's image of the changed file. The CRCs and the zlib checksum make it None."""
    rng = np.random.default_rng(5)
    for image in (_images((12, 16))[1], _images((7, 5))[0]):
        data = encode_png(image, 1)
        for position in range(len(data)):
            for value in {data[position] ^ 0x01, data[position] ^ 0x80, int(rng.integers(256))} - {
                data[position]
            }:
                changed = data[:position] + bytes([value]) + data[position + 1 :]
                decoded = decode_written_rgb(changed)
                assert decoded is None or np.array_equal(decoded, _libpng(changed)), position
        for length in range(len(data)):
            assert decode_written_rgb(data[:length]) is None, length
        assert decode_written_rgb(data + b"\x00") is None
