"""The built-in ORB-SLAM2-style pipeline behind the tracker interface."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.core.progress import progress_bar
from depotbench.eval.trackers.base import TrackerRun
from depotbench.eval.trackers.frames import FrameSource
from depotbench.sim.sequence import Sequence
from depotbench.slam import kernels
from depotbench.slam.config import SlamConfig
from depotbench.slam.rejection import box_classes, classify
from depotbench.slam.system import Slam, seed_frame
from depotbench.slam.types import Frame, FrameResult
from threadpoolctl import threadpool_limits

STAGES = ("extract", "reject", "track", "tracking_total", "mapping")


def one_blas_thread() -> threadpool_limits:
    """Track with one BLAS thread: the pipeline is sequential and its matrices small (the
    local BA's reduced system is at most ~500 square). With OpenBLAS's thread per core, on a
    2-core machine doing other work, that solve took 20 ms instead of 0.4 ms: the threads
    spin against the other load. Sweep workers run with one already."""
    return threadpool_limits(1, user_api="blas")


def camera_of(sequence: Sequence) -> Intrinsics:
    """The camera the tracker projects with: the sequence's own, distortion and all."""
    return sequence.intrinsics


def true_moving_labels(
    sequence: Sequence, index: int, keypoints: np.ndarray, moving_ids: set[int]
) -> np.ndarray:
    """True where a keypoint lies on an instance that moves in this frame."""
    instances = sequence.instances(index)
    h, w = instances.shape
    cols = np.clip(np.rint(keypoints[:, 0]).astype(int), 0, w - 1)
    rows = np.clip(np.rint(keypoints[:, 1]).astype(int), 0, h - 1)
    return np.isin(instances[rows, cols], list(moving_ids))


def _charge(result, stage) -> None:
    """Report a cached stage's time as if it had run now (it ran once, when cached)."""
    times = result.diagnostics.stage_ms
    times["extract"] = stage.extract_ms
    if stage.flow is not None:
        times["reject"] += stage.flow_ms
    times["tracking_total"] = times["extract"] + times["reject"] + times["track"]


class BuiltinTracker:
    name = "builtin"

    def __init__(self, config: SlamConfig, stages: list | None = None) -> None:
        """``stages``: per frame, cached features (and flow) from ``depotbench.eval.run.stages``."""
        self.config = config
        self.stages = stages
        self._blank: tuple[np.ndarray, np.ndarray] | None = None

    def run(self, frames: FrameSource, progress: bool) -> TrackerRun:
        kernels.ready()  # compiled before the clock starts: no frame's time includes it
        with one_blas_thread():
            return self._run(frames, progress)

    def _run(self, frames: FrameSource, progress: bool) -> TrackerRun:
        sequence = frames.sequence
        started = time.perf_counter()
        slam = Slam(self.config, camera_of(sequence))
        if self.stages is not None and len(self.stages) != len(frames):
            raise ValueError(f"{len(self.stages)} frames of stages for {len(frames)} frames")
        objects = sequence.objects() if sequence.is_generated and self.stages is None else None
        results, labels = [], []
        bar = progress_bar(
            range(len(frames)),
            desc=f"slam {self.config.strategy}",
            unit="frame",
            disable=not progress,
            leave=False,
        )
        with bar:  # closed (and its line cleared) before an error is printed
            for i in bar:
                if self.stages is not None:
                    results.append(self._step(slam, frames, i))
                    if self.stages[i].labels is not None:
                        labels.append(self.stages[i].labels)
                    continue
                rgb, depth_raw = frames.images(i)
                depth_m = depth_raw.astype(np.float32) / np.float32(sequence.intrinsics.depth_scale)
                frame = Frame(frames.timestamp_s(i), rgb, depth_m, slam.camera, frames.detections(i))
                result = slam.process(frame)
                results.append(result)
                if objects is not None:
                    moving = {o.instance_id for o in objects[i] if o.moving}
                    labels.append(true_moving_labels(sequence, i, result.diagnostics.keypoints_px, moving))
        return _tracker_run(results, labels, slam, time.perf_counter() - started)

    def _step(self, slam: Slam, frames: FrameSource, i: int):
        """Track frame ``i`` from its cached stages (no image is read)."""
        stage = self.stages[i]
        k = frames.sequence.intrinsics
        if self._blank is None:
            self._blank = (
                np.zeros((k.height, k.width, 3), np.uint8),
                np.zeros((k.height, k.width), np.float32),
            )
        frame = Frame(frames.timestamp_s(i), *self._blank, slam.camera, frames.detections(i))
        result = slam.process(frame, stage.features, stage.flow)
        _charge(result, stage)
        return result

    def run_tree(
        self, frames: FrameSource, configs: list[SlamConfig], paths: list[tuple[str, ...]]
    ) -> list[TrackerRun]:
        """Runs of several configurations that keep the same keypoints up to some frame.

        ``paths[j]`` names, per frame, which keypoints configuration j keeps (a hash,
        ``depotbench.eval.run.stages.decision_path``). While configurations agree they are one run;
        where they part, the system is forked (``Slam.fork``) and each branch goes
        on. Each run equals, bit for bit, the run of its configuration alone
        (``tests/test_sweep.py``): a shared frame is tracked once, and each
        configuration's own rejection reasons and box classes are put in its results.
        Its per-frame times are those of the shared run up to where it parted. Needs
        the cached stages.
        """
        kernels.ready()
        with one_blas_thread():
            return self._run_tree(frames, configs, paths)

    def _run_tree(
        self, frames: FrameSource, configs: list[SlamConfig], paths: list[tuple[str, ...]]
    ) -> list[TrackerRun]:
        if self.stages is None:
            raise ValueError("run_tree needs the cached stages")
        if len(configs) != len(paths) or any(len(p) != len(frames) for p in paths):
            raise ValueError("one decision path of every frame per configuration")
        runs: list[TrackerRun | None] = [None] * len(configs)
        labels = [s.labels for s in self.stages if s.labels is not None]
        memos: dict[int, dict] = {}
        # Depth-first over the branches: (system, next frame, members, (result, configuration
        # that made it) per frame, seconds so far).
        pending = [(Slam(configs[0], camera_of(frames.sequence)), 0, list(range(len(configs))), [], 0.0)]
        while pending:
            slam, i, members, results, elapsed = pending.pop()
            while i < len(frames):
                groups: dict[str, list[int]] = {}
                for m in members:
                    groups.setdefault(paths[m][i], []).append(m)
                if len(groups) > 1:
                    break
                started = time.perf_counter()
                results.append((self._step(slam, frames, i), slam.config))
                elapsed += time.perf_counter() - started
                i += 1
            if i == len(frames):
                for m in members:
                    own = []
                    for k, (result, made_by) in enumerate(results):
                        if made_by != configs[m]:
                            memo = memos.setdefault(k, {})
                            result = _member_frame(result, configs[m], self.stages, frames, k, memo)
                        own.append(result)
                    runs[m] = _tracker_run(own, labels, slam, elapsed)
                continue
            for group in reversed(list(groups.values())):
                pending.append((slam.fork(configs[group[0]]), i, group, list(results), elapsed))
        return runs


def _member_frame(
    result: FrameResult, config: SlamConfig, stages: list, frames: FrameSource, i: int, memo: dict
) -> FrameResult:
    """A shared frame's result as ``config`` would report it: the same kept keypoints (so the
    same tracking), but its own reason per rejected keypoint and box class per keypoint."""
    stage, detections = stages[i], frames.detections(i)
    previous = stages[i - 1].features if i else None
    seed_frame(config.tracking, i)
    codes = classify(
        config.strategy, stage.features, previous, detections, config.rejection, stage.flow, memo
    )
    dilation = config.rejection.box_dilation_px
    key = ("box classes", dilation)  # the same for every setting of the frame but the dilation
    if key not in memo:
        memo[key] = box_classes(stage.features.keypoints_px, list(detections), dilation)
    classes = memo[key]
    return replace(result, diagnostics=replace(result.diagnostics, rejection=codes, keypoint_classes=classes))


def _tracker_run(results: list, labels: list, slam: Slam, total_s: float) -> TrackerRun:
    stage_ms = {s: np.array([r.diagnostics.stage_ms[s] for r in results]) for s in STAGES}
    keyframes = slam.map.keyframes
    return TrackerRun(
        timestamps_s=np.array([r.timestamp_s for r in results]),
        states=tuple(r.state for r in results),
        poses=tuple(r.world_from_camera for r in results),
        track_ms=stage_ms["tracking_total"],
        keyframes=len(keyframes),
        total_s=total_s,
        results=results,
        labels=labels or None,
        stage_ms=stage_ms,
        keyframe_poses={kf.frame_index: kf.world_from_camera.copy() for kf in keyframes},
    )


def build(tracker, config: SlamConfig, progress: bool, stages: list | None = None) -> BuiltinTracker:
    """The registry's entry point (``registry.build``): ``stages`` are the cached features
    and flow of every frame, or None to compute them while tracking."""
    return BuiltinTracker(config, stages)


def check(tracker, camera_sequence: Sequence | None = None) -> None:
    """Nothing to check before a run: its settings are checked with the strategy's."""
