"""How a detector sees the bench's scenes, before anyone blames the SLAM.

Detections are matched to the true visible boxes COCO's way: per image and
class, detections in falling confidence each take the unmatched true box they
overlap most, if IoU >= 0.5. Per class: precision and recall at the detector's
operating point and AP50 (COCO's 101-point interpolation). A ``dynamic`` row
matches across classes among dynamic priors, because SLAM only asks "is this a
mover?": a pig called dog still counts there. Recall is split by size (COCO's
small/medium/large), truncation by the image border and occlusion.

Class names on both sides are read through ``depotbench.detectors.coco.bench_name``, the
table the ONNX detector and ``export-dataset`` use: a detection called 'dining table',
'diningtable' or 'tvmonitor' (a model's table, a ``confusion`` fault, a plug-in) is the
bench's desk or tv, where it had scored as a miss beside a false positive of its own class.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from depotbench.core.errors import InputError
from depotbench.detectors.coco import bench_name
from depotbench.detectors.config import DetectorConfig
from depotbench.detectors.detection import Detection, Prior
from depotbench.detectors.faults import Difficulty
from depotbench.detectors.groundtruth import GroundTruthDetector, is_truncated
from depotbench.eval.run.cache import StageCache
from depotbench.eval.run.detections import detect_sequence
from depotbench.sim.sequence import Sequence

IOU_THRESHOLD = 0.5
DYNAMIC = "dynamic (any class)"
SIZES = (("small", 0.0, 32.0**2), ("medium", 32.0**2, 96.0**2), ("large", 96.0**2, np.inf))
OCCLUSION = (("none", 0.0, 0.1), ("partial", 0.1, 0.5), ("heavy", 0.5, 1.01))


@dataclass(frozen=True)
class TruthBox:
    box_xyxy: tuple[float, float, float, float]
    class_name: str
    prior: Prior
    difficulty: Difficulty
    truncated: bool
    ignored: bool = False
    """Too small to count (below min_visible_pixels): a detection of it is neither right nor wrong."""

    def groups(self) -> list[str]:
        """The recall splits this object falls in."""
        area, occ = self.difficulty.area_px, self.difficulty.occlusion
        out = [name for name, low, high in SIZES if low <= area < high]
        out.append("truncated" if self.truncated else "whole")
        out += [f"occlusion {name}" for name, low, high in OCCLUSION if low <= occ < high]
        return out


@dataclass
class ClassResult:
    truths: int = 0
    detections: int = 0
    true_positives: int = 0
    ap50: float | None = None
    recall_by_group: dict[str, tuple[int, int]] = field(default_factory=dict)
    """group -> (found, total)."""

    @property
    def precision(self) -> float | None:
        return self.true_positives / self.detections if self.detections else None

    @property
    def recall(self) -> float | None:
        return self.true_positives / self.truths if self.truths else None


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of every box in ``a`` (N x 4, xyxy) with every box in ``b`` (M x 4)."""
    if not len(a) or not len(b):
        return np.zeros((len(a), len(b)))
    x0 = np.maximum(a[:, None, 0], b[None, :, 0])
    y0 = np.maximum(a[:, None, 1], b[None, :, 1])
    x1 = np.minimum(a[:, None, 2], b[None, :, 2])
    y1 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return inter / (area_a[:, None] + area_b[None, :] - inter)


def match(detections: list[Detection], truths: list[TruthBox]) -> tuple[np.ndarray, np.ndarray]:
    """COCO greedy matching: (per detection, matched truth index or -1; per truth, matched)."""
    order = sorted(range(len(detections)), key=lambda i: -detections[i].confidence)
    ious = iou_matrix(
        np.array([d.box_xyxy for d in detections], float).reshape(-1, 4),
        np.array([t.box_xyxy for t in truths], float).reshape(-1, 4),
    )
    matched_truth = np.full(len(detections), -1)
    taken = np.zeros(len(truths), bool)
    for i in order:
        candidates = np.where(~taken, ious[i], -1.0) if len(truths) else np.zeros(0)
        if len(candidates) and candidates.max() >= IOU_THRESHOLD:
            j = int(candidates.argmax())
            taken[j] = True
            matched_truth[i] = j
    return matched_truth, taken


def average_precision(scores: np.ndarray, hits: np.ndarray, truths: int) -> float | None:
    """COCO's AP at one IoU: the precision envelope sampled at 101 recall points."""
    if truths == 0:
        return None
    order = np.argsort(-scores, kind="mergesort")  # pycocotools sorts the same way
    tp = np.cumsum(hits[order])
    fp = np.cumsum(~hits[order])
    recall = tp / truths
    precision = tp / np.maximum(tp + fp, np.finfo(float).eps)
    envelope = np.maximum.accumulate(precision[::-1])[::-1] if len(precision) else precision
    points = np.linspace(0.0, 1.0, 101)
    index = np.searchsorted(recall, points, side="left")
    sampled = np.array([envelope[i] if i < len(envelope) else 0.0 for i in index])
    return float(sampled.mean())


@dataclass
class _Tally:
    scores: list[float] = field(default_factory=list)
    hits: list[bool] = field(default_factory=list)
    truths: int = 0
    groups: dict[str, list[int]] = field(default_factory=lambda: defaultdict(lambda: [0, 0]))


def truth_boxes(
    sequence: Sequence, detector: GroundTruthDetector, index: int, min_visible_pixels: int
) -> list[TruthBox]:
    k = sequence.intrinsics
    return [
        TruthBox(
            tuple(float(v) for v in o.box_xyxy),
            bench_name(o.class_name),
            detector.priors.prior(o.class_name),
            diff,
            is_truncated(o, k.width, k.height),
            o.visible_pixels < min_visible_pixels,
        )
        for o, diff in zip(detector.visible(index), detector.difficulties(index), strict=True)
    ]


def refuse_repeats(sequences: list[Sequence]) -> None:
    """Refuse a sequence folder given twice, as ``export-dataset`` does: its truths would count
    twice (``detect-eval seq seq ./seq/`` reported 18 frames of a 6-frame sequence)."""
    first: dict[Path, Path] = {}
    for sequence in sequences:
        real = sequence.root.resolve()
        if real in first:
            also = "" if first[real] == sequence.root else f" (also as {first[real]})"
            raise InputError(f"{sequence.root}: the sequence is given twice{also}; give each once")
        first[real] = sequence.root


def evaluate_detector(
    sequences: list[Sequence],
    config: DetectorConfig,
    cache: StageCache | None = None,
    progress: bool = False,
    min_visible_pixels: int = 1000,
) -> dict:
    """Per class and for dynamic priors: precision, recall, AP50 and recall splits; latency."""
    refuse_repeats(sequences)
    tallies: dict[str, _Tally] = defaultdict(_Tally)
    latency = []
    for sequence in sequences:
        detections = detect_sequence(sequence, config, cache, progress)
        if detections is None:
            raise ValueError("detect-eval needs a detector (not none)")
        latency.append(detections.latency_ms)
        truth_source = GroundTruthDetector(sequence, 1, config.priors)
        for i, boxes in enumerate(detections.per_frame):
            found = [in_bench_words(d) for d in boxes]
            truths = truth_boxes(sequence, truth_source, i, min_visible_pixels)
            for name in {t.class_name for t in truths} | {d.class_name for d in found}:
                _tally(
                    tallies[name],
                    [d for d in found if d.class_name == name],
                    [t for t in truths if t.class_name == name],
                )
            _tally(
                tallies[DYNAMIC],
                [d for d in found if d.prior is Prior.DYNAMIC],
                [t for t in truths if t.prior is Prior.DYNAMIC],
            )
    classes = {}
    for name, t in sorted(tallies.items()):
        hits = np.array(t.hits, bool)
        result = ClassResult(
            truths=t.truths,
            detections=len(t.hits),
            true_positives=int(hits.sum()),
            ap50=average_precision(np.array(t.scores), hits, t.truths),
            recall_by_group={g: (found, total) for g, (found, total) in sorted(t.groups.items())},
        )
        classes[name] = asdict(result) | {"precision": result.precision, "recall": result.recall}
    times = np.concatenate(latency) if latency else np.zeros(0)
    return {
        "detector": config.to_dict(),
        "sequences": [str(s.root) for s in sequences],
        "frames": int(sum(len(s) for s in sequences)),
        "iou_threshold": IOU_THRESHOLD,
        "min_visible_pixels": min_visible_pixels,
        "latency_ms": (
            {"mean": float(times.mean()), "median": float(np.median(times))} if len(times) else None
        ),
        "classes": classes,
    }


def in_bench_words(detection: Detection) -> Detection:
    """The detection with its class named as the truth names it (its prior is the detector's)."""
    name = bench_name(detection.class_name)
    return detection if name == detection.class_name else replace(detection, class_name=name)


def _tally(tally: _Tally, detections: list[Detection], truths: list[TruthBox]) -> None:
    matched, taken = match(detections, truths)
    for det, m in zip(detections, matched, strict=True):
        if m >= 0 and truths[m].ignored:
            continue
        tally.scores.append(det.confidence)
        tally.hits.append(bool(m >= 0))
    counted = [(t, found) for t, found in zip(truths, taken, strict=True) if not t.ignored]
    tally.truths += len(counted)
    for truth, found in counted:
        for group in truth.groups():
            tally.groups[group][0] += int(found)
            tally.groups[group][1] += 1


GROUP_ORDER = (
    "small",
    "medium",
    "large",
    "whole",
    "truncated",
    "occlusion none",
    "occlusion partial",
    "occlusion heavy",
)


def format_evaluation(report: dict) -> str:
    from depotbench.core.text_table import Column, cell, render

    rows = []
    for name, c in report["classes"].items():
        groups = "  ".join(
            f"{g} {c['recall_by_group'][g][0]}/{c['recall_by_group'][g][1]}"
            for g in GROUP_ORDER
            if g in c["recall_by_group"]
        )
        rows.append(
            [
                name,
                str(c["truths"]),
                str(c["detections"]),
                cell(c["precision"], ".3f"),
                cell(c["recall"], ".3f"),
                cell(c["ap50"], ".3f"),
                groups,
            ]
        )
    columns = [Column("class", "left"), *(Column(h) for h in ("truths", "dets", "prec", "recall", "AP50"))]
    lines = [render([*columns, Column("recall by group (found/total)", "left")], rows)]
    lat = report["latency_ms"]
    if lat:
        lines.append(
            f"\n{report['frames']} frames; detector {lat['mean']:.1f} ms mean, {lat['median']:.1f} ms median "
            "per frame (as measured when the boxes were computed)"
        )
    return "\n".join(lines)
