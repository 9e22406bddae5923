"""The real ORB-SLAM3 (``pyorbslam3``, GPL-3, an optional extra) behind the tracker interface.

It runs in a child process (``orbslam3_worker``) on the sequence folder, or on a
masked copy when ``mask`` rejection is on, with settings written from the
sequence's camera and a DBoW2 vocabulary built by ``depotbench vocab``.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

from eval.frames import FrameSource
from eval.trackers.base import TrackerError, TrackerRun
from eval.trackers.external import run_child, write_settings
from eval.trackers.reaper import Scratch
from slam.types import TrackingState

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


class Orbslam3Tracker:
    name = "orbslam3"

    def __init__(self, vocabulary: Path, timeout_s: float = 3600.0) -> None:
        self.vocabulary = vocabulary
        self.timeout_s = timeout_s

    def run(self, frames: FrameSource, progress: bool) -> TrackerRun:
        if not available():
            raise TrackerError(f"ORB-SLAM3 is not installed: {INSTALL_HINT}")
        if not self.vocabulary.is_file():
            raise TrackerError(f"{self.vocabulary}: no such vocabulary (build one with `depotbench vocab`)")
        sequence = frames.sequence
        try:  # a folder and process group that end with depotbench, SIGKILL included
            guard = Scratch("depotbench-orbslam3-")
        except OSError as exc:
            raise TrackerError(
                f"orbslam3: cannot make a scratch folder in {exc.filename}: {exc.strerror}"
            ) from None
        with guard:
            scratch = guard.path
            request = {
                "vocabulary": str(self.vocabulary.resolve()),
                "settings": str(write_settings(sequence, scratch / "settings.yaml")),
                "sequence": str(frames.folder(scratch).resolve()),
                "out": str(scratch),
            }
            (scratch / "request.json").write_text(json.dumps(request), encoding="utf-8")
            total_s = run_child(
                [sys.executable, "-m", "eval.trackers.orbslam3_worker", str(scratch / "request.json")],
                what="orbslam3",
                cwd=scratch,
                timeout_s=self.timeout_s,
                frames=len(sequence),
                progress=progress,
                group=guard.group,
            )
            records = [json.loads(line) for line in (scratch / "frames.jsonl").read_text().splitlines()]
            keyframes = _data_lines(scratch / "keyframes.txt")
        if len(records) != len(sequence):
            raise TrackerError(f"orbslam3: reported {len(records)} frames of {len(sequence)}")
        return TrackerRun(
            timestamps_s=np.array([r["timestamp_s"] for r in records]),
            states=tuple(STATES.get(r["state"], TrackingState.NOT_INITIALIZED) for r in records),
            poses=tuple(None if r["pose"] is None else np.array(r["pose"]) for r in records),
            track_ms=np.array([r["track_ms"] for r in records]),
            keyframes=keyframes,
            total_s=total_s,
        )
