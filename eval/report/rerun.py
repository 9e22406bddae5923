"""A Rerun recording of a run (extra [viz]): scrub through frames, keypoints and trajectories.

Per frame: the RGB image with its keypoints coloured by decision, the same keypoints
coloured by true label, the camera's estimated and true positions so far, and the
position error. Open the file with ``rerun FILE.rrd``.

Rerun writes into a pipe and this module copies the pipe into the file: on a full disk
Rerun's own file writer logs ERROR lines and then raises "File-writer thread shut down
prematurely" or hangs in ``flush`` (3 times in 5 tries); here a failed write is an
``OSError`` of ours, named in one line, and the partial file is removed.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from depotbench.core.errors import InputError
from depotbench.eval.report.html import (
    DECISION_COLOURS,
    MOVING_COLOUR,
    STATIC_COLOUR,
    RunView,
    aligned_trajectories,
)
from depotbench.eval.report.maps import GHOST, GHOST_RGB

PIPE_CHUNK = 1 << 16


def _log(recording, view: RunView) -> None:
    """Everything of the run, frame by frame."""
    import rerun as rr

    pair = aligned_trajectories(view)
    if pair is not None:
        ref, est = pair
        truth = rr.LineStrips3D([ref.positions_m], colors=[(90, 90, 90)])
        recording.log("world/groundtruth", truth, static=True)
        errors = np.linalg.norm(est.positions_m - ref.positions_m, axis=1)
        by_time = {round(float(t), 6): i for i, t in enumerate(est.timestamps_s)}
    dense = view.placed  # placed once, with the page (html.load_run)
    if dense is not None:
        colours = np.rint(dense.colours * 255).astype(np.uint8)
        colours[dense.kinds == GHOST] = np.rint(np.array(GHOST_RGB) * 255).astype(np.uint8)
        recording.log("world/map", rr.Points3D(dense.points_m, colors=colours, radii=0.01), static=True)
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


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


class _PipeToFile(threading.Thread):
    """Copies a pipe into a file. After a failed write it keeps draining the pipe, so that
    the writer at the other end never blocks; the failure is kept for the caller."""

    def __init__(self, source: int, path: Path) -> None:
        super().__init__(name="rrd-writer", daemon=True)
        self.source = source
        self.path = path
        self.failure: OSError | None = None

    def run(self) -> None:
        target = None
        try:
            target = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except OSError as exc:
            self.failure = exc
        with os.fdopen(self.source, "rb", buffering=0) as source:
            while chunk := source.read(PIPE_CHUNK):
                if target is None or self.failure is not None:
                    continue
                try:
                    _write_all(target, chunk)
                except OSError as exc:
                    self.failure = exc
        if target is not None:
            os.close(target)


def _record(view: RunView, staged: Path, name: str) -> None:
    """The recording ``name`` of ``view`` written whole to ``staged``; an OSError if not."""
    import rerun as rr

    read_end, write_end = os.pipe()
    copier = _PipeToFile(read_end, staged)
    copier.start()
    try:
        recording = rr.RecordingStream("depotbench", recording_id=name)
        try:
            recording.save(f"/dev/fd/{write_end}")  # its own descriptor on our pipe
            _log(recording, view)
            recording.flush()
        finally:
            recording.disconnect()  # closes Rerun's descriptor on the pipe
    finally:
        os.close(write_end)  # the last writer: the copier reads to the end and stops
        copier.join()
    if copier.failure is not None:
        raise OSError(copier.failure.errno, copier.failure.strerror)


@contextlib.contextmanager
def staged_recording(view: RunView, path: Path) -> Iterator[None]:
    """Write the recording beside ``path`` (hidden, ``.NAME.partial``), run the block, then
    rename it into place. A failure, in the writing or in the block, removes it."""
    try:
        import rerun  # noqa: F401
    except ImportError:
        raise InputError("--rerun needs the Rerun SDK: pip install 'depotbench[viz]'") from None
    staged = path.with_name(f".{path.name}.partial")
    try:
        try:
            _record(view, staged, path.stem)
        except OSError as exc:
            raise InputError(f"{path}: cannot write the recording ({exc.strerror or exc})") from None
        yield
        os.replace(staged, path)
    finally:
        staged.unlink(missing_ok=True)


def write_recording(view: RunView, path: Path) -> None:
    """The recording of ``view`` at ``path``, written whole or not at all."""
    with staged_recording(view, path):
        pass
