"""A Rerun recording of a run (extra [viz]): scrub through frames, keypoints and trajectories.

Per frame: the RGB image with its keypoints coloured by decision, the same keypoints
coloured by true label, the camera's estimated and true positions so far, and the
position error. Open the file with ``rerun FILE.rrd``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from eval.html_report import (
    DECISION_COLOURS,
    MOVING_COLOUR,
    STATIC_COLOUR,
    RunView,
    aligned_trajectories,
)
from sim.errors import InputError


def write_recording(view: RunView, path: Path) -> None:
    try:
        import rerun as rr
    except ImportError:
        raise InputError("--rerun needs the Rerun SDK: pip install 'depotbench[viz]'") from None
    staged = path.with_name(f".{path.name}.partial")  # renamed into place once complete
    try:
        recording = rr.RecordingStream("depotbench", recording_id=str(path.stem))
        recording.save(str(staged))
        pair = aligned_trajectories(view)
        if pair is not None:
            ref, est = pair
            truth = rr.LineStrips3D([ref.positions_m], colors=[(90, 90, 90)])
            recording.log("world/groundtruth", truth, static=True)
            errors = np.linalg.norm(est.positions_m - ref.positions_m, axis=1)
            by_time = {round(float(t), 6): i for i, t in enumerate(est.timestamps_s)}
        d = view.diagnostics
        starts = np.r_[0, np.cumsum(d["keypoint_counts"])] if d is not None else None
        names = [str(n) for n in d["rejection_names"]] if d is not None else []
        for i, (t, state) in enumerate(zip(view.timestamps_s, view.states, strict=True)):
            recording.set_time("frame", sequence=i)
            recording.log("state", rr.TextLog(state))
            if view.sequence is not None and i < len(view.sequence):
                recording.log("camera/image", rr.Image(view.sequence.rgb(i)))
            if d is not None and starts is not None:
                points = d["keypoints_px"][starts[i] : starts[i + 1]]
                codes = d["rejection"][starts[i] : starts[i + 1]]
                colours = [DECISION_COLOURS.get(names[c], (255, 255, 255)) for c in codes]
                recording.log("camera/image/decision", rr.Points2D(points, colors=colours, radii=2.0))
                if "moving" in d:
                    moving = d["moving"][starts[i] : starts[i + 1]]
                    truth = [MOVING_COLOUR if m else STATIC_COLOUR for m in moving]
                    recording.log("camera/image/truth", rr.Points2D(points, colors=truth, radii=2.0))
            if pair is not None:
                j = by_time.get(round(float(t), 6))
                if j is not None:
                    so_far = rr.LineStrips3D([est.positions_m[: j + 1]], colors=[(220, 50, 50)])
                    recording.log("world/estimate", so_far)
                    recording.log("error_m", rr.Scalars(float(errors[j])))
        recording.flush()
        recording.disconnect()
    except BaseException:
        staged.unlink(missing_ok=True)
        raise
    os.replace(staged, path)
