"""Threshold-independent stages of the built-in tracker, computed once and cached.

- Features (ORB keypoints, descriptors, depth at keypoints, undistorted
  positions) per (sequence files, every tracking setting, camera), with each
  keypoint's true moving label for generated sequences.
- Flow (LK of every keypoint into the previous frame) per (features, LK window
  and levels): one flow stage serves every flow-based strategy and every value of
  their thresholds.

A run given these stages reads no image, extracts nothing and runs no LK; its
decisions and results are bit for bit those of a run that computed them
itself (``tests/test_stages.py``). The time each stage took when it was
computed is kept with it and reported in the run's extraction and rejection
times, so cached runs do not look faster than the tracker is.
"""

from __future__ import annotations

import hashlib
import io
import time
import zipfile
import zlib
from dataclasses import asdict, dataclass

import numpy as np
from depotbench.core.progress import progress_bar
from depotbench.core.version import code_version
from depotbench.eval.run.cache import StageCache, content_hash
from depotbench.eval.run.detections import sequence_fingerprint
from depotbench.eval.trackers.builtin import camera_of, true_moving_labels
from depotbench.sim.sequence import Sequence
from depotbench.slam import kernels
from depotbench.slam.config import RejectionConfig, SlamConfig, TrackingConfig
from depotbench.slam.features import FeatureExtractor, FrameFeatures
from depotbench.slam.rejection import Flow, classify, flow_to_previous
from depotbench.slam.system import seed_frame
from depotbench.slam.types import REJECTION_CODES, Rejection

FEATURES_STAGE = "features"
FLOW_STAGE = "flow"
STAGE_FORMAT = 2
"""2: stage times measured with the kernels compiled beforehand (``kernels.ready``): a stage
kept from before may hold the compile time in its first frames, so it is measured again."""
NO_IMAGE = np.zeros((0, 0), np.uint8)
_FIELDS = ("keypoints_px", "undistorted_px", "octaves", "descriptors", "depth_m", "angles_deg")


@dataclass(frozen=True)
class FrameStages:
    features: FrameFeatures
    """With an empty ``grey``: the image is not kept."""
    labels: np.ndarray | None
    extract_ms: float
    flow: Flow | None = None
    flow_ms: float = 0.0


def features_key(sequence: Sequence, tracking: TrackingConfig) -> str:
    """The features of a sequence, its tracking settings and camera, as this code
    (``code_version``) extracts them: a version may find other keypoints (0.5.3 did on 2-3 %
    of a frame), and a real folder's files, unlike a generated one's meta.json, name no
    version."""
    camera = camera_of(sequence)
    return content_hash(
        STAGE_FORMAT, code_version(), sequence_fingerprint(sequence), asdict(tracking), repr(camera)
    )


def flow_key(features: str, rejection: RejectionConfig) -> str:
    return content_hash(STAGE_FORMAT, features, rejection.lk_window_px, rejection.lk_levels)


def sequence_stages(
    sequence: Sequence,
    tracking: TrackingConfig,
    rejection: RejectionConfig,
    need_flow: bool,
    cache: StageCache | None,
    progress: bool = False,
) -> list[FrameStages]:
    """Every frame's features (and flow, when asked), from the cache or computed and cached."""
    f_key = features_key(sequence, tracking)
    l_key = flow_key(f_key, rejection)
    features = _load(cache.get(FEATURES_STAGE, f_key)) if cache is not None else None
    flows = _load(cache.get(FLOW_STAGE, l_key)) if cache is not None and need_flow else None
    if features is not None and (flows is not None or not need_flow):
        return _assemble(features, flows if need_flow else None)
    kernels.ready()  # the times kept with the stages must not include compiling
    features, flows = _compute(sequence, tracking, rejection, progress)
    if cache is not None:
        cache.put(FEATURES_STAGE, f_key, _dump(features))
        cache.put(FLOW_STAGE, l_key, _dump(flows))
    return _assemble(features, flows if need_flow else None)


def _compute(
    sequence: Sequence, tracking: TrackingConfig, rejection: RejectionConfig, progress: bool
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    camera = camera_of(sequence)
    extractor = FeatureExtractor(tracking)
    objects = sequence.objects() if sequence.is_generated else None
    scale = np.float32(sequence.intrinsics.depth_scale)
    per_frame: dict[str, list[np.ndarray]] = {name: [] for name in _FIELDS}
    counts, labels, extract_ms, flow_prev, flow_ok, flow_ms = [], [], [], [], [], []
    previous = None
    for i in progress_bar(
        range(len(sequence)), desc="features", unit="frame", disable=not progress, leave=False
    ):
        rgb, depth = sequence.rgb(i), sequence.depth_raw(i).astype(np.float32) / scale
        started = time.perf_counter()
        current = extractor.extract(rgb, depth, camera)
        extract_ms.append((time.perf_counter() - started) * 1e3)
        started = time.perf_counter()
        if previous is None:
            prev, ok = np.full((len(current), 2), np.nan, np.float32), np.zeros(len(current), bool)
        else:
            prev, ok = flow_to_previous(previous, current, rejection)
        flow_ms.append((time.perf_counter() - started) * 1e3)
        flow_prev.append(np.asarray(prev, np.float32).reshape(-1, 2))
        flow_ok.append(np.asarray(ok, bool))
        for name in _FIELDS:
            per_frame[name].append(getattr(current, name))
        counts.append(len(current))
        if objects is not None:
            moving = {o.instance_id for o in objects[i] if o.moving}
            labels.append(true_moving_labels(sequence, i, current.keypoints_px, moving))
        previous = current
    features = {name: np.concatenate(values) if values else np.zeros(0) for name, values in per_frame.items()}
    features |= {"counts": np.array(counts), "extract_ms": np.array(extract_ms)}
    if labels:
        features["labels"] = np.concatenate(labels)
    flows = {
        "prev": np.concatenate(flow_prev) if flow_prev else np.zeros((0, 2), np.float32),
        "ok": np.concatenate(flow_ok) if flow_ok else np.zeros(0, bool),
        "counts": np.array(counts),
        "flow_ms": np.array(flow_ms),
    }
    return features, flows


def _assemble(features: dict[str, np.ndarray], flows: dict[str, np.ndarray] | None) -> list[FrameStages]:
    counts = features["counts"]
    bounds = np.r_[0, np.cumsum(counts)]
    out = []
    for i in range(len(counts)):
        lo, hi = int(bounds[i]), int(bounds[i + 1])
        frame = FrameFeatures(NO_IMAGE, *(features[name][lo:hi] for name in _FIELDS))
        labels = features["labels"][lo:hi] if "labels" in features else None
        flow, flow_ms = None, 0.0
        if flows is not None and i > 0:
            flow, flow_ms = (flows["prev"][lo:hi], flows["ok"][lo:hi]), float(flows["flow_ms"][i])
        out.append(FrameStages(frame, labels, float(features["extract_ms"][i]), flow, flow_ms))
    return out


def _dump(arrays: dict[str, np.ndarray]) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _load(data: bytes | None) -> dict[str, np.ndarray] | None:
    if data is None:
        return None
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            return {name: archive[name] for name in archive.files}
    except (ValueError, OSError, KeyError, EOFError, zipfile.BadZipFile, zlib.error):
        return None  # a damaged entry is recomputed


def decision_path(
    stages: list[FrameStages],
    detections: list[tuple] | None,
    config: SlamConfig,
    memos: list[dict] | None = None,
    reasons: bool = False,
) -> tuple[str, ...]:
    """Per frame, a hash of which keypoints the strategy keeps, computed without tracking
    (``reasons``: and why it rejects the others, which a dense map's exclusion follows).

    Rejection depends on the frame, the previous frame, the boxes and the flow, never on
    the tracker's state; tracking sees only the kept keypoints. So two threshold settings
    of one strategy whose paths are equal give the same run, and a sweep tracks it once;
    settings whose paths agree up to some frame share the run up to there and fork
    (``tests/test_sweep.py`` checks both against tracking each job alone). ``memos`` (a
    dict per frame) carry ``classify``'s shared work from one setting's path to the next.
    """
    kept = REJECTION_CODES[Rejection.KEPT]
    path = []
    previous = None
    for i, stage in enumerate(stages):
        seed_frame(config.tracking, i)
        boxes = detections[i] if detections is not None else ()
        memo = memos[i] if memos is not None else None
        codes = classify(config.strategy, stage.features, previous, boxes, config.rejection, stage.flow, memo)
        digest = hashlib.sha256(codes.tobytes() if reasons else np.packbits(codes == kept).tobytes())
        digest.update(len(codes).to_bytes(4, "little"))
        path.append(digest.hexdigest()[:16])
        previous = stage.features
    return tuple(path)


def decision_signature(path: tuple[str, ...], features: str, strategy: str, dense_map: bool = False) -> str:
    """One hash of a whole decision path: jobs with equal signatures are one run (a run with
    its dense map is not one without)."""
    return content_hash(STAGE_FORMAT, features, strategy, list(path), *(["dense_map"] if dense_map else []))
