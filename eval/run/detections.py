"""A sequence's detections, computed once per (sequence, detector) and cached.

The detector itself (ground truth or a network) runs once per sequence and
detector configuration; its boxes and per-frame latency are cached on disk
(``depotbench.eval.run.cache``) keyed by a fingerprint of the sequence's files and the
detector's content key. Faults are applied on top, after the cache: they are
cheap and seeded, so changing a fault setting never re-runs a network.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depotbench.core.errors import InputError
from depotbench.core.files import file_digest
from depotbench.core.path_text import path_text
from depotbench.core.progress import progress_bar
from depotbench.core.version import code_version
from depotbench.detectors.base import DetectorFrame
from depotbench.detectors.config import DetectorConfig, DetectorKind, check_model_file
from depotbench.detectors.detection import Detection, Prior
from depotbench.detectors.faults import inject
from depotbench.detectors.groundtruth import GroundTruthDetector
from depotbench.eval.run.cache import StageCache, content_hash
from depotbench.sim.sequence import Sequence

CACHE_STAGE = "detections"
CACHE_FORMAT = 1
FINGERPRINT_FORMAT = "sequence-files-v3"


@dataclass(frozen=True)
class SequenceDetections:
    per_frame: tuple[tuple[Detection, ...], ...]
    latency_ms: np.ndarray
    """The detector's own time per frame, as measured when it ran (faults add none)."""
    from_cache: bool


def sequence_fingerprint(sequence: Sequence) -> str:
    """What every result on a sequence depends on: the bytes of every file of the sequence
    format it holds (``Sequence.files``) and the camera it is read with.

    It keys cached stages and sweep rows, so it hashes content, not stat: a depth PNG
    rewritten in place or a corrected groundtruth.txt gets a key of its own. Where the
    folder lies and what it is called are no part of it: a sequence copied, moved or renamed
    is the same sequence, its rows are resumed and paired with a baseline made elsewhere. A
    real folder's camera, guessed from its name (freiburg1/2/3) where it has no camera.yaml,
    is hashed as the camera it gave. Hashing a 300-frame 640x480 sequence reads about 150 MB
    once, at about 1.5 GB/s with SHA-256's CPU instructions; an opened ``Sequence`` is hashed
    once (``_FINGERPRINTS``).
    """
    known = _FINGERPRINTS.get(sequence)
    if known is None:
        digest = hashlib.sha256(FINGERPRINT_FORMAT.encode())
        digest.update(f"{sequence.intrinsics!r} {sequence.fps!r}".encode() + b"\0")
        for path in sequence.files():
            digest.update(os.fsencode(path.relative_to(sequence.root)) + b"\0")
            digest.update(file_digest(path, "sequence file"))
        known = _FINGERPRINTS[sequence] = digest.hexdigest()[:32]
    return known


_FINGERPRINTS: weakref.WeakKeyDictionary[Sequence, str] = weakref.WeakKeyDictionary()
"""Each opened sequence's fingerprint: an open sequence is hashed once however many stages
key on it (a branching sweep task asked three times: features, stages, detections). Opening
the folder again hashes it again, so a file changed between two opens is seen."""


def stored_path(root: Path, anchor: Path | None) -> str:
    """A sequence folder as rows name it: relative to ``anchor`` when inside it, else absolute,
    as text any store holds (``depotbench.core.path_text``: a name that is not UTF-8 too)."""
    absolute = root.resolve()
    if anchor is not None:
        base = anchor.resolve()
        if base in absolute.parents:
            return path_text(absolute.relative_to(base).as_posix())
    return path_text(absolute)


def build_detector(config: DetectorConfig, sequence: Sequence):
    if config.kind is DetectorKind.GROUNDTRUTH:
        return GroundTruthDetector(sequence, config.min_visible_pixels, config.priors)
    if config.kind is DetectorKind.ONNX:
        from depotbench.detectors.onnx import OnnxDetector, OnnxModelError

        try:
            return OnnxDetector(config.model_path, config.onnx, config.priors)
        except OnnxModelError as exc:
            raise InputError(str(exc)) from None
    raise ValueError(f"no detector for {config.kind}")


def detect_sequence(
    sequence: Sequence,
    config: DetectorConfig,
    cache: StageCache | None = None,
    progress: bool = False,
) -> SequenceDetections | None:
    """Every frame's detections (None for ``--detector none``), faults applied."""
    if config.kind is DetectorKind.NONE:
        return None
    base = config.base()
    if config.kind is DetectorKind.ONNX:
        check_model_file(config.model_path)
    # The ground-truth detector is cheap and refuses a sequence it cannot serve, so it is
    # built first; a network is loaded only when the cache does not have its boxes.
    detector = build_detector(base, sequence) if config.kind is DetectorKind.GROUNDTRUTH else None
    # this code's detections (``code_version``): a real folder's files, unlike a generated
    # one's meta.json, name no version
    key = content_hash(
        CACHE_FORMAT, code_version(), sequence_fingerprint(sequence), base.key(), base.priors.overrides
    )
    raw = _load(cache.get(CACHE_STAGE, key)) if cache is not None else None
    from_cache = raw is not None
    if raw is None:
        detector = detector or build_detector(base, sequence)
        raw = _run(detector, sequence, progress)
        if cache is not None:
            cache.put(CACHE_STAGE, key, _dump(*raw))
    per_frame, latency = raw
    if config.faults.active:
        difficulties = None
        if isinstance(detector, GroundTruthDetector) and _needs_difficulty(config):
            difficulties = [detector.difficulties(i) for i in range(len(sequence))]
        k = sequence.intrinsics
        per_frame = inject(
            list(per_frame),
            config.faults,
            (k.width, k.height),
            config.priors,
            sequence_seed=_sequence_seed(sequence),
            difficulties=difficulties,
        )
    return SequenceDetections(tuple(per_frame), latency, from_cache)


def _needs_difficulty(config: DetectorConfig) -> bool:
    f = config.faults
    return bool(f.miss_small or f.miss_occluded or f.miss_blurred)


def _sequence_seed(sequence: Sequence) -> int:
    seed = (sequence.meta or {}).get("seed", 0) if sequence.is_generated else 0
    return int(seed) if isinstance(seed, int) and seed >= 0 else 0


def _run(detector, sequence: Sequence, progress: bool) -> tuple[list[tuple[Detection, ...]], np.ndarray]:
    needs_image = not isinstance(detector, GroundTruthDetector)
    empty = np.zeros((0, 0, 3), np.uint8)
    per_frame, latency = [], []
    bar = progress_bar(
        range(len(sequence)),
        desc=f"detect {detector.name}",
        unit="frame",
        disable=not progress,
        leave=False,
    )
    with bar:
        for i in bar:
            frame = DetectorFrame(
                i, sequence.frames[i].timestamp_s, sequence.rgb(i) if needs_image else empty
            )
            started = time.perf_counter()
            per_frame.append(detector.detect(frame))
            latency.append((time.perf_counter() - started) * 1e3)
    return per_frame, np.array(latency)


def _dump(per_frame: list[tuple[Detection, ...]], latency: np.ndarray) -> bytes:
    frames = [
        [[*d.box_xyxy, d.class_name, d.prior.value, d.confidence] for d in boxes] for boxes in per_frame
    ]
    return json.dumps({"frames": frames, "latency_ms": latency.tolist()}).encode("utf-8")


def _load(data: bytes | None) -> tuple[list[tuple[Detection, ...]], np.ndarray] | None:
    if data is None:
        return None
    try:
        doc = json.loads(data)
        per_frame = [
            tuple(
                Detection((x0, y0, x1, y1), name, Prior(prior), conf)
                for x0, y0, x1, y1, name, prior, conf in f
            )
            for f in doc["frames"]
        ]
        return per_frame, np.array(doc["latency_ms"], float)
    except (ValueError, KeyError, TypeError):
        return None  # a damaged entry is recomputed, and overwritten
