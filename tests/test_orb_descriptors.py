"""ORB's descriptor computed on the bench's own pyramid against OpenCV's ``ORB.compute``, the
reference: the shipped point pairs are the ones the installed OpenCV samples (read off it by
probing, not from its source), and the compiled descriptor equals OpenCV's bit for bit on
textures, frames of every pyramid level, keypoints at the edge and at every angle."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from depotbench.core.camera import Intrinsics
from depotbench.core.jit import Kernels
from depotbench.slam import kernels
from depotbench.slam.config import TrackingConfig
from depotbench.slam.features import (
    EDGE_PX,
    PATCH_PX,
    FeatureExtractor,
    describe,
    orb_blur,
    orb_pattern,
)

pytestmark = pytest.mark.skipif(not kernels.compiled(), reason="the compiled descriptor needs numba")

CONFIG = TrackingConfig()
ROTATED_APART = np.float32(234.514)
"""An angle whose float32 cosine and sine (cosf, sinf) differ from the double ones rounded, by
enough to move one of the pattern's samples to the next pixel (one of two million angles)."""


def _orb() -> cv2.ORB:
    return cv2.ORB_create(CONFIG.n_features, CONFIG.scale_factor, CONFIG.n_levels, EDGE_PX, 0, 2,
                          cv2.ORB_HARRIS_SCORE, PATCH_PX)  # fmt: skip


def _opencv(image: np.ndarray, xs, ys, angles, octave: int = 0) -> np.ndarray:
    """OpenCV's ORB on keypoints at level-``octave`` positions, as the extractor hands them over."""
    scale = FeatureExtractor(CONFIG)._scales[octave]
    size = PATCH_PX * float(scale)
    keypoints = [
        cv2.KeyPoint(float(np.float32(x) * scale), float(np.float32(y) * scale), size, float(a), 0.0, octave)
        for x, y, a in zip(xs, ys, angles, strict=True)
    ]
    described, descriptors = _orb().compute(image, keypoints)
    assert len(described) == len(keypoints)
    return descriptors


def _read_pattern_off_opencv(rng: np.random.Generator) -> np.ndarray:
    """Each bit's point pair, found from OpenCV's ORB alone: keypoints at angle 0 on uniform
    noise, and for each bit the one ordered pair of the patch's 961 points whose comparisons
    on the blurred patches give that bit at every keypoint."""
    radius = PATCH_PX // 2
    offsets = np.array([(x, y) for y in range(-radius, radius + 1) for x in range(-radius, radius + 1)])
    values, bits = [], []
    for _ in range(2):
        image = rng.integers(0, 256, (480, 640), dtype=np.uint8)
        centres = np.array([(x, y) for y in range(40, 440, 9) for x in range(40, 600, 9)])
        descriptors = _opencv(image, centres[:, 0], centres[:, 1], np.zeros(len(centres)))
        blurred = orb_blur(image)
        rows, cols = centres[:, 1, None] + offsets[None, :, 1], centres[:, 0, None] + offsets[None, :, 0]
        values.append(blurred[rows, cols].astype(np.int16))
        bits.append(np.unpackbits(descriptors, axis=1, bitorder="little").astype(bool))
    values, bits = np.concatenate(values), np.concatenate(bits)
    first, second = np.divmod(np.arange(len(offsets) ** 2), len(offsets))
    first, second = first[first != second], second[first != second]
    pattern = []
    for bit in range(256):
        a, b = first, second
        for sample in range(len(values)):
            if len(a) <= 1:
                break
            agree = (values[sample, a] < values[sample, b]) == bits[sample, bit]
            a, b = a[agree], b[agree]
        assert len(a) == 1, f"bit {bit}: {len(a)} pairs fit"
        assert np.array_equal(values[:, a[0]] < values[:, b[0]], bits[:, bit]), f"bit {bit}"
        pattern.append((*offsets[a[0]], *offsets[b[0]]))
    return np.array(pattern)


def test_the_shipped_pattern_is_the_one_the_installed_opencv_samples():
    np.testing.assert_array_equal(orb_pattern(), _read_pattern_off_opencv(np.random.default_rng(7)))


def _noise(rng: np.random.Generator, shape=(480, 640), sigma: float = 1.0) -> np.ndarray:
    return cv2.GaussianBlur(rng.integers(0, 256, shape, dtype=np.uint8), (0, 0), sigma)


def test_every_level_angle_and_edge_is_described_as_opencv_does():
    """Keypoints on each of the eight levels, from ``EDGE_PX`` inside its edges (the rotated
    pattern reaches 18 px) to its middle, at every whole degree, at the angles a float32
    arctangent gives, and at ``ROTATED_APART``."""
    rng = np.random.default_rng(3)
    extractor = FeatureExtractor(CONFIG)
    image = _noise(rng)
    levels = extractor.pyramid(image)
    assert len(levels) == CONFIG.n_levels
    described = 0
    for octave, level in enumerate(levels):
        h, w = level.shape
        xs = np.r_[EDGE_PX, w - EDGE_PX - 1, rng.integers(EDGE_PX, w - EDGE_PX, 400)]
        ys = np.r_[h - EDGE_PX - 1, EDGE_PX, rng.integers(EDGE_PX, h - EDGE_PX, 400)]
        angles = np.r_[ROTATED_APART, 359.99994, np.arange(360)[:400], rng.uniform(0, 360, 40)].astype(
            np.float32
        )[: len(xs)]
        octaves = np.full(len(xs), octave)
        ours = describe(levels, xs, ys, octaves, angles)
        np.testing.assert_array_equal(ours, _opencv(image, xs, ys, angles, octave), err_msg=f"level {octave}")
        described += len(xs)
    assert described == 8 * 402


def test_an_angle_a_float32_cosine_rounds_apart_is_described_as_opencv_does():
    """OpenCV takes the cosine and sine in double precision: at ``ROTATED_APART`` a float32
    cosine moves a sample and changes bits (checked here), the double one does not."""
    import math

    radians = ROTATED_APART * np.float32(math.pi / 180.0)
    double = np.float32(math.cos(float(radians))), np.float32(math.sin(float(radians)))
    single = np.cos(np.array([radians], np.float32))[0], np.sin(np.array([radians], np.float32))[0]
    pattern = np.r_[orb_pattern()[:, :2], orb_pattern()[:, 2:]].astype(np.float32)

    def samples(a, b):
        return np.rint(pattern[:, 0] * a - pattern[:, 1] * b), np.rint(pattern[:, 0] * b + pattern[:, 1] * a)

    moved = [not np.array_equal(p, q) for p, q in zip(samples(*double), samples(*single), strict=True)]
    rng = np.random.default_rng(5)
    extractor = FeatureExtractor(CONFIG)
    for _ in range(20):
        image = rng.integers(0, 256, (100, 100), dtype=np.uint8)
        xs, ys, angles = np.array([50]), np.array([50]), np.array([ROTATED_APART])
        ours = describe(extractor.pyramid(image), xs, ys, np.zeros(1, int), angles)
        np.testing.assert_array_equal(ours, _opencv(image, xs, ys, angles))
    assert any(moved) or single == double  # numpy's float32 cosine may round as the double does


def test_the_fixed_point_blur_would_change_descriptors():
    """Why the extractor blurs with two float passes: OpenCV's ``GaussianBlur`` on bytes rounds
    some pixels one level apart, and the descriptors on it differ from ORB's."""
    rng = np.random.default_rng(9)
    image = _noise(rng, sigma=0.7)
    centres = np.array([(x, y) for y in range(40, 440, 7) for x in range(40, 600, 7)])
    angles = rng.uniform(0, 360, len(centres)).astype(np.float32)
    reference = _opencv(image, centres[:, 0], centres[:, 1], angles)
    ours = describe([image], centres[:, 0], centres[:, 1], np.zeros(len(centres), int), angles)
    np.testing.assert_array_equal(ours, reference)
    fixed = cv2.GaussianBlur(image, (7, 7), sigmaX=2, sigmaY=2, borderType=cv2.BORDER_REFLECT_101)
    assert (fixed != orb_blur(image)).mean() > 0.01
    from depotbench.slam.kernels import features as compiled

    level = (np.zeros(1, np.int64), np.array([640]))
    at = (centres[:, 0], centres[:, 1], np.zeros(len(centres), np.int64), angles, orb_pattern())
    on_fixed = compiled.describe(fixed.ravel(), *level, *at)
    assert (on_fixed != reference).any(axis=1).mean() > 0.05


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_extractor_gives_the_same_features_on_both_paths(seed: int):
    """A whole extraction with the descriptors from OpenCV's ORB (DEPOTBENCH_KERNELS=numpy) and
    compiled: the same keypoints and the same descriptors, on textures with corners of every
    strength, rotated so that the orientations spread over the circle."""
    rng = np.random.default_rng(seed)
    image = np.clip((_noise(rng, sigma=1.5).astype(np.float32) - 128) * 4 + 128, 0, 255).astype(np.uint8)
    for x, y, w, h in rng.integers(0, 600, (40, 4)):
        image[y % 440 : y % 440 + h // 10 + 5, x : x + w // 10 + 5] = rng.integers(0, 256)
    image = cv2.warpAffine(image, cv2.getRotationMatrix2D((320, 240), 40.0 * seed + 17, 1.0), (640, 480))
    rgb, depth = np.repeat(image[..., None], 3, axis=2), np.ones(image.shape)
    camera = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480)
    found = {}
    for path in (Kernels.NUMPY, Kernels.NUMBA):
        with kernels.using(path):
            found[path] = FeatureExtractor(CONFIG).extract(rgb, depth, camera)
    reference, compiled = found[Kernels.NUMPY], found[Kernels.NUMBA]
    assert len(compiled) > 900
    assert set(compiled.octaves.tolist()) == set(range(CONFIG.n_levels))
    np.testing.assert_array_equal(compiled.keypoints_px, reference.keypoints_px)
    np.testing.assert_array_equal(compiled.angles_deg, reference.angles_deg)
    np.testing.assert_array_equal(compiled.descriptors, reference.descriptors)
