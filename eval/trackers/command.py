"""Any SLAM program as a tracker, through a command template.

The template is split like a shell command line (``shlex``) but run without a
shell; each word may hold placeholders:

``{sequence}``      the sequence folder (a masked copy under ``mask``)
``{associations}``  its associations.txt (written when the folder has none)
``{settings}``      ORB-SLAM2/3 RGB-D settings for its camera
``{vocabulary}``    the ORB vocabulary (``depotbench vocab``)
``{trajectory}``    where the program must write its TUM trajectory; without this
                    placeholder it is read from ``CameraTrajectory.txt`` in the
                    program's working folder (ORB-SLAM2's ``rgbd_tum`` writes there)

e.g. ``rgbd_tum {vocabulary} {settings} {sequence} {associations}``. Frames with
a pose in the trajectory count as tracked; the program reports no per-frame time.
"""

from __future__ import annotations

import shlex
import string
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from eval.frames import FrameSource
from eval.trackers.base import TrackerError, TrackerRun
from eval.trackers.external import poses_by_frame, run_child, write_settings
from eval.trajectory import read_tum
from sim.errors import InputError
from sim.sequence import timestamp_name
from slam.types import TrackingState

PLACEHOLDERS = ("sequence", "associations", "settings", "vocabulary", "trajectory")
DEFAULT_TRAJECTORY = "CameraTrajectory.txt"


def parse_template(template: str) -> list[str]:
    """The template's words, refused when empty, unbalanced or naming unknown placeholders."""
    try:
        words = shlex.split(template)
    except ValueError as exc:
        raise InputError(f"--command {template!r}: {exc}") from None
    if not words:
        raise InputError("--command: the template is empty")
    for word in words:
        try:
            names = {name for _, name, _, _ in string.Formatter().parse(word) if name is not None}
        except ValueError as exc:
            raise InputError(f"--command: {word!r}: {exc}") from None
        unknown = names - set(PLACEHOLDERS)
        if unknown:
            raise InputError(
                f"--command: unknown placeholder {{{sorted(unknown)[0]}}}; "
                f"known: {', '.join('{' + p + '}' for p in PLACEHOLDERS)}"
            )
    return words


def uses(words: list[str], placeholder: str) -> bool:
    return any("{" + placeholder + "}" in word for word in words)


class CommandTracker:
    name = "cmd"

    def __init__(
        self, template: str, vocabulary: Callable[[], Path] | None = None, timeout_s: float = 3600.0
    ) -> None:
        self.words = parse_template(template)
        self.vocabulary = vocabulary
        self.timeout_s = timeout_s

    def run(self, frames: FrameSource, progress: bool) -> TrackerRun:
        sequence = frames.sequence
        with tempfile.TemporaryDirectory(prefix="depotbench-cmd-") as scratch_dir:
            scratch = Path(scratch_dir)
            folder = frames.folder(scratch).resolve()
            associations = folder / "associations.txt"
            if not associations.is_file():
                associations = scratch / "associations.txt"
                associations.write_text(
                    "".join(
                        f"{timestamp_name(f.timestamp_s)} {f.rgb_path.relative_to(sequence.root)} "
                        f"{timestamp_name(f.depth_timestamp_s)} {f.depth_path.relative_to(sequence.root)}\n"
                        for f in sequence.frames
                    ),
                    encoding="utf-8",
                )
            trajectory = scratch / (
                "trajectory.txt" if uses(self.words, "trajectory") else DEFAULT_TRAJECTORY
            )
            values = {
                "sequence": str(folder),
                "associations": str(associations),
                "settings": str(write_settings(sequence, scratch / "settings.yaml")),
                "trajectory": str(trajectory),
                "vocabulary": "",
            }
            if uses(self.words, "vocabulary"):
                if self.vocabulary is None:
                    raise TrackerError("--command uses {vocabulary}, but no vocabulary was given")
                values["vocabulary"] = str(self.vocabulary().resolve())
            argv = [word.format(**values) for word in self.words]
            total_s = run_child(
                argv,
                what=f"cmd {Path(argv[0]).name}",
                cwd=scratch,
                timeout_s=self.timeout_s,
                frames=len(sequence),
                progress=progress,
            )
            if not trajectory.is_file():
                raise TrackerError(f"cmd {argv[0]}: wrote no trajectory ({trajectory.name})")
            estimate = read_tum(trajectory)
        poses = poses_by_frame(sequence, estimate.timestamps_s, estimate.poses)
        first = next((i for i, pose in enumerate(poses) if pose is not None), len(poses))
        states = tuple(
            TrackingState.OK
            if pose is not None
            else (TrackingState.NOT_INITIALIZED if i < first else TrackingState.LOST)
            for i, pose in enumerate(poses)
        )
        return TrackerRun(
            timestamps_s=sequence.timestamps_s,
            states=states,
            poses=tuple(poses),
            track_ms=np.full(len(sequence), np.nan),
            keyframes=None,
            total_s=total_s,
        )
