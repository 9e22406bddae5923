#!/usr/bin/env python3
"""The bench's own tracker as an external program (docs/external-trackers.md).

It reads what the bench hands any program -- the sequence folder, the detections file and
the parameters JSON -- runs the built-in pipeline on them, and writes the TUM trajectory
and the keypoint decisions. Its results equal the built-in run's bit for bit
(tests/test_example_trackers.py), so it proves the protocol loses nothing: boxes,
parameters, poses and per-keypoint decisions all cross it exactly.

    trackers:
      - name: builtin_external
        command: ./builtin_tracker.py --sequence {sequence} --detections {detections}
          --parameters {parameters} --trajectory {trajectory} --keypoints {keypoints}
        parameters: {strategy: box_epipolar_flow, epsilon_px: 1.0}

(in a spec beside this file: a program's path is relative to the spec; it runs on the
``python3`` first in ``PATH``, depotbench's own with its virtual environment active).
The parameters are ``strategy`` (one of ``depotbench.slam.rejection.STRATEGIES``; the bench's
``mask`` is its own strategy for any program) and any threshold by the name
``depotbench run --set NAME=VALUE`` takes.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from depotbench.core.errors import InputError
from depotbench.eval.metrics.trajectory import Trajectory
from depotbench.eval.run.harness import slam_config
from depotbench.eval.trackers.base import TrackerRun
from depotbench.eval.trackers.builtin import BuiltinTracker, camera_of
from depotbench.eval.trackers.frames import FrameSource
from depotbench.eval.trackers.protocol import read_detections, write_keypoints
from depotbench.sim.sequence import Sequence, timestamp_name
from depotbench.slam.config import ConfigError, Setting, SlamConfig, check_pyramid, parse_setting
from depotbench.slam.rejection import STRATEGIES
from depotbench.slam.types import REJECTION_CODES, Rejection

KEPT = REJECTION_CODES[Rejection.KEPT]
REASONS = {code: reason.value for reason, code in REJECTION_CODES.items()}
"""The word written for each rejection code (``dynamic_box``, ``epipolar``, ...)."""


class ProgressFrames(FrameSource):
    """The bench's FrameSource, telling the bench on stderr how many frames are done.

    The tracker reads each frame's images first, so when it asks for frame ``i`` the
    frames before it are done. Nothing else differs: the tracker sees the same frames.
    """

    def images(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        print(index, file=sys.stderr, flush=True)
        return super().images(index)


def setting_of(name: str, value: object) -> Setting:
    """A JSON value as the setting it names: numbers and booleans as they are (the bench checks
    them against their fields), text parsed as ``--set`` parses it."""
    if isinstance(value, str):
        try:
            return parse_setting(name, value)
        except ConfigError as exc:
            raise InputError(f"parameter {name}: {exc}") from None
    if isinstance(value, bool | int | float):
        return value
    raise InputError(f"parameter {name}: {value!r} is not a number, a boolean or a string")


def read_config(path: Path, sequence: Sequence) -> SlamConfig:
    """The configuration the bench builds for ``--strategy S --set NAME=VALUE ...``."""
    try:
        parameters = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the parameters: {exc}") from None
    if not isinstance(parameters, dict) or not isinstance(parameters.get("strategy"), str):
        raise InputError(f"{path}: the parameters must be a JSON object holding a 'strategy'")
    strategy = parameters.pop("strategy")
    if strategy not in STRATEGIES:  # the bench's 'mask' blanks {sequence} before any program sees it
        raise InputError(f"{path}: strategy {strategy!r} is none of {', '.join(STRATEGIES)}")
    settings = {name: setting_of(name, value) for name, value in parameters.items()}
    config = slam_config(strategy, settings)
    camera = camera_of(sequence)
    try:  # as the bench's prepare() does, so a bad pyramid is one line, not a traceback
        check_pyramid(config.tracking, camera.width, camera.height)
    except ConfigError as exc:
        raise InputError(f"{path}: {exc}") from None
    return config


def write_trajectory(path: Path, trajectory: Trajectory | None) -> None:
    """TUM lines with every value in ``repr``, so positions and quaternions read back bit
    for bit (the bench's own ``write_tum`` keeps 9 decimals). Header only when no frame
    was tracked."""
    lines = ["# timestamp tx ty tz qx qy qz qw\n"]
    if trajectory is not None:
        for t, p, q in zip(
            trajectory.timestamps_s, trajectory.positions_m, trajectory.quats_xyzw, strict=True
        ):
            values = " ".join(repr(float(v)) for v in (*p, *q))
            lines.append(f"{timestamp_name(t)} {values}\n")
    path.write_text("".join(lines), encoding="utf-8")


def write_decisions(path: Path, run: TrackerRun) -> None:
    """Every frame's keypoints, kept or not, with the rejection's name as the reason."""
    results = run.results or []
    codes = [r.diagnostics.rejection for r in results]
    write_keypoints(
        path,
        [r.timestamp_s for r in results],
        [r.diagnostics.keypoints_px for r in results],
        [c == KEPT for c in codes],
        [["" if c == KEPT else REASONS[int(c)] for c in frame] for frame in codes],
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequence", type=Path, required=True, help="the sequence folder")
    parser.add_argument("--detections", type=Path, required=True, help="the bench's detections file")
    parser.add_argument("--parameters", type=Path, required=True, help="the run's parameters (JSON)")
    parser.add_argument("--trajectory", type=Path, required=True, help="where to write the TUM trajectory")
    parser.add_argument("--keypoints", type=Path, required=True, help="where to write the keypoint decisions")
    args = parser.parse_args(argv)
    try:
        sequence = Sequence.open(args.sequence)
        boxes = read_detections(args.detections, sequence)
        config = read_config(args.parameters, sequence)
    except InputError as exc:
        print(f"builtin_tracker: {exc}", file=sys.stderr)
        return 2
    run = BuiltinTracker(config).run(ProgressFrames(sequence, boxes), progress=False)
    write_trajectory(args.trajectory, run.trajectory())
    write_decisions(args.keypoints, run)
    print(len(sequence), file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
