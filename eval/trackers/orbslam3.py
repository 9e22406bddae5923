"""The real ORB-SLAM3 (``pyorbslam3``, GPL-3, an optional extra) behind the tracker interface.

It runs in a child process (``orbslam3_worker``) on the sequence folder, or on a
masked copy when ``mask`` rejection is on, with settings written from the
sequence's camera and a DBoW2 vocabulary built by ``depotbench vocab``.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import sys
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from depotbench.core.errors import InputError
from depotbench.core.parameters import parameter_text
from depotbench.eval.trackers.base import TrackerError, TrackerRun
from depotbench.eval.trackers.external import run_child
from depotbench.eval.trackers.frames import FrameSource
from depotbench.eval.trackers.reaper import Scratch
from depotbench.eval.trackers.vocabulary import vocabulary_problem
from depotbench.sim.camera import OrbSlamSettings, orbslam_yaml
from depotbench.slam.types import TrackingState

STATES = {
    "OK": TrackingState.OK,
    "OK_KLT": TrackingState.OK,
    "RECENTLY_LOST": TrackingState.LOST,
    "LOST": TrackingState.LOST,
}
"""ORB-SLAM3's tracking states; the others (not ready, no images yet, not initialised)
mean not initialised. RECENTLY_LOST poses are predictions, not tracking: lost."""
INSTALL_HINT = "pip install 'depotbench[orbslam3]' (the pyorbslam3 wheel, GPL-3)"


def available() -> bool:
    return importlib.util.find_spec("pyorbslam3") is not None


def _data_lines(path: Path) -> int | None:
    """Poses in a TUM file ORB-SLAM3 wrote (its keyframe trajectory), None if it wrote none."""
    if not path.is_file():
        return None
    return sum(1 for line in path.read_text().splitlines() if line.strip() and not line.startswith("#"))


PARAMETERS: dict[str, tuple[str, type, float, float]] = {
    "ORBextractor.nFeatures": ("n_features", int, 50, 20000),
    "ORBextractor.scaleFactor": ("scale_factor", float, 1.01, 2.0),
    "ORBextractor.nLevels": ("n_levels", int, 1, 16),
    "ORBextractor.iniThFAST": ("ini_th_fast", int, 1, 255),
    "ORBextractor.minThFAST": ("min_th_fast", int, 1, 255),
    "ThDepth": ("close_depth_threshold", float, 1.0, 1000.0),
}
"""ORB-SLAM3's settings a sweep may set, by their names in its settings file: the field
of ``OrbSlamSettings`` each fills, its type and its range (ThDepth is in units of the
baseline: 40 x 0.08 m in TUM's files)."""


PACE = "pace"
"""The runner's own parameter (not a setting of ORB-SLAM3): how frames are fed. Each frame
takes at least ``pace`` x the gap to the next frame's timestamp, the rest slept out, as
ORB-SLAM3's ``Examples/RGB-D/rgbd_tum.cc`` paces a TUM sequence (pace 1: the camera's
rate). Unset or 0: back to back, the fastest. The pace changes results: ORB-SLAM3 maps in a
thread of its own, and one that falls behind lets more keyframes through (walking_static on
2 cores, median keyframes per 200 frames: 102 back to back, 81 at pace 1, 65 with the
mapper idle)."""
PACE_RANGE = (0.0, 10.0)


def known_parameters() -> tuple[str, ...]:
    return (*PARAMETERS, PACE)


def pace_of(parameters: tuple[tuple[str, str], ...]) -> float:
    """The run's pace (0 when not given), checked."""
    text = dict(parameters).get(PACE)
    if text is None:
        return 0.0
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"orbslam3: {PACE} = {text!r} is not a number") from None
    low, high = PACE_RANGE
    if not low <= value <= high:  # also refuses nan
        raise InputError(f"orbslam3: {PACE} = {text} is out of range [{low:g}, {high:g}]")
    return value


def default_parameters() -> dict[str, str]:
    """The parameters' values in the settings the bench writes (``OrbSlamSettings``)."""
    defaults = OrbSlamSettings()
    return {name: parameter_text(getattr(defaults, field)) for name, (field, _, _, _) in PARAMETERS.items()}


def canonical_parameters(values: Mapping[str, str]) -> dict[str, str]:
    """Each number in one spelling (``parameter_text``): its parameters are numbers, so 1,
    1.0 and 1e0 are one run with one key. Text that is no number is left as given, for
    ``orbslam_settings`` and ``pace_of`` to refuse by name."""
    out = {}
    for name, text in values.items():
        try:
            out[name] = parameter_text(float(text))
        except ValueError:
            out[name] = text
    return out


def orbslam_settings(sequence_fps: float, parameters: tuple[tuple[str, str], ...]) -> OrbSlamSettings:
    """The settings file's non-camera fields with the run's parameters, each checked."""
    values: dict[str, int | float] = {}
    for name, text in parameters:
        if name == PACE:
            continue  # the runner's, not the settings file's
        if name not in PARAMETERS:
            raise InputError(f"orbslam3: unknown parameter {name!r}; known: {', '.join(known_parameters())}")
        field, kind, low, high = PARAMETERS[name]
        try:
            value = kind(text)
        except ValueError:
            raise InputError(
                f"orbslam3: {name} = {text!r} is not {'an integer' if kind is int else 'a number'}"
            ) from None
        if not low <= value <= high:
            raise InputError(f"orbslam3: {name} = {text} is out of range [{low:g}, {high:g}]")
        values[field] = value
    settings = OrbSlamSettings(fps=sequence_fps, **values)
    if settings.min_th_fast > settings.ini_th_fast:
        raise InputError("orbslam3: ORBextractor.minThFAST must not exceed ORBextractor.iniThFAST")
    return settings


class Orbslam3Tracker:
    name = "orbslam3"

    def __init__(
        self, vocabulary: Path, timeout_s: float = 3600.0, parameters: tuple[tuple[str, str], ...] = ()
    ) -> None:
        orbslam_settings(30.0, parameters)  # refused here, before any run
        self.pace = pace_of(parameters)
        self.vocabulary = vocabulary
        self.timeout_s = timeout_s
        self.parameters = parameters

    def run(self, frames: FrameSource, progress: bool) -> TrackerRun:
        if not available():
            raise TrackerError(f"ORB-SLAM3 is not installed: {INSTALL_HINT}")
        problem = vocabulary_problem(self.vocabulary)
        if problem is not None:
            raise TrackerError(f"{self.vocabulary}: {problem}")
        sequence = frames.sequence
        try:  # a folder and process group that end with depotbench, SIGKILL included
            guard = Scratch("depotbench-orbslam3-")
        except OSError as exc:
            raise TrackerError(
                f"orbslam3: cannot make a scratch folder in {exc.filename}: {exc.strerror}"
            ) from None
        with guard:
            scratch = guard.path
            settings = scratch / "settings.yaml"
            settings.write_text(
                orbslam_yaml(sequence.intrinsics, orbslam_settings(sequence.fps, self.parameters)),
                encoding="utf-8",
            )
            request = {
                "vocabulary": str(self.vocabulary.resolve()),
                "settings": str(settings),
                "sequence": str(frames.folder(scratch).resolve()),
                # A real folder's camera as the run was given it (one of another size than
                # TUM's, with no camera.yaml, opens in the worker only with it); a generated
                # sequence has its own, and refuses another.
                "intrinsics": None if sequence.is_generated else dataclasses.asdict(sequence.intrinsics),
                "out": str(scratch),
                "pace": self.pace,
            }
            (scratch / "request.json").write_text(json.dumps(request), encoding="utf-8")
            child = run_child(
                [
                    sys.executable,
                    "-m",
                    "depotbench.eval.trackers.orbslam3_worker",
                    str(scratch / "request.json"),
                ],
                what="orbslam3",
                cwd=scratch,
                timeout_s=self.timeout_s,
                frames=len(sequence),
                progress=progress,
                group=guard.group,
            )
            records = [json.loads(line) for line in (scratch / "frames.jsonl").read_text().splitlines()]
            keyframes = _data_lines(scratch / "keyframes.txt")
            drawn = scratch / "map_points.npy"
            points = np.load(drawn, allow_pickle=False).astype(np.float64) if drawn.is_file() else None
        if len(records) != len(sequence):
            raise TrackerError(f"orbslam3: reported {len(records)} frames of {len(sequence)}")
        return TrackerRun(
            timestamps_s=np.array([r["timestamp_s"] for r in records]),
            states=tuple(STATES.get(r["state"], TrackingState.NOT_INITIALIZED) for r in records),
            poses=tuple(None if r["pose"] is None else np.array(r["pose"]) for r in records),
            track_ms=np.array([r["track_ms"] for r in records]),
            keyframes=keyframes,
            total_s=child.wall_s,
            peak_memory_mb=child.peak_memory_mb,
            cpu_s=child.cpu_s,
            log=child.log,
            map_points=points,
            map_colours=None if points is None else np.full((len(points), 3), 160, np.uint8),
        )


def build(tracker, config, progress: bool, stages: list | None = None) -> Orbslam3Tracker:
    """The registry's entry point: refused before a vocabulary is built for nothing when the
    wheel is not installed."""
    from depotbench.eval.trackers.vocabulary import default_vocabulary

    if not available():
        raise InputError(f"--slam orbslam3: ORB-SLAM3 is not installed: {INSTALL_HINT}")
    vocabulary = tracker.vocabulary or default_vocabulary(progress)
    return Orbslam3Tracker(vocabulary, tracker.timeout_s, tracker.parameters)


def check(tracker, camera_sequence=None) -> None:
    """Its settings in range before any run (at 30 frames/s: the rate changes no range)."""
    orbslam_settings(30.0, tracker.parameters)
    pace_of(tracker.parameters)
