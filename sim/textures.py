"""Seeded procedural textures: every surface gets structure that ORB can latch on.

Real depots are full of print, wear and clutter; flat colours would starve the
feature extractor and make every SLAM result meaningless. Each function draws
from the ``numpy.random.Generator`` it is handed, nothing else. One texture is not
drawn: cats wear a photograph of a tabby's fur (``assets/textures``), because no
procedural coat made them cats to a detector; it is laid on along the body, not
projected by a cube map (``tabby``).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
from depotbench.core.assets import asset
from depotbench.sim import actor_registry
from depotbench.sim.draws import picks
from depotbench.sim.ipp import without_ipp

Colour = tuple[int, int, int]
_LETTERS = "ABCDEFGHJKLMNPRSTUVWXYZ0123456789"


def _noise(rng: np.random.Generator, size: int, octaves: int = 4, amplitude: float = 40.0) -> np.ndarray:
    """Multi-octave value noise in [-amplitude, amplitude] (float32, size x size)."""
    total = np.zeros((size, size), np.float32)
    weight = 1.0
    with without_ipp():  # the same bits on every CPU (sim/ipp.py)
        for octave in range(octaves):
            cells = 4 * 2**octave
            grid = rng.uniform(-1, 1, (cells, cells)).astype(np.float32)
            total += weight * cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC)
            weight *= 0.55
    return total * (amplitude / max(1e-6, float(np.abs(total).max())))


def _base(rng: np.random.Generator, size: int, colour: Colour, grain: float = 30.0) -> np.ndarray:
    image = np.empty((size, size, 3), np.float32)
    image[:] = colour
    image += _noise(rng, size, amplitude=grain)[:, :, None]
    image += rng.normal(0, 6, (size, size, 1)).astype(np.float32)
    return image


def _finish(image: np.ndarray) -> np.ndarray:
    return np.clip(image, 0, 255).astype(np.uint8)


def _text(rng: np.random.Generator, image: np.ndarray, n: int, colour: Colour, scale: float) -> None:
    """Random stencil words drawn into ``image`` (float, drawn through a uint8 mask)."""
    h, w = image.shape[:2]
    if h < 12 or w < 12:
        return
    mask = np.zeros((h, w), np.uint8)
    for _ in range(n):
        word = "".join(picks(rng, _LETTERS, int(rng.integers(2, 7))))
        org = (int(rng.integers(0, max(1, w - 20))), int(rng.integers(min(12, h - 1), h)))
        cv2.putText(
            mask,
            word,
            org,
            cv2.FONT_HERSHEY_SIMPLEX,
            scale * rng.uniform(0.6, 1.4),
            255,
            int(rng.integers(1, 3)),
            cv2.LINE_AA,
        )
    alpha = (mask.astype(np.float32) / 255.0)[:, :, None]
    image[:] = image * (1 - alpha) + np.array(colour, np.float32) * alpha


def concrete(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Worn floor: stains, cracks, painted lane marks and scuffs."""
    image = _base(rng, size, (128, 126, 120), grain=35)
    for _ in range(40):
        centre = tuple(int(v) for v in rng.integers(0, size, 2))
        axes = tuple(int(v) for v in rng.integers(4, 40, 2))
        shade = float(rng.uniform(-45, 25))
        cv2.ellipse(image, centre, axes, float(rng.uniform(0, 180)), 0, 360, (shade + 120,) * 3, -1)
    for _ in range(25):
        p = rng.integers(0, size, 2)
        q = p + rng.integers(-80, 80, 2)
        cv2.line(image, tuple(int(v) for v in p), tuple(int(v) for v in q), (60, 60, 58), 1, cv2.LINE_AA)
    for _ in range(450):  # chips and gravel: corners that stay visible at 5 m
        c = rng.integers(0, size, 2)
        shade = float(rng.choice([20.0, 225.0]))
        r = int(rng.integers(3, 8))
        poly = (c + rng.integers(-r, r + 1, (4, 2))).astype(np.int32)
        cv2.fillPoly(image, [poly], (shade, shade, shade * 0.95))
    if rng.uniform() < 0.7:
        x = int(rng.integers(0, size - 30))
        cv2.rectangle(image, (x, 0), (x + 14, size), (40, 190, 230), -1)
    for _ in range(6):  # hazard tape: a row of corners wherever it lies
        x0, y0 = (int(v) for v in rng.integers(0, size - 120, 2))
        horizontal = rng.uniform() < 0.5
        for k in range(0, 120, 12):
            a = (x0 + k, y0) if horizontal else (x0, y0 + k)
            b = (x0 + k + 6, y0 + 14) if horizontal else (x0 + 14, y0 + k + 6)
            cv2.rectangle(image, a, b, (30, 30, 30), -1)
            a2 = (a[0] + 6, a[1]) if horizontal else (a[0], a[1] + 6)
            b2 = (b[0] + 6, b[1]) if horizontal else (b[0], b[1] + 6)
            cv2.rectangle(image, a2, b2, (40, 200, 235), -1)
    image += rng.normal(0, 8, image.shape).astype(np.float32)
    return _finish(image)


def wall(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Corrugated panels with bolts, signs and grime."""
    colour = tuple(int(c) for c in rng.choice([(170, 175, 165), (150, 160, 175), (185, 170, 140)]))
    image = _base(rng, size, colour, grain=25)
    period = int(rng.integers(16, 28))
    for x in range(0, size, period):
        cv2.line(image, (x, 0), (x, size), tuple(c * 0.75 for c in colour), 2)
    for y in range(24, size, 96):
        for x in range(8, size, 48):
            cv2.circle(image, (x, y), 3, (70, 70, 70), -1)
    for _ in range(int(rng.integers(2, 5))):
        x0, y0 = (int(v) for v in rng.integers(0, size - 120, 2))
        w, h = (int(v) for v in rng.integers(50, 120, 2))
        sign = tuple(
            int(c) for c in rng.choice([(200, 40, 30), (240, 200, 30), (30, 90, 170), (240, 240, 235)])
        )
        cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), sign, -1)
        cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), (20, 20, 20), 2)
        _text(rng, image[y0 : y0 + h, x0 : x0 + w], 2, (15, 15, 15), 0.5)
    for _ in range(60):  # repair plates: a sheet of the wall's metal, outlined and riveted
        x0, y0 = (int(v) for v in rng.integers(0, size - 28, 2))
        w, h = (int(v) for v in rng.integers(10, 28, 2))
        lightness = float(rng.choice([rng.uniform(0.55, 0.8), rng.uniform(1.15, 1.35)]))
        shade = tuple(c * lightness for c in colour)
        cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), shade, -1)
        cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), tuple(c * 0.4 for c in colour), 1)
        for cx, cy in (
            (x0 + 3, y0 + 3),
            (x0 + w - 3, y0 + 3),
            (x0 + 3, y0 + h - 3),
            (x0 + w - 3, y0 + h - 3),
        ):
            cv2.circle(image, (cx, cy), 1, (80, 80, 80), -1)
    for _ in range(64):  # inspection tags and stencilled labels: off-white with black print
        x0, y0 = (int(v) for v in rng.integers(0, size - 40, 2))
        w, h = int(rng.integers(18, 40)), int(rng.integers(12, 22))
        paper = float(rng.integers(205, 240))
        cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), (paper, paper, paper * 0.95), -1)
        _text(rng, image[y0 : y0 + h, x0 : x0 + w], 1, (20, 20, 20), 0.3)
    for _ in range(20):  # rust streaks running down from bolts and seams
        x0, y0 = int(rng.integers(0, size - 4)), int(rng.integers(0, size - 60))
        length, width = int(rng.integers(20, 60)), int(rng.integers(2, 5))
        rust = (float(rng.integers(110, 150)), float(rng.integers(60, 85)), float(rng.integers(30, 50)))
        cv2.line(image, (x0, y0), (x0 + int(rng.integers(-3, 4)), y0 + length), rust, width)
    image += _noise(rng, size, amplitude=20)[:, :, None]
    return _finish(image)


def crate(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Wooden planks with grain, nails and stencilled print."""
    colour = tuple(int(c) for c in rng.choice([(160, 120, 75), (185, 150, 100), (140, 100, 60)]))
    image = _base(rng, size, colour, grain=20)
    plank = int(rng.integers(28, 52))
    for y in range(0, size, plank):
        cv2.line(image, (0, y), (size, y), (60, 40, 25), 2)
        for _ in range(6):
            yy = y + int(rng.integers(2, plank))
            cv2.line(
                image,
                (0, yy),
                (size, yy + int(rng.integers(-6, 6))),
                tuple(c * 0.85 for c in colour),
                1,
            )
        for x in (8, size - 8):
            cv2.circle(image, (x, y + plank // 2), 2, (40, 40, 40), -1)
    _text(rng, image, 3, (30, 30, 30), 0.9)
    return _finish(image)


def cardboard(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Boxes: tape, labels, barcodes, arrows."""
    image = _base(rng, size, (175, 140, 95), grain=15)
    cv2.rectangle(image, (size // 2 - 12, 0), (size // 2 + 12, size), (200, 180, 140), -1)
    x0, y0 = (int(v) for v in rng.integers(10, size - 110, 2))
    cv2.rectangle(image, (x0, y0), (x0 + 100, y0 + 70), (245, 245, 240), -1)
    for k in range(30):
        if rng.uniform() < 0.6:
            x = x0 + 8 + 3 * k
            cv2.line(image, (x, y0 + 35), (x, y0 + 64), (10, 10, 10), int(rng.integers(1, 3)))
    _text(rng, image[y0 : y0 + 35, x0 : x0 + 100], 1, (10, 10, 10), 0.45)
    _text(rng, image, 2, (40, 30, 25), 0.8)
    return _finish(image)


def sack(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Feed sacks: woven burlap with a printed brand."""
    image = _base(rng, size, tuple(int(c) for c in rng.choice([(200, 185, 150), (225, 220, 205)])), 15)
    yy, xx = np.mgrid[0:size, 0:size]
    image += (12 * np.sin(xx * 1.6) * np.sin(yy * 1.6))[:, :, None].astype(np.float32)
    centre = (size // 2, size // 2)
    cv2.circle(image, centre, size // 5, tuple(int(c) for c in rng.integers(20, 200, 3)), 4)
    _text(rng, image, 3, (int(rng.integers(10, 120)), 60, 30), 0.9)
    return _finish(image)


def metal(rng: np.random.Generator, size: int = 128, colour: Colour = (220, 110, 30)) -> np.ndarray:
    """Painted steel (rack uprights and beams): chips, holes, labels."""
    image = _base(rng, size, colour, grain=18)
    for y in range(6, size, 14):
        shade = tuple(0.6 * c for c in colour)
        cv2.rectangle(image, (size // 2 - 3, y), (size // 2 + 3, y + 6), shade, -1)
    for _ in range(20):
        c = tuple(int(v) for v in rng.integers(0, size, 2))
        cv2.circle(image, c, int(rng.integers(1, 4)), (150, 150, 150), -1)
    return _finish(image)


def wood(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Desk top and pallets: grain and knots."""
    image = _base(rng, size, (150, 110, 70), grain=10)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    image += (18 * np.sin(yy / 3.0 + _noise(rng, size, amplitude=6.0)))[:, :, None]
    for _ in range(4):
        c = tuple(int(v) for v in rng.integers(0, size, 2))
        cv2.ellipse(
            image,
            c,
            (int(rng.integers(5, 14)), int(rng.integers(3, 7))),
            0,
            0,
            360,
            (80, 50, 30),
            2,
        )
    return _finish(image)


def screen(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """A monitor or laptop showing windows and text."""
    image = np.full((size, size, 3), (40, 50, 70), np.float32)
    for _ in range(3):
        x0, y0 = (int(v) for v in rng.integers(0, size - 80, 2))
        w, h = (int(v) for v in rng.integers(80, 170, 2))
        cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), (95, 100, 110), -1)
        cv2.rectangle(image, (x0, y0), (x0 + w, y0 + 10), (60, 80, 120), -1)
    return _finish(image)


def _wear(rng: np.random.Generator, image: np.ndarray, colour: Colour, folds: int) -> None:
    """Folds (short dark and light curved strokes) and stitched seams on fabric.

    Real clothes carry wrinkles, seams and prints, and give ORB as many corners per
    pixel as a cluttered background does (TUM's walking sequences); smooth fabric would
    make people nearly featureless and the dynamic-SLAM problem disappear.
    """
    size = image.shape[0]
    for _ in range(folds):
        start = rng.uniform(0, size, 2)
        heading = rng.uniform(0, np.pi)
        steps = np.cumsum(rng.normal(0, 0.25, 6)) + heading
        points = start + np.cumsum(np.stack([np.cos(steps), np.sin(steps)], 1) * rng.uniform(5, 12), 0)
        shade = float(rng.choice([0.45, 0.6, 1.35]))
        cv2.polylines(
            image,
            [points.astype(np.int32)],
            False,
            tuple(float(np.clip(c * shade, 0, 255)) for c in colour),
            int(rng.integers(1, 3)),
            cv2.LINE_AA,
        )
    for _ in range(2):
        x = int(rng.integers(8, size - 8))
        cv2.line(image, (x, 0), (x, size), tuple(0.5 * c for c in colour), 2)
        for y in range(3, size, 7):
            cv2.line(image, (x + 3, y), (x + 3, y + 3), tuple(min(255.0, 1.4 * c + 30) for c in colour), 1)


def cloth(rng: np.random.Generator, pattern: str, colour: Colour, size: int = 256) -> np.ndarray:
    """Clothing: ``plain`` (folds, seams, buttons, a small print), ``stripes`` or ``plaid``."""
    image = _base(rng, size, colour, grain=22)
    sign = rng.choice([-1, 1])
    accent = tuple(int(np.clip(c + sign * rng.uniform(70, 110), 0, 255)) for c in colour)
    line = tuple(int(v) for v in rng.integers(0, 255, 3))
    if pattern == "stripes":
        y = 0
        while y < size:
            width = int(rng.integers(4, 14))
            cv2.rectangle(image, (0, y), (size, y + width), accent, -1)
            y += width + int(rng.integers(5, 18))
    elif pattern == "plaid":
        period = int(rng.integers(22, 40))
        overlay = image.copy()
        for v in range(0, size, period):
            cv2.rectangle(overlay, (v, 0), (v + period // 3, size), accent, -1)
            cv2.rectangle(overlay, (0, v), (size, v + period // 3), accent, -1)
        image = 0.4 * image + 0.6 * overlay
        for v in range(period // 2, size, period):
            cv2.line(image, (v, 0), (v, size), line, 1)
            cv2.line(image, (0, v), (size, v), line, 1)
    elif pattern != "plain":
        raise ValueError(f"unknown clothing pattern {pattern!r} (plain, stripes, plaid)")
    _wear(rng, image, colour, folds=40)
    for y in range(int(rng.integers(10, 30)), size, int(rng.integers(30, 50))):
        cv2.circle(image, (size // 2, y), 3, line, -1)
    _text(rng, image, 2, line, 0.7)
    image += _noise(rng, size, amplitude=18)[:, :, None]
    return _finish(image)


def denim(rng: np.random.Generator, colour: Colour, size: int = 256) -> np.ndarray:
    """Trousers: twill, seams, pockets and rivets, faded along folds."""
    image = _base(rng, size, colour, grain=20)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    image += (10 * np.sign(np.sin((xx + yy) * 1.2)))[:, :, None]
    _wear(rng, image, colour, folds=35)
    for _ in range(2):
        x0, y0 = (int(v) for v in rng.integers(10, size - 70, 2))
        cv2.rectangle(image, (x0, y0), (x0 + 50, y0 + 45), (200, 160, 80), 1)
        for corner in ((x0, y0), (x0 + 50, y0)):
            cv2.circle(image, corner, 3, (210, 190, 120), -1)
    image += _noise(rng, size, amplitude=14)[:, :, None]
    return _finish(image)


def fur(rng: np.random.Generator, colour: Colour, size: int = 128, spots: bool = False) -> np.ndarray:
    """Animal coats: strands and, optionally, patches."""
    image = _base(rng, size, colour, grain=30)
    for _ in range(300):
        p = rng.integers(0, size, 2)
        q = p + rng.integers(-5, 6, 2)
        shade = tuple(c * float(rng.uniform(0.7, 1.2)) for c in colour)
        cv2.line(image, tuple(int(v) for v in p), tuple(int(v) for v in q), shade, 1)
    if spots:
        for _ in range(6):
            c = tuple(int(v) for v in rng.integers(0, size, 2))
            cv2.circle(image, c, int(rng.integers(6, 18)), (40, 35, 30), -1)
    return _finish(image)


def skin(rng: np.random.Generator, size: int = 128) -> np.ndarray:
    """Skin with hair, brows and shading: heads and forearms are not smooth balls."""
    tone = tuple(int(c) for c in rng.choice([(235, 195, 165), (200, 150, 110), (140, 95, 65), (95, 65, 45)]))
    image = _base(rng, size, tone, grain=14)
    hair = tuple(int(c) for c in rng.choice([(30, 22, 18), (90, 60, 30), (200, 170, 110), (120, 120, 120)]))
    cv2.rectangle(image, (0, 0), (size, size // 3), hair, -1)
    for _ in range(60):
        x = int(rng.integers(0, size))
        cv2.line(image, (x, 0), (x + int(rng.integers(-6, 7)), size // 3 + int(rng.integers(-4, 8))), hair, 1)
    for _ in range(12):
        c = tuple(int(v) for v in rng.integers(0, size, 2))
        axes = (int(rng.integers(3, 9)), int(rng.integers(1, 4)))
        cv2.ellipse(image, c, axes, float(rng.uniform(0, 180)), 0, 360, tuple(0.55 * v for v in tone), -1)
    return _finish(image)


SKIN_TONES: tuple[Colour, ...] = (
    (236, 200, 172),
    (222, 178, 142),
    (198, 146, 108),
    (160, 110, 76),
    (120, 80, 55),
    (88, 60, 42),
)
HAIR_COLOURS: tuple[Colour, ...] = (
    (25, 20, 18),
    (55, 38, 25),
    (95, 65, 38),
    (165, 125, 75),
    (205, 180, 125),
    (130, 125, 120),
    (120, 55, 30),
)


def skin_tone(rng: np.random.Generator, tone: Colour, size: int = 128) -> np.ndarray:
    """Bare skin: the tone with soft blotches, pores and a few freckles."""
    image = _base(rng, size, tone, grain=10)
    for _ in range(10):
        c = tuple(int(v) for v in rng.integers(0, size, 2))
        axes = (int(rng.integers(4, 12)), int(rng.integers(2, 6)))
        cv2.ellipse(image, c, axes, float(rng.uniform(0, 180)), 0, 360, tuple(0.85 * v for v in tone), -1)
    for _ in range(25):
        c = tuple(int(v) for v in rng.integers(0, size, 2))
        cv2.circle(image, c, 1, tuple(0.7 * v for v in tone), -1)
    return _finish(image)


def hair(rng: np.random.Generator, colour: Colour, size: int = 128) -> np.ndarray:
    """Hair: dense strands, darker and lighter than the colour, mostly along one direction."""
    image = _base(rng, size, colour, grain=18)
    for _ in range(700):
        p = rng.uniform(0, size, 2)
        angle = rng.normal(np.pi / 2, 0.35)
        q = p + rng.uniform(6, 18) * np.array([np.cos(angle), np.sin(angle)])
        shade = tuple(
            float(np.clip(c * rng.uniform(0.55, 1.45) + rng.uniform(-8, 8), 0, 255)) for c in colour
        )
        cv2.line(image, tuple(int(v) for v in p), tuple(int(v) for v in q), shade, 1, cv2.LINE_AA)
    return _finish(image)


def hivis(rng: np.random.Generator, colour: Colour, size: int = 256) -> np.ndarray:
    """A high-visibility work vest: fluorescent fabric, two reflective bands, a print."""
    image = _base(rng, size, colour, grain=14)
    for y in (int(size * 0.35), int(size * 0.65)):
        cv2.rectangle(image, (0, y), (size, y + size // 14), (200, 202, 205), -1)
        cv2.rectangle(image, (0, y), (size, y + size // 14), (120, 120, 125), 1)
    _wear(rng, image, colour, folds=25)
    _text(rng, image, 1, (30, 30, 30), 0.6)
    return _finish(image)


def plastic(rng: np.random.Generator, colour: Colour, size: int = 64) -> np.ndarray:
    """Hard hats and caps: a smooth shell with a few scuffs."""
    image = _base(rng, size, colour, grain=12)
    for _ in range(8):
        p = rng.integers(0, size, 2)
        cv2.line(
            image,
            tuple(int(v) for v in p),
            tuple(int(v) for v in p + rng.integers(-6, 7, 2)),
            tuple(0.7 * c for c in colour),
            1,
        )
    return _finish(image)


FUR_PHOTO = asset("textures", "cat_fur.png")
"""A tabby's forehead fur, cropped from scikit-image's CC0 photograph of Chelsea the cat
(``assets/textures/PROVENANCE.md``)."""


@functools.cache
def _fur_photo() -> np.ndarray:
    image = cv2.imread(str(FUR_PHOTO), cv2.IMREAD_COLOR)
    if image is None:
        raise FileNotFoundError(f"{FUR_PHOTO}: the cats' fur photograph is missing or unreadable")
    image = np.ascontiguousarray(image[:, :, ::-1], dtype=np.float32)
    image.flags.writeable = False
    return image


def coat(rng: np.random.Generator, kind: str, size: int = 128) -> np.ndarray:
    """An animal's coat: one of its kind's colours (``QuadrupedBody.coat``) with a pattern
    (mud, a dark saddle) and fur strands over it, for a cube map; for 'photo' coats, the
    photographed fur in the coat's colour laid out round the body (``tabby``, twice ``size``)."""
    colours = actor_registry.get(kind).body.coat.colours  # type: ignore[union-attr]
    colour, pattern = colours[int(rng.integers(len(colours)))]
    if pattern == "photo":
        return tabby(colour, 2 * size)
    image = _base(rng, size, colour, grain=25)
    if pattern == "dirt":
        # Soft-edged smears a few shades off the coat, not dark spots: a Dalmatian's spots
        # would be the densest ORB corners of the scene and break up the animal's outline.
        for _ in range(4):
            c = tuple(int(v) for v in rng.integers(0, size, 2))
            axes = (int(rng.integers(14, 30)), int(rng.integers(10, 22)))
            cv2.ellipse(image, c, axes, float(rng.uniform(0, 180)), 0, 360, (170, 130, 105), -1)
    elif pattern == "saddle":
        cv2.rectangle(image, (0, 0), (size, size // 2), (25, 22, 20), -1)
    for _ in range(400):
        p = rng.integers(0, size, 2)
        q = p + rng.integers(-4, 5, 2)
        shade = tuple(float(np.clip(c * rng.uniform(0.65, 1.3), 0, 255)) for c in colour)
        cv2.line(image, tuple(int(v) for v in p), tuple(int(v) for v in q), shade, 1)
    return _finish(image)


def countershaded(image: np.ndarray, back: float, cream: float) -> np.ndarray:
    """A coat laid out round the body (rows from the belly over a flank to the back and
    down again) darkened along the back by up to ``back`` and blended towards cream
    underneath by up to ``cream``: most furred animals are paler below."""
    size = image.shape[0]
    around = np.cos(2 * np.pi * (np.arange(size) + 0.5) / size)[:, None, None]  # 1 under, -1 on top
    belly, top = np.clip(around, 0.0, 1.0), np.clip(-around, 0.0, 1.0)
    shaded = image.astype(np.float32) * (1.0 - back * top)
    return shaded + (np.array([235, 222, 200], np.float32) - shaded) * (cream * belly**2)


def tabby(colour: Colour, size: int = 256) -> np.ndarray:
    """A cat's coat laid out round the body (``countershaded``'s rows; columns along a
    part): the photographed fur in the coat's colour, mirrored so that it repeats without
    a seam, darker along the back and paling to cream underneath, as a cat is: the
    shading is what makes the fur a cat's body to a detector (a lone cat is recognised in
    116 of 120 views, docs/recognition.md)."""
    photo = _fur_photo()
    tile = np.concatenate([photo, photo[:, ::-1]], axis=1)
    tile = np.concatenate([tile, tile[::-1]], axis=0)
    with without_ipp():
        tile = cv2.resize(tile, (size // 2, size // 2), interpolation=cv2.INTER_AREA)
    fur = np.tile(tile, (2, 2, 1)) * (np.asarray(colour, np.float32) / tile.reshape(-1, 3).mean(axis=0))
    return _finish(countershaded(fur, back=0.3, cream=0.55))
