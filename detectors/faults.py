"""Seeded fault injection: a detector's failures, dialled in exactly.

Every fault is off by default and set by name (``--fault miss=0.3``). Faults act
on the whole sequence's detections at once, because some of them (latency, a
detector that runs every n-th frame) move boxes between frames. Each frame draws
from its own generator, seeded from (fault seed, sequence seed, frame index), so
a frame's faults do not depend on which other frames were processed, and the
same configuration gives the same boxes on every run.

Per box, in this order: the miss draw, class confusion, scale bias, edge jitter,
confidence noise. Per frame: false positives are added, then the frame may be
dropped. Over the sequence: every-n-th-frame holding, then latency.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from depotbench.detectors.detection import Detection
from depotbench.detectors.priors import PriorTable


class FaultError(ValueError):
    """A fault setting out of range, malformed, or unknown."""


@dataclass(frozen=True)
class Difficulty:
    """What makes one true object hard to detect (known only for ground-truth boxes)."""

    area_px: float
    occlusion: float
    """0 (in plain view) .. 1 (hidden): 1 - visible fraction where the sequence records it,
    else the share of its outline that borders a nearer surface."""
    speed_px: float
    """Image motion of its centre between frames, px per frame (blur grows with it)."""


@dataclass(frozen=True)
class Faults:
    miss: float = 0.0
    """Probability that any box is missed."""
    miss_small: float = 0.0
    """Extra miss probability of boxes smaller than ``small_area_px``."""
    small_area_px: float = 1024.0
    """COCO's 'small': 32 x 32 px."""
    miss_occluded: float = 0.0
    """Extra miss probability of a fully occluded object, scaled by its occlusion."""
    miss_blurred: float = 0.0
    """Extra miss probability at ``blur_px`` of image motion per frame and above, linear below."""
    blur_px: float = 20.0
    jitter: float = 0.0
    """Std of each box edge, as a fraction of the box's width (x0, x1) or height (y0, y1)."""
    scale: float = 1.0
    """Box width and height times this about the centre: > 1 loose, < 1 tight boxes."""
    false_positives: float = 0.0
    """Mean false boxes per frame (Poisson), of class ``false_positive_class``."""
    false_positive_class: str = "person"
    confusion: tuple[tuple[str, str, float], ...] = ()
    """(true class, reported class, probability) rows: 'person->dog:0.1;pig->person:0.5'."""
    latency: int = 0
    """Frame i gets the boxes of frame i - latency (none before that)."""
    confidence_noise: float = 0.0
    """Std of Gaussian noise added to confidences (clipped to [0, 1])."""
    drop: float = 0.0
    """Probability that a frame returns no boxes at all."""
    every: int = 1
    """The detector runs on every n-th frame only; boxes are held in between."""
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("miss", "miss_small", "miss_occluded", "miss_blurred", "drop"):
            _in_range(name, getattr(self, name), 0.0, 1.0)
        _in_range("small_area_px", self.small_area_px, 1.0, 1e7)
        _in_range("blur_px", self.blur_px, 0.1, 1e4)
        _in_range("jitter", self.jitter, 0.0, 1.0)
        _in_range("scale", self.scale, 0.1, 10.0)
        _in_range("false_positives", self.false_positives, 0.0, 100.0)
        _in_range("latency", self.latency, 0, 1000)
        _in_range("confidence_noise", self.confidence_noise, 0.0, 1.0)
        _in_range("every", self.every, 1, 1000)
        _in_range("seed", self.seed, 0, 2**63 - 1)
        rows: dict[str, float] = {}
        for true_class, _, p in self.confusion:
            _in_range(f"confusion {true_class}", p, 0.0, 1.0)
            rows[true_class] = rows.get(true_class, 0.0) + p
        over = [c for c, total in rows.items() if total > 1.0 + 1e-9]
        if over:
            raise FaultError(f"confusion probabilities of {over[0]!r} sum to {rows[over[0]]:g} > 1")

    @property
    def active(self) -> bool:
        return self != Faults(seed=self.seed)

    def with_settings(self, settings: dict[str, str]) -> Faults:
        """Apply ``name=value`` overrides (the CLI's ``--fault``)."""
        kinds = {f.name: f.type for f in fields(self)}
        values: dict[str, Any] = {}
        for name, text in settings.items():
            if name not in kinds:
                raise FaultError(f"unknown fault {name!r}; known: {', '.join(sorted(kinds))}")
            values[name] = _parse_value(name, text, kinds[name])
        merged = {f: getattr(self, f) for f in kinds} | values
        return Faults(**merged)

    def summary(self) -> str:
        """The settings that differ from no faults, as ``latency=3,miss=0.5`` (a label's part:
        two fault models must never share a name in a table or a gate)."""
        default = Faults(seed=self.seed) if self.active else self
        parts = []
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "seed" or value == getattr(default, f.name):
                continue
            if f.name == "confusion":
                value = ";".join(f"{a}->{b}:{p:g}" for a, b, p in value)
            elif isinstance(value, float):
                value = f"{value:g}"
            parts.append(f"{f.name}={value}")
        if self.active and self.seed != 0:
            parts.append(f"seed={self.seed}")
        return ",".join(parts)

    def to_dict(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["confusion"] = [list(row) for row in self.confusion]
        return out


def check_range(
    label: str, value: float, low: float, high: float, error: type[ValueError] = FaultError
) -> None:
    """``value`` a finite number in [low, high], or ``error`` naming ``label``."""
    if not (isinstance(value, int | float) and math.isfinite(value) and low <= value <= high):
        raise error(f"{label} = {value!r} is out of range [{low:g}, {high:g}]")


def _in_range(name: str, value: float, low: float, high: float) -> None:
    check_range(f"fault {name}", value, low, high)


def _parse_value(name: str, text: str, kind: Any) -> Any:
    if name == "confusion":
        return parse_confusion(text)
    if kind in ("str", str):
        if not text.strip():
            raise FaultError(f"fault {name} is empty")
        return text.strip()
    try:
        return int(text) if kind in ("int", int) else float(text)
    except ValueError:
        raise FaultError(f"fault {name}={text!r} is not a number") from None


def parse_confusion(text: str) -> tuple[tuple[str, str, float], ...]:
    """'person->dog:0.1;pig->person:0.5' as rows; '' is no confusion."""
    rows = []
    for item in filter(None, (s.strip() for s in text.split(";"))):
        try:
            pair, p = item.rsplit(":", 1)
            source, target = (s.strip() for s in pair.split("->"))
            prob = float(p)
        except ValueError:
            raise FaultError(f"confusion {item!r} is not 'true class->reported class:probability'") from None
        if not source or not target or source == target:
            raise FaultError(f"confusion {item!r} needs two different class names")
        rows.append((source, target, prob))
    return tuple(rows)


def frame_rng(faults: Faults, sequence_seed: int, index: int) -> np.random.Generator:
    return np.random.default_rng([faults.seed, sequence_seed & (2**63 - 1), index])


def inject(
    detections: list[tuple[Detection, ...]],
    faults: Faults,
    image_size: tuple[int, int],
    priors: PriorTable,
    sequence_seed: int = 0,
    difficulties: list[tuple[Difficulty | None, ...]] | None = None,
) -> list[tuple[Detection, ...]]:
    """The detections of a whole sequence with the faults applied.

    ``difficulties`` (one per detection, or None) make small, occluded and moving
    objects harder to detect; without them only the plain ``miss`` applies.
    ``image_size`` is (width, height).
    """
    if not faults.active:
        return list(detections)
    per_frame = []
    for index, boxes in enumerate(detections):
        rng = frame_rng(faults, sequence_seed, index)
        hard = difficulties[index] if difficulties is not None else (None,) * len(boxes)
        kept = [
            faulted
            for det, diff in zip(boxes, hard, strict=True)
            if (faulted := _box_faults(det, diff, faults, rng, image_size, priors)) is not None
        ]
        kept.extend(_false_positives(faults, rng, image_size, priors))
        if rng.random() < faults.drop:
            kept = []
        per_frame.append(tuple(kept))
    if faults.every > 1:
        per_frame = [per_frame[i - i % faults.every] for i in range(len(per_frame))]
    if faults.latency:
        k = faults.latency
        per_frame = [per_frame[i - k] if i >= k else () for i in range(len(per_frame))]
    return per_frame


def miss_probability(faults: Faults, difficulty: Difficulty | None) -> float:
    keep = 1.0 - faults.miss
    if difficulty is not None:
        if difficulty.area_px < faults.small_area_px:
            keep *= 1.0 - faults.miss_small
        keep *= 1.0 - faults.miss_occluded * min(1.0, max(0.0, difficulty.occlusion))
        keep *= 1.0 - faults.miss_blurred * min(1.0, difficulty.speed_px / faults.blur_px)
    return 1.0 - keep


def _box_faults(
    det: Detection,
    difficulty: Difficulty | None,
    faults: Faults,
    rng: np.random.Generator,
    image_size: tuple[int, int],
    priors: PriorTable,
) -> Detection | None:
    # Every box draws the same numbers whatever the settings, so turning one fault up
    # does not reshuffle the others' draws.
    u_miss, u_confuse = rng.random(2)
    edges = rng.standard_normal(4)
    noise = rng.standard_normal()
    if u_miss < miss_probability(faults, difficulty):
        return None
    name = _confused(det.class_name, faults.confusion, u_confuse)
    x0, y0, x1, y1 = det.box_xyxy
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    w, h = (x1 - x0) * faults.scale, (y1 - y0) * faults.scale
    x0, x1 = cx - w / 2 + edges[0] * faults.jitter * w, cx + w / 2 + edges[1] * faults.jitter * w
    y0, y1 = cy - h / 2 + edges[2] * faults.jitter * h, cy + h / 2 + edges[3] * faults.jitter * h
    box = _clip_box((x0, y0, x1, y1), image_size)
    if box is None:
        return None
    confidence = det.confidence
    if faults.confidence_noise:
        confidence = float(np.clip(confidence + noise * faults.confidence_noise, 0.0, 1.0))
    return Detection(box, name, priors.prior(name) if name != det.class_name else det.prior, confidence)


def _confused(name: str, table: tuple[tuple[str, str, float], ...], u: float) -> str:
    cumulative = 0.0
    for source, target, p in table:
        if source == name:
            cumulative += p
            if u < cumulative:
                return target
    return name


def _clip_box(
    box: tuple[float, float, float, float], image_size: tuple[int, int]
) -> tuple[float, float, float, float] | None:
    """The box inside the image; None when less than a pixel of it is left."""
    width, height = image_size
    x0, y0, x1, y1 = box
    if x1 < x0:
        x0, x1 = x1, x0
    if y1 < y0:
        y0, y1 = y1, y0
    x0, x1 = max(0.0, x0), min(float(width), x1)
    y0, y1 = max(0.0, y0), min(float(height), y1)
    if x1 - x0 < 1.0 or y1 - y0 < 1.0:
        return None
    return (float(x0), float(y0), float(x1), float(y1))


def _false_positives(
    faults: Faults, rng: np.random.Generator, image_size: tuple[int, int], priors: PriorTable
) -> list[Detection]:
    """Poisson many boxes, log-uniform 20-200 px a side, uniform over the image."""
    count = int(rng.poisson(faults.false_positives)) if faults.false_positives else 0
    width, height = image_size
    out = []
    for _ in range(count):
        w, h = np.exp(rng.uniform(np.log(20.0), np.log(200.0), 2))
        w, h = min(w, width - 1.0), min(h, height - 1.0)
        x0, y0 = rng.uniform(0, width - w), rng.uniform(0, height - h)
        name = faults.false_positive_class
        out.append(Detection((x0, y0, x0 + w, y0 + h), name, priors.prior(name), 1.0))
    return out
