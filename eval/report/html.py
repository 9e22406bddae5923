"""``depotbench report``: one self-contained HTML page for a run or a sweep.

The page needs no network and no script: plots are PNGs drawn by matplotlib and
frames are PNGs drawn by OpenCV, all inlined as data URIs. For a run it shows the
trajectory against ground truth from above, the error over time with the
tracking state, a strip of frames with keypoints coloured by decision and by
true dynamic label, and the scenario's difficulty. For a sweep it adds the best
configuration per family (each mean with its 95 % interval and n, and the runs that
held), ATE and rejection precision/recall against each swept threshold (bands, and
each family's none run), the accuracy/time Pareto plot, each sequence's knobs, seed and
difficulty, and a section per family (at most ``MAX_FAMILY_SECTIONS``, the others
named): every run of every configuration, and the run detail of its best
configuration (tracked again from the cache; runs are deterministic, so it is the
stored run) and of its none run.

Inputs are read within bounds (regular files, size limits, an .npz's declared sizes
before any array is allocated) and checked, so a hostile or damaged file is one line
naming it. A sequence that is gone, damaged or changed since the sweep leaves out only
what needs its frames; the page lists what it left out, and ``depotbench report``
warns about it in one line.
"""

from __future__ import annotations

import io
import json
import logging
import math
import os
import zipfile
import zlib
from array import array
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from depotbench.core.errors import FileError, InputError
from depotbench.core.files import MIB, open_regular, read_text
from depotbench.core.path_text import text_path
from depotbench.eval.metrics.alignment import Alignment, align
from depotbench.eval.metrics.figures import Baseline, ScoredRun, is_baseline
from depotbench.eval.metrics.record import RunRecord
from depotbench.eval.metrics.statistics import SuccessRule
from depotbench.eval.metrics.trajectory import Trajectory, associate, read_tum
from depotbench.eval.report.page import Image, Mean, Table, render
from depotbench.eval.sweep.family import family_name, family_order, sorted_families
from depotbench.eval.sweep.summary import (
    LEGEND_FONT,
    configuration_label,
    pareto_figure,
    pyplot,
    settings_text,
    strip_figures,
    threshold_figures,
    with_rho,
)
from depotbench.sim.sequence import Sequence
from depotbench.slam.types import Rejection, TrackingState
from pydantic import (
    BaseModel,
    ConfigDict,
    StrictFloat,
    StrictInt,
    StrictStr,
    ValidationError,
    field_validator,
)

LOG = logging.getLogger(__name__)

DECISION_COLOURS: dict[str, tuple[int, int, int]] = {
    Rejection.KEPT.value: (40, 200, 60),
    Rejection.DYNAMIC_BOX.value: (230, 40, 40),
    Rejection.EPIPOLAR.value: (255, 160, 0),
    Rejection.FLOW_OUTLIER.value: (200, 60, 220),
    Rejection.MOVING_FLOW.value: (0, 170, 255),
    "rejected": (230, 40, 40),  # an external program's rejection (harness.PROGRAM_REJECTED)
}
"""RGB per rejection decision (the legend of the frame strip)."""
MOVING_COLOUR = (255, 40, 40)
STATIC_COLOUR = (60, 120, 255)
STATE_COLOURS = {
    TrackingState.OK.value: None,
    TrackingState.RELOCALIZED.value: "#fde68a",
    TrackingState.LOST.value: "#fca5a5",
    TrackingState.NOT_INITIALIZED.value: "#e5e7eb",
}
STRIP_FRAMES = 5
STRIP_WIDTH_PX = 320


@dataclass(frozen=True)
class RunView:
    """Everything the page shows of one run."""

    title: str
    metrics: dict[str, Any]
    timestamps_s: np.ndarray
    states: tuple[str, ...]
    estimate: Trajectory | None
    sequence: Sequence | None
    diagnostics: dict[str, np.ndarray] | None
    sequence_problem: str | None = None
    """Why ``sequence`` is None (not found, damaged): shown where its frames would be."""
    folder: Path | None = None
    """The run folder, where the run was read from one."""
    placed: Any = None
    """Its dense map placed in the ground-truth frame and classified (``maps.PlacedMap``): a
    run folder's map.ply, or the map of a run tracked again for a sweep's page."""


@dataclass
class Notes:
    """What the page leaves out, and why. An omission is an outcome, never silent: each one
    is listed at the top of the page and in the one warning line on stderr."""

    items: list[str] = field(default_factory=list)

    def add(self, text: str) -> None:
        if text not in self.items:
            self.items.append(text)

    def warning(self) -> str | None:
        """One line (a path may hold a newline: it is shown escaped)."""
        if not self.items:
            return None
        return "left out of the page: " + "; ".join(t.replace("\n", "\\n") for t in self.items)


@dataclass(frozen=True)
class Rendered:
    """A page, what it leaves out, and the run it shows (for ``--rerun``; None for a sweep)."""

    text: str
    notes: Notes
    run: RunView | None = None


# -- the sequence a run or row names ------------------------------------------------------


def resolve_sequence(recorded: str, base: Path) -> Path | None:
    """The folder a stored sequence path names, or None when there is none.

    Absolute: as is. Relative: against ``base`` (the sweep or run folder, where a writer
    keeps a path that travels with it) first, then the working directory (older sweeps
    stored paths relative to where they ran, ``specs/../seq``). Resolved, so that the
    sequence's fingerprint, which holds its folder, is the one the sweep computed.
    """
    path = text_path(recorded)
    candidates = [path] if path.is_absolute() else [base / path, path]
    return next((c.resolve() for c in candidates if c.is_dir()), None)


def open_sequence(recorded: Any, base: Path) -> tuple[Sequence | None, str | None]:
    """The sequence a run or row names, or None and why: not found, or damaged (a lost frame
    file). The reason is for the page and the warning line, never dropped."""
    if not isinstance(recorded, str) or not recorded:
        return None, "the run names no sequence (metrics.json has no sequence path)"
    root = resolve_sequence(recorded, base)
    if root is None:
        where = "no such folder" if Path(recorded).is_absolute() else f"looked in {base} and in {Path.cwd()}"
        return None, f"sequence {recorded}: not found ({where})"
    try:
        return Sequence.open(root), None
    except FileError as exc:  # SequenceFormatError among them: a file of the sequence is bad
        return None, f"sequence {recorded}: damaged ({exc})"


def _inside(path: Path, root: Path) -> bool:
    path, root = path.resolve(), root.resolve()
    return path == root or root in path.parents


# -- reading a run folder, within bounds -------------------------------------------------
# The bounded readers of core/files.py (regular files only, size-checked before reading):
# a frames.csv linked to /dev/zero would otherwise be read until memory runs out.

MAX_METRICS_BYTES = 1 * MIB
"""metrics.json holds statistics, not per-frame values: about 3 KB whatever the run's length."""
MAX_FRAMES_CSV_BYTES = 8 * MIB
"""frames.csv: at most ~45 bytes a frame (``1234.123456,not_initialized,12.345``), so a
100,000-frame run (depotbench.scenes.schema.MAX_FRAMES) writes about 4.5 MB."""
MAX_DIAGNOSTICS_BYTES = 2048 * MIB
"""The decoded arrays of diagnostics.npz: 13.1 KB a frame at the tracker's default 1,000
keypoints (walking_static), so 1.3 GB for a 100,000-frame run. Checked from the members'
headers before any array is allocated: a 14 MB zip can declare a 3 GiB array."""
MAX_NPZ_MEMBERS = 64
"""diagnostics.npz holds 13 arrays."""
NPZ_KINDS = "biufU"
"""The array kinds diagnostics_arrays writes (booleans, integers, floats, text); never
objects, which would be pickles."""
FRAME_STATES = {s.value: s.value for s in TrackingState}
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError)
"""What a damaged archive raises while read: a bad header or CRC, corrupt deflate data, a
truncated member (numpy's ``EOF: reading array data``)."""


def _limit(limit: int) -> str:
    return f"{limit // MIB} MiB"


def _read_run_file(path: Path, limit: int, what: str) -> str:
    try:
        return read_text(path, limit, what)
    except FileNotFoundError:
        raise FileError(path, None, f"is missing (every run folder has its {path.name})") from None


def read_metrics(path: Path) -> dict[str, Any]:
    """metrics.json: an object whose parts the page reads are of the kind it reads."""
    text = _read_run_file(path, MAX_METRICS_BYTES, "run's metrics.json")
    try:
        metrics = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FileError(path, exc.lineno, f"not valid JSON ({exc.msg})") from None
    if not isinstance(metrics, dict):
        raise FileError(path, None, f"must hold a JSON object, not {type(metrics).__name__}")
    for name in ("tracker", "strategy", "detector"):
        if not isinstance(metrics.get(name), str):
            raise FileError(path, None, f"{name}: missing or not text")
    for name in ("ate_m", "rpe_translation_m", "rejection", "stage_time"):
        if not isinstance(metrics.get(name) or {}, dict):
            raise FileError(path, None, f"{name}: must be an object")
    if not isinstance((metrics.get("stage_time") or {}).get("tracking_total") or {}, dict):
        raise FileError(path, None, "stage_time.tracking_total: must be an object")
    if not isinstance(metrics.get("sequence") or "", str):
        raise FileError(path, None, "sequence: must be a path (text)")
    return metrics


def read_frames(path: Path) -> tuple[np.ndarray, tuple[str, ...]]:
    """frames.csv: per frame its timestamp and tracking state, each line checked."""
    text = _read_run_file(path, MAX_FRAMES_CSV_BYTES, "run's frames.csv")
    lines = io.StringIO(text)
    header = lines.readline().rstrip("\r\n").split(",")
    if "timestamp_s" not in header or "state" not in header:
        raise FileError(path, 1, "the header must name the columns timestamp_s and state")
    at, st = header.index("timestamp_s"), header.index("state")
    stamps: array[float] = array("d")
    states: list[str] = []
    for number, line in enumerate(lines, start=2):
        fields = line.rstrip("\r\n").split(",")
        if fields == [""]:
            continue
        if len(fields) != len(header):
            raise FileError(path, number, f"{len(fields)} fields, the header names {len(header)}")
        try:
            stamp = float(fields[at])
        except ValueError:
            stamp = math.nan
        if not math.isfinite(stamp):
            raise FileError(path, number, f"timestamp_s {fields[at][:40]!r} is not a finite number")
        state = FRAME_STATES.get(fields[st])
        if state is None:
            known = ", ".join(FRAME_STATES)
            raise FileError(path, number, f"state {fields[st][:40]!r} is not a tracking state ({known})")
        stamps.append(stamp)
        states.append(state)
    return np.frombuffer(stamps, dtype=float).copy(), tuple(states)


def _npy_header(stream, path: Path, member: str) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype of one .npy member, read from its header alone."""
    version = np.lib.format.read_magic(stream)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(stream)
    elif version == (2, 0):
        shape, _, dtype = np.lib.format.read_array_header_2_0(stream)
    else:
        raise FileError(path, None, f"member {member}: .npy format {version} is not one numpy.savez writes")
    if dtype.kind not in NPZ_KINDS or dtype.hasobject or any(n < 0 for n in shape):
        raise FileError(path, None, f"member {member}: an array of {dtype} {shape}, not a diagnostics array")
    return shape, dtype


def _npz_members(archive: zipfile.ZipFile, path: Path, limit: int, what: str) -> list[zipfile.ZipInfo]:
    """The members, refused unless each is a plain .npy and together they declare at most
    ``limit`` bytes of arrays."""
    members = archive.infolist()
    if len(members) > MAX_NPZ_MEMBERS:
        raise FileError(
            path, None, f"holds {len(members)} members, more than the {MAX_NPZ_MEMBERS} of a {what}"
        )
    total = 0
    for info in members:
        name = info.filename
        if not name.endswith(".npy") or info.flag_bits & 0x1:
            raise FileError(path, None, f"member {name[:60]!r} is not a plain .npy array")
        if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise FileError(path, None, f"member {name}: compression {info.compress_type} is not numpy's")
        with archive.open(info) as stream:
            shape, dtype = _npy_header(stream, path, name)
        total += math.prod(shape) * dtype.itemsize
        if total > limit or info.file_size > limit:
            raise FileError(
                path,
                None,
                f"declares more than the {_limit(limit)} limit for a {what} "
                f"(member {name}: {dtype} {shape}, {total / MIB:.0f} MiB so far)",
            )
    return members


def read_npz(path: Path, limit: int, what: str) -> dict[str, np.ndarray]:
    """The arrays of an .npz within bounds: a regular file of at most ``limit`` bytes whose
    members' headers together declare at most ``limit`` bytes, all checked before any array
    is allocated (numpy allocates what a header declares, then reads). Belongs in
    sim/files.py beside read_bytes."""
    fd = open_regular(path, limit, what)
    with os.fdopen(fd, "rb") as handle:
        try:
            with zipfile.ZipFile(handle) as archive:
                members = _npz_members(archive, path, limit, what)
                arrays = {}
                for info in members:
                    with archive.open(info) as stream:
                        arrays[info.filename[:-4]] = np.lib.format.read_array(stream, allow_pickle=False)
                return arrays
        except _ZIP_ERRORS as exc:
            raise FileError(path, None, f"cannot be read as a {what} ({exc})") from None


def check_diagnostics(d: dict[str, np.ndarray], path: Path) -> None:
    """Per-keypoint arrays that agree with the per-frame counts, and decision codes that name
    a decision: the frame strip and the recording index with them."""
    for name in ("keypoint_counts", "keypoints_px", "rejection", "rejection_names"):
        if name not in d:
            raise FileError(path, None, f"has no {name} array")
    counts, points, codes = d["keypoint_counts"], d["keypoints_px"], d["rejection"]
    if counts.ndim != 1 or counts.dtype.kind not in "iu" or (len(counts) and counts.min() < 0):
        raise FileError(path, None, "keypoint_counts must be one count (an integer >= 0) per frame")
    if points.ndim != 2 or points.shape[1] != 2 or points.dtype.kind not in "iuf":
        raise FileError(
            path, None, f"keypoints_px must be N x 2 pixel positions, not {points.dtype} {points.shape}"
        )
    if len(counts) and counts.max() > len(points):
        raise FileError(
            path, None, f"keypoint_counts names {counts.max()} keypoints in a frame, more than all"
        )
    total = int(counts.sum())
    for name in ("keypoints_px", "rejection", "moving"):
        if name in d and (d[name].ndim < 1 or len(d[name]) != total):
            raise FileError(
                path, None, f"{name} holds {len(d[name])} keypoints, keypoint_counts add up to {total}"
            )
    names = d["rejection_names"]
    if codes.ndim != 1 or codes.dtype.kind not in "iu" or names.ndim != 1 or names.dtype.kind != "U":
        raise FileError(path, None, "rejection must be integer codes into rejection_names (text)")
    if len(codes) and (codes.min() < 0 or codes.max() >= len(names)):
        raise FileError(path, None, f"rejection holds codes outside 0..{len(names) - 1} (rejection_names)")


def load_run(folder: Path, notes: Notes | None = None) -> RunView:
    """A run folder written by ``depotbench run``; a missing, oversized or damaged file is
    named. A sequence that cannot be found or opened is noted (``notes``), not fatal."""
    notes = notes if notes is not None else Notes()
    metrics = read_metrics(folder / "metrics.json")
    frames_path = folder / "frames.csv"
    timestamps, states = read_frames(frames_path)
    trajectory = folder / "trajectory.txt"
    estimate = read_tum(trajectory) if trajectory.is_file() else None
    diagnostics = None
    diagnostics_path = folder / "diagnostics.npz"
    if os.path.lexists(diagnostics_path):  # a device or a dangling link is refused by name
        diagnostics = read_npz(diagnostics_path, MAX_DIAGNOSTICS_BYTES, "run's diagnostics.npz")
        check_diagnostics(diagnostics, diagnostics_path)
        if len(diagnostics["keypoint_counts"]) != len(states):
            raise FileError(
                frames_path,
                None,
                f"lists {len(states)} frames, {diagnostics_path.name} {len(diagnostics['keypoint_counts'])}",
            )
    sequence, problem = open_sequence(metrics.get("sequence"), folder)
    if problem is not None:
        notes.add(f"{problem}; left out: the frames, the ground truth and the scenario's difficulty")
    placed = _placed_map(folder, metrics, sequence, notes)
    return RunView(
        title=f"{metrics['tracker']} · {metrics['strategy']} · {metrics['detector']}",
        metrics=metrics,
        timestamps_s=timestamps,
        states=states,
        estimate=estimate,
        sequence=sequence,
        diagnostics=diagnostics,
        sequence_problem=problem,
        folder=folder,
        placed=placed,
    )


def view_of(title: str, tracked, sequence: Sequence) -> RunView:
    """A run tracked in this process (``depotbench.eval.run.harness.Tracked``) on ``sequence``."""
    from depotbench.eval.run.harness import run_diagnostics

    run = tracked.run
    placed = None
    dense = getattr(tracked, "map", None)
    if dense is not None and dense.scores is not None and len(dense.points):
        from depotbench.eval.report.maps import placed_points
        from depotbench.eval.run.dense import reference_of

        strategy = str(tracked.metrics.get("strategy", "map"))
        placed = placed_points(dense.points, dense.colours, dense.scores, reference_of(sequence), strategy)
    return RunView(
        title=title,
        metrics=tracked.metrics,
        timestamps_s=np.asarray(run.timestamps_s, float),
        states=tuple(s.value for s in run.states),
        estimate=run.trajectory(),
        sequence=sequence,
        diagnostics=run_diagnostics(run, tracked.decisions),
        placed=placed,
    )


# -- figures -----------------------------------------------------------------


def figure_png(fig) -> bytes:
    from io import BytesIO

    buffer = BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    pyplot().close(fig)
    return buffer.getvalue()


def _reference(sequence: Sequence | None) -> Trajectory | None:
    if sequence is None or sequence.groundtruth is None:
        return None
    gt = sequence.groundtruth
    return Trajectory.from_quaternions(gt.timestamps_s, gt.positions_m, gt.quats_xyzw, "groundtruth")


def aligned_trajectories(view: RunView) -> tuple[Trajectory, Trajectory] | None:
    """Ground truth and the estimate associated with it, SE(3)-aligned as ATE aligns them."""
    reference = _reference(view.sequence)
    if reference is None or view.estimate is None or len(view.estimate) < 3:
        return None
    ref, est = associate(reference, view.estimate)
    aligned, _ = align(est, ref, Alignment.SE3)
    return ref, aligned


def trajectory_figure(view: RunView):
    """Top view: the two axes along which the ground truth moves most."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(4.6, 4.2))
    reference = _reference(view.sequence)
    pair = aligned_trajectories(view)
    if reference is not None:
        extent = np.ptp(reference.positions_m, axis=0)
        a, b = sorted(np.argsort(-extent)[:2])
        ax.plot(
            reference.positions_m[:, a], reference.positions_m[:, b], "-", c="0.3", lw=2, label="ground truth"
        )
        if pair is not None:
            est = pair[1].positions_m
            ax.plot(est[:, a], est[:, b], "-", c="C3", lw=1.2, label="estimate (SE(3)-aligned)")
            ax.plot(est[0, a], est[0, b], "o", c="C3", ms=5)
        names = "xyz"
        ax.set(xlabel=f"{names[a]} (m)", ylabel=f"{names[b]} (m)")
        # Equal scales by widening the data limits, not by shrinking the box: a walk 0.4 m
        # across and 6 m along left an axis 0.2 in wide, its tick labels on top of each other.
        ax.set_aspect("equal", adjustable="datalim")
        ax.xaxis.set_major_locator(plt.MaxNLocator(5))
        ax.yaxis.set_major_locator(plt.MaxNLocator(6))
    elif view.estimate is not None:
        ax.plot(
            view.estimate.positions_m[:, 0], view.estimate.positions_m[:, 1], "-", c="C3", label="estimate"
        )
    ax.set_title("trajectory from above")
    # Under the axes: inside, 'best' still sat on a walk that crosses the whole plot.
    ax.legend(fontsize=LEGEND_FONT, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncols=2, frameon=False)
    fig.tight_layout()
    return fig


def error_figure(view: RunView):
    """Translational error per tracked frame, with the tracking state shaded behind it."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.0, 3.0))
    t0 = float(view.timestamps_s[0]) if len(view.timestamps_s) else 0.0
    times = view.timestamps_s - t0
    step = float(np.median(np.diff(times))) if len(times) > 1 else 1.0
    for time, state in zip(times, view.states, strict=True):
        colour = STATE_COLOURS.get(state)
        if colour:
            ax.axvspan(time - step / 2, time + step / 2, color=colour, lw=0)
    pair = aligned_trajectories(view)
    if pair is not None:
        ref, est = pair
        errors = np.linalg.norm(est.positions_m - ref.positions_m, axis=1)
        ax.plot(est.timestamps_s - t0, errors * 100, ".-", c="C3", ms=3, lw=1)
    occurring = set(view.states)
    for state, colour in STATE_COLOURS.items():
        if colour and state in occurring:
            ax.plot([], [], "s", ms=8, c=colour, label=state.lower())
    ax.set(xlabel="time (s)", ylabel="position error (cm)", title="error over time (SE(3)-aligned)")
    ax.set_xlim(times.min() - step if len(times) else 0, times.max() + step if len(times) else 1)
    if ax.get_legend_handles_labels()[0]:  # outside the axes, where it covers no frame's error
        ax.legend(fontsize=LEGEND_FONT, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.tight_layout()
    return fig


def _strip_frames(view: RunView) -> list[int]:
    """Evenly spread frames, preferring ones with true movers when labels are known."""
    d = view.diagnostics
    n = len(d["keypoint_counts"])
    if n <= STRIP_FRAMES:
        return list(range(n))
    candidates = np.linspace(0, n - 1, STRIP_FRAMES * 3).round().astype(int)
    if "moving" in d:
        starts = np.r_[0, np.cumsum(d["keypoint_counts"])]
        movers = np.array([d["moving"][starts[i] : starts[i + 1]].sum() for i in range(n)])
        with_movers = [int(i) for i in candidates if movers[i] > 0]
        if len(with_movers) >= STRIP_FRAMES:
            picks = np.linspace(0, len(with_movers) - 1, STRIP_FRAMES).round().astype(int)
            return [with_movers[p] for p in picks]
    return list(np.linspace(0, n - 1, STRIP_FRAMES).round().astype(int))


def strip_problem(view: RunView) -> str | None:
    """Why the frame strip cannot be drawn, or None when it can."""
    d, sequence = view.diagnostics, view.sequence
    if d is None:
        return "the tracker kept no per-keypoint diagnostics"
    if sequence is None:
        return view.sequence_problem or "no sequence"
    if len(d["keypoint_counts"]) != len(sequence):
        return f"the run has {len(d['keypoint_counts'])} frames, its sequence {sequence.root} {len(sequence)}"
    return None


def frame_strip(view: RunView) -> bytes | None:
    """Frames with keypoints coloured by decision (top row) and by true label (bottom row), as JPEG."""
    d, sequence = view.diagnostics, view.sequence
    if strip_problem(view) is not None or d is None or sequence is None:
        return None
    starts = np.r_[0, np.cumsum(d["keypoint_counts"])]
    names = [str(n) for n in d["rejection_names"]]
    tiles_decision, tiles_truth = [], []
    for i in _strip_frames(view):
        rgb = sequence.rgb(i)
        scale = STRIP_WIDTH_PX / rgb.shape[1]
        base = cv2.resize(rgb, (STRIP_WIDTH_PX, round(rgb.shape[0] * scale)), interpolation=cv2.INTER_AREA)
        base = (base * 0.75).astype(np.uint8)  # dimmed, so the keypoints stand out
        points = d["keypoints_px"][starts[i] : starts[i + 1]] * scale
        codes = d["rejection"][starts[i] : starts[i + 1]]
        decision, truth = base.copy(), base.copy()
        moving = d["moving"][starts[i] : starts[i + 1]] if "moving" in d else None
        for j, (u, v) in enumerate(np.rint(points).astype(int)):
            colour = DECISION_COLOURS.get(names[codes[j]], (255, 255, 255))
            cv2.circle(decision, (int(u), int(v)), 2, colour, -1, cv2.LINE_AA)
            if moving is not None:
                cv2.circle(truth, (int(u), int(v)), 2, MOVING_COLOUR if moving[j] else STATIC_COLOUR, -1)
        label = f"frame {i}  {view.states[i].lower()}"
        for tile in (decision, truth):
            cv2.putText(tile, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        tiles_decision.append(decision)
        tiles_truth.append(truth)
    rows = [np.hstack(tiles_decision)]
    if "moving" in d:
        rows.append(np.hstack(tiles_truth))
    # JPEG: rendered frames are photographs to the codec (a PNG strip weighs ~1 MB).
    ok, jpeg = cv2.imencode(".jpg", np.vstack(rows)[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 88])
    return jpeg.tobytes() if ok else None


# -- page ----------------------------------------------------------------------


def percent(value: float | None) -> float | None:
    """A percentage shown to 0.01 %: rho of a run that matches its reference to the
    micrometre is 0, not 1.304e-06 (what four significant digits make of it)."""
    return None if value is None else round(value, 2)


def _render(name: str, notes: Notes, **context: Any) -> str:
    """A page from its template, with the strip's colours every run section names."""
    return render(
        name,
        notes=notes.items,
        moving_colour=MOVING_COLOUR,
        static_colour=STATIC_COLOUR,
        **context,
    )


@dataclass(frozen=True)
class RunSection:
    """What a run's section shows (``templates/run.html.j2``)."""

    heading: str
    title: str
    where: str
    summary: Table
    plots: list[Image]
    strip: Image | None
    strip_problem: str | None
    decisions: list[tuple[str, tuple[int, int, int]]]
    """The strip's legend: each decision that occurs in the run, with its colour."""
    map_scores: Table | None
    map_image: Image | None
    difficulty: Table | None
    difficulty_missing: str | None


def difficulty_table(view: RunView) -> tuple[Table | None, str | None]:
    """The scenario's difficulty, or why there is none."""
    sequence = view.sequence
    if sequence is None:
        return None, f"Left out: {view.sequence_problem or 'no sequence'}."
    difficulty = (sequence.meta or {}).get("difficulty")
    if not isinstance(difficulty, dict) or not difficulty:
        return None, "No difficulty recorded (not a generated sequence)."
    rows = [[k.replace("_", " "), v] for k, v in sorted(difficulty.items())]
    profile = (sequence.meta or {}).get("sensor_profile")
    if isinstance(profile, str):  # sequences from 0.7 and before name none
        rows.insert(0, ["sensor profile", profile])
    return Table(["measure", "value"], rows), None


def _strip(view: RunView, notes: Notes) -> tuple[Image | None, str | None]:
    """The frame strip, or why there is none (noted when something is wrong: a run without
    diagnostics, an external tracker's, is not)."""
    problem = strip_problem(view)
    strip = None
    if problem is None:
        try:
            strip = frame_strip(view)
        except FileError as exc:  # a frame file of the sequence that cannot be decoded
            if view.sequence is None or not _inside(exc.path, view.sequence.root):
                raise
            problem = f"sequence {view.sequence.root}: damaged ({exc})"
        if strip is None and problem is None:
            problem = "the frames could not be encoded as JPEG"
    if strip is not None:
        return Image(strip, "frames with keypoints"), None
    if view.diagnostics is not None and view.sequence is not None:
        notes.add(f"{view.title}: frame strip: {problem}")
    return None, str(problem)


def _decisions_shown(view: RunView) -> list[tuple[str, tuple[int, int, int]]]:
    """The decisions the run made, in the colours the strip draws them (an external program's
    run: kept and rejected; the built-in tracker's: the reasons it gave)."""
    d = view.diagnostics
    names = [str(n) for n in d["rejection_names"]]
    used = sorted({int(c) for c in np.unique(d["rejection"])})
    return [(names[c].replace("_", " "), DECISION_COLOURS.get(names[c], (255, 255, 255))) for c in used]


SUMMARY_HEADER = [
    "ATE RMSE (m)",
    "ATE max (m)",
    "RPE RMSE (m)",
    "tracked",
    "lost",
    "keyframes",
    "precision",
    "recall",
    "ms/frame",
]


def run_section(view: RunView, heading: str, notes: Notes) -> RunSection:
    m = view.metrics
    ate, rpe = m.get("ate_m") or {}, m.get("rpe_translation_m") or {}
    rejection = m.get("rejection") or {}
    total = (m.get("stage_time") or {}).get("tracking_total") or {}
    summary = [
        ate.get("rmse"),
        ate.get("max"),
        rpe.get("rmse"),
        f"{m.get('tracked_frames')}/{m.get('frames')}",
        m.get("lost_frames"),
        m.get("keyframes"),
        rejection.get("precision"),
        rejection.get("recall"),
        total.get("mean_ms"),
    ]
    plots = [
        Image(figure_png(trajectory_figure(view)), "trajectory from above"),
        Image(figure_png(error_figure(view)), "error over time"),
    ]
    strip, problem = _strip(view, notes)
    legend = _decisions_shown(view) if strip is not None else []
    scores, picture = _map_parts(view)
    difficulty, missing = difficulty_table(view)
    where = view.sequence.root if view.sequence is not None else view.metrics.get("sequence") or "?"
    return RunSection(
        heading=heading,
        title=view.title,
        where=str(where),
        summary=Table(SUMMARY_HEADER, [summary]),
        plots=plots,
        strip=strip,
        strip_problem=problem,
        decisions=legend,
        map_scores=scores,
        map_image=picture,
        difficulty=difficulty,
        difficulty_missing=missing,
    )


MAX_MAP_BYTES = 256 * MIB
"""map.ply: 15 bytes a point (binary xyz and rgb), so 17M points, far above a 2 cm map of a hall."""


def _placed_map(folder: Path, metrics: dict[str, Any], sequence: Sequence | None, notes: Notes):
    """A run folder's map.ply (``--map`` runs on a generated sequence) placed and classified, once
    for the page and the Rerun recording; a map that cannot be read or placed is named in the
    notes and left out."""
    figures = metrics.get("map")
    if not isinstance(figures, dict) or "to_groundtruth" not in figures:
        return None
    path = folder / "map.ply"
    if sequence is None or not sequence.is_generated:
        notes.add(f"{path}: left out: the dense map (no generated sequence to place it against)")
        return None
    from depotbench.eval.report.maps import placed_map
    from depotbench.eval.run.dense import reference_of

    try:
        os.close(open_regular(path, MAX_MAP_BYTES, "run's map.ply"))
        placed = placed_map(folder, reference_of(sequence), str(metrics.get("strategy", "map")))
        _map_rows(placed.figures)  # what the page tabulates must be there, or the map is left out
    except (OSError, ValueError, KeyError, TypeError, FileError) as exc:
        notes.add(f"{path}: cannot be read ({exc}); left out: the dense map")
        return None
    return placed


def _map_rows(figures: dict[str, Any]) -> list[list[Any]]:
    return [
        [
            f"{s['threshold_m'] * 100:g} cm",
            s["accuracy"],
            s["completeness"],
            s["f_score"],
            s["ghost_fraction"],
        ]
        for s in figures.get("scores", [])
    ]


def _map_parts(view: RunView) -> tuple[Table | None, Image | None]:
    """A run folder's dense map from above, its ghosts in red, with its figures per threshold (a
    sweep's page sets its runs' maps side by side instead: ``_family_section``)."""
    if view.folder is None or view.placed is None:
        return None, None
    from depotbench.eval.report.maps import top_views

    scores = Table(
        ["within", "accuracy", "completeness", "F-score", "ghost fraction"], _map_rows(view.placed.figures)
    )
    return scores, Image(figure_png(top_views([view.placed])), "dense map from above")


def run_page(view: RunView, notes: Notes) -> str:
    section = run_section(view, "Run", notes)
    title = f"depotbench run: {view.title}"
    return _render(
        "run_page.html.j2", notes, title=title, subtitle=str(view.metrics.get("sequence") or ""), run=section
    )


# -- sweeps --------------------------------------------------------------------

PARETO_HEADER = ["family", "configuration", "detector", "ATE (m)", "ms"]
CONFIG_HEADER = [
    "family",
    "configuration",
    "detector",
    "runs held",
    "ATE (m)",
    "ρ (%)",
    "precision",
    "recall",
]
"""A configuration's columns in the best and every-configuration tables, before its time (ms);
the best one's table also shows the share of frames tracked."""


MAX_SUMMARY_BYTES = 64 * MIB
"""summary.json: about 420 bytes a configuration, so 45 MB for the largest sweep (100,000
jobs, each its own configuration)."""
Number = StrictFloat | StrictInt | None


class _Stats(BaseModel):
    """One figure over a configuration's runs (``depotbench.eval.metrics.statistics.Stats``)."""

    model_config = ConfigDict(extra="allow")
    n: StrictInt
    mean: Number = None
    ci_low: Number = None
    ci_high: Number = None


class _Configuration(BaseModel):
    """A configuration as ``depotbench.eval.sweep.summary.configurations`` writes it into summary.json.
    Its runs and statistics over seeds are optional: a sweep before them has none."""

    model_config = ConfigDict(extra="allow")
    label: StrictStr | None = None
    runs: StrictInt | None = None
    successes: StrictInt | None = None
    success_rate: Number = None
    stats: dict[StrictStr, _Stats] | None = None
    family: StrictStr
    tracker: StrictStr
    detector: StrictStr
    strategy: StrictStr
    settings: dict[StrictStr, StrictStr | StrictFloat | StrictInt]
    """Threshold values as the sweep wrote them (text, ``"0.5"``); the plots read them as numbers."""
    sequences: StrictInt
    ate_rmse_m: Number
    rho_percent: Number
    rejection_precision: Number
    rejection_recall: Number
    tracked_fraction: Number
    track_ms_median: Number

    @field_validator("settings")
    @classmethod
    def _numbers(cls, settings: dict[str, Any]) -> dict[str, Any]:
        for name, value in settings.items():
            try:
                number = float(value)
            except ValueError:
                number = math.nan
            if not math.isfinite(number):
                raise ValueError(f"{name}: {str(value)[:40]!r} is not a finite number")
        return settings


class _SuccessRule(BaseModel):
    model_config = ConfigDict(extra="allow")
    min_tracked_fraction: StrictFloat | StrictInt
    best_min_success_rate: StrictFloat | StrictInt


class _Summary(BaseModel):
    model_config = ConfigDict(extra="allow")
    configurations: list[_Configuration]
    best: dict[StrictStr, _Configuration]
    pareto: list[_Configuration]
    unqualified: dict[StrictStr, Number] | None = None
    success_rule: _SuccessRule | None = None


def _first_problem(source: str, exc: ValidationError) -> str:
    """One line: the first problem pydantic found, and how many more there are."""
    from depotbench.scenes.schema import format_validation_error

    lines = format_validation_error(source, exc).splitlines()
    return lines[0] + (f" (and {len(lines) - 1} more)" if len(lines) > 1 else "")


def read_summary(path: Path) -> dict[str, Any]:
    """summary.json, each part of the kind the page reads (``{}`` is refused by name, not a KeyError)."""
    try:
        text = read_text(path, MAX_SUMMARY_BYTES, "sweep's summary.json")
    except FileNotFoundError:
        raise FileError(path, None, "is missing (every sweep folder has one)") from None
    try:
        summary = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FileError(path, exc.lineno, f"not valid JSON ({exc.msg})") from None
    if not isinstance(summary, dict):
        kind = type(summary).__name__
        raise FileError(path, None, f"must hold a JSON object (configurations, best, pareto), not a {kind}")
    try:
        _Summary.model_validate(summary)
    except ValidationError as exc:
        raise InputError(_first_problem(str(path), exc)) from None
    return summary  # as written: settings keep their JSON form, which rows are matched by


def stored_spec(path: Path):
    """The sweep spec kept in results.sqlite (meta ``spec``), or None for a sweep without one."""
    from depotbench.eval.sweep.spec import SweepSpec
    from depotbench.eval.sweep.store import ResultStore

    with ResultStore(path, readonly=True) as store:
        stored = store.meta("spec")
    if stored is None:
        return None
    try:
        return SweepSpec.model_validate_json(stored)
    except ValidationError as exc:
        raise InputError(_first_problem(f"{path}: meta 'spec'", exc)) from None


def stored_spec_path(path: Path) -> str | None:
    """Where the sweep's spec file was (meta ``spec_path``): its relative paths (a program,
    a model, a settings template) start there."""
    from depotbench.eval.sweep.store import ResultStore

    with ResultStore(path, readonly=True) as store:
        return store.meta("spec_path")


class SweepSequences:
    """The sweep's sequences by the path its rows store, each found (``resolve_sequence``)
    and opened once. One that is gone or damaged is noted, and the sections that need its
    frames are left out: the tables come from results.sqlite alone (probes M8, D6)."""

    def __init__(self, folder: Path, notes: Notes) -> None:
        self.folder = folder
        self.notes = notes
        self._opened: dict[str, Sequence | None] = {}

    def get(self, recorded: str) -> Sequence | None:
        if recorded not in self._opened:
            sequence, problem = open_sequence(recorded, self.folder)
            self._opened[recorded] = sequence
            if problem is not None:
                self._note(problem)
        return self._opened[recorded]

    def damaged(self, recorded: str, exc: FileError) -> None:
        """A frame file found bad while tracked again: the sequence is left out from here on."""
        self._opened[recorded] = None
        self._note(f"sequence {recorded}: damaged ({exc})")

    def _note(self, problem: str) -> None:
        self.notes.add(
            f"{problem}; left out: its scenario difficulty and run details (the tables are "
            "from results.sqlite)"
        )


def _row_of(rows: list[ScoredRun], family: str, config: dict[str, Any]) -> ScoredRun | None:
    """A stored row of ``config`` in ``family`` (settings compared as sorted JSON): one that
    did not fail and has an ATE where there is one (a configuration shown for a family where
    none held may have failed on some seeds)."""
    settings = json.dumps(config["settings"], sort_keys=True)
    matching = [
        r
        for r in rows
        if r["family"] == family
        and r["strategy"] == config["strategy"]
        and r["detector"] == config["detector"]
        and r["tracker"] == config["tracker"]
        and json.dumps(json.loads(r["settings"]), sort_keys=True) == settings
        and json.loads(r.get("parameters") or "{}") == (config.get("parameters") or {})
    ]
    return min(matching, key=lambda r: bool(r.get("failure")) or r.get("ate_rmse_m") is None, default=None)


@dataclass(frozen=True)
class _Grid:
    """What re-tracking a stored row needs from the sweep's spec."""

    trackers: list
    detectors: list
    variants: list
    anchor: Path
    """The sweep folder: rows name the sequences inside it relative to it."""
    dense_map: bool = False
    """The sweep's runs built dense maps (their keys say so)."""


def _job_of_row(row: ScoredRun | RunRecord, grid: _Grid, sequence: Sequence, fingerprint: str | None):
    """The job of a stored row outside the spec's grid (a search trial: its tracker's
    parameters or its strategy's settings were drawn), rebuilt from the row and trusted only
    if its key is the row's."""
    from depotbench.eval.run.harness import RunJob, identity_of, job_key, maps_itself, tracker_identity
    from depotbench.eval.sweep.engine import SweepJob
    from depotbench.eval.sweep.spec import threshold_value

    if fingerprint is None:
        return None
    trackers = [t for t in grid.trackers if t.label == row["tracker"]]
    detectors = [d for d in grid.detectors if d.label == row["detector"]]
    if not trackers or not detectors:
        return None
    parameters = tuple(sorted((k, str(v)) for k, v in json.loads(row.get("parameters") or "{}").items()))
    tracker = replace(trackers[0], parameters=parameters) if parameters else trackers[0]
    settings = tuple(sorted((k, threshold_value(k, v)) for k, v in json.loads(row["settings"]).items()))
    mapped = grid.dense_map and maps_itself(tracker)
    for detector in detectors:
        key = job_key(fingerprint, tracker_identity(tracker), detector, row["strategy"], settings, mapped)
        if key == row["key"]:
            run = RunJob(sequence.root, row["strategy"], detector, settings, tracker, mapped)
            identity = identity_of(run, key, row["family"], row["sequence"], fingerprint, row.get("seed"))
            return SweepJob(key, row["family"], run, fingerprint, identity)
    return None


def _missing_job(row: ScoredRun, fingerprint: str | None) -> str:
    """Why a stored row has no job in the spec's grid on the sequence as it is now."""
    if fingerprint is not None and row.get("sequence_fingerprint") not in (None, fingerprint):
        return (
            f"sequence {row['sequence']} is not the one the sweep ran on (its files or its folder "
            "changed, so its fingerprint differs)"
        )
    return "its settings are not in the spec's grid (a search trial)"


@dataclass(frozen=True)
class _Wanted:
    """A run of a family's section to track again, and how the section titles it."""

    family: str
    job: Any
    """The ``SweepJob`` of the run."""
    title: str
    sequence: Sequence
    recorded: str
    """The sequence as the rows name it."""


def _family_runs(
    family: str,
    config: dict,
    chosen: ScoredRun,
    rows: list[ScoredRun],
    sequence: Sequence,
    grid: _Grid,
    notes: Notes,
    role: str = "best",
) -> list[_Wanted]:
    """The featured run of a family (its best configuration's, or ``role``) and its none run,
    to be tracked again on ``sequence``."""
    from depotbench.eval.sweep.engine import jobs_for

    found = jobs_for(
        grid.variants, grid.trackers, grid.detectors, [(sequence.root, family)], grid.anchor, grid.dense_map
    )
    jobs = {j.key: j for j in found}
    fingerprint = found[0].fingerprint if found else None
    baseline = next(
        (
            r
            for r in rows
            if r["sequence"] == chosen["sequence"]
            and is_baseline(r)
            and r["detector"] == chosen["detector"]
            and r["tracker"] == chosen["tracker"]
            and (r.get("parameters") or "{}") == (chosen.get("parameters") or "{}")
        ),
        None,
    )
    wanted = [chosen] + ([baseline] if baseline is not None and baseline["key"] != chosen["key"] else [])
    runs = []
    for row in wanted:
        label = role if row is chosen else "baseline (none)"
        job = jobs.get(row["key"]) or _job_of_row(row, grid, sequence, fingerprint)
        if job is None:
            notes.add(f"{family}: the {label} run is not tracked again: {_missing_job(row, fingerprint)}")
            continue
        shown = settings_text(config["settings"]) if row is chosen else ""
        tracker = job.job.tracker
        parameters = settings_text(dict(tracker.parameters)) if tracker.parameters else ""
        parts = (f"{tracker.label} {parameters}", f"{job.job.strategy} {shown}", job.job.detector.label)
        title = f"{family_name(family)}: {label} — " + " · ".join(part.strip() for part in parts)
        seed = row.get("seed")
        if seed is not None:
            title += f" (seed {seed})"
        if tracker.type.external:  # the bench's own tracker repeats itself bit for bit
            title += " (run again for this page: an external program may not repeat its stored figures)"
        runs.append(_Wanted(family, job, title, sequence, row["sequence"]))
    return runs


PARALLEL_FRAMES = 300
"""The runs a page tracks again are shared among worker processes only when they hold at least
this many frames in all: a worker takes about 1.5 s to start (imports and compiled kernels),
a frame 10-30 ms to track, so fewer frames finish sooner in this process."""


def _track_again(index: int, job) -> tuple[int, Any, tuple[str, int | None, str] | None]:
    """Worker entry point: the ``index``-th wanted run tracked again from the stage cache, or
    the frame file that could not be read (path, line, problem: a FileError does not cross
    processes whole)."""
    from depotbench.eval.run.cache import StageCache
    from depotbench.eval.run.harness import track

    try:
        return index, track(job, StageCache.from_env()), None
    except FileError as exc:
        return index, None, (str(exc.path), exc.line, exc.problem)


def _featured_runs(
    folder: Path,
    rows: list[ScoredRun],
    held: set[str],
    featured: dict[str, tuple[dict, str]],
    sequences: SweepSequences,
    notes: Notes,
    workers: int = 1,
) -> dict[str, list[RunView]]:
    """Per family, the run of its featured configuration (``featured``: the configuration and
    what it is, ``best``), and its none run, tracked again from the cache, ``workers`` runs at
    a time (the views come in the families' order whatever order the runs finish in). ``held``:
    the keys of every row results.sqlite holds, whose views are kept (the others go)."""
    from depotbench.core.executors import make_pool
    from depotbench.eval.report import view_cache
    from depotbench.eval.sweep.spec import detector_configs, tracker_configs, tracker_variants, variants

    if not featured:
        return {}
    spec = stored_spec(folder / "results.sqlite")
    if spec is None:
        notes.add(
            "run details: results.sqlite keeps no sweep spec (meta 'spec') to track the best runs again"
        )
        return {}
    source = stored_spec_path(folder / "results.sqlite") or str(folder / "results.sqlite")
    try:
        trackers = tracker_configs(spec, source)
        grid = _Grid(
            tracker_variants(spec, trackers, source),
            detector_configs(spec, source),
            variants(spec),
            folder,
            spec.dense_map,
        )
    except InputError as exc:
        # A spec names its files relative to the spec file, which the sweep folder does not
        # keep (``onnx:models/x.onnx``): every result is still in the database.
        notes.add(f"run details: the sweep's spec cannot build its trackers and detectors again ({exc})")
        return {}
    wanted: list[_Wanted] = []
    for family, (config, role) in sorted(featured.items()):
        chosen = _row_of(rows, family, config)
        if chosen is None:
            notes.add(
                f"{family}: run details: no row of results.sqlite has summary.json's {role} configuration"
            )
            continue
        sequence = sequences.get(chosen["sequence"])
        if sequence is None:
            continue  # noted by ``sequences``
        wanted += _family_runs(family, config, chosen, rows, sequence, grid, notes, role)
    # A run tracked again for an earlier page is read back from the sweep folder
    # (``view_cache``): a finished sweep's page is written again without tracking anything.
    cache = view_cache.of_sweep(folder)
    kept: dict[int, RunView | None] = {}
    for i, w in enumerate(wanted):
        fields = view_cache.load(cache, w.job.key)
        kept[i] = None if fields is None else RunView(title=w.title, sequence=w.sequence, **fields)
    todo = [i for i, view in kept.items() if view is None]
    tracked: dict[int, tuple] = {}
    frames = sum(len(wanted[i].sequence) for i in todo)
    pool = make_pool("local", max(1, min(workers, len(todo))) if frames >= PARALLEL_FRAMES else 1)
    failed = True
    try:
        for _, (index, *answer) in pool.map_unordered(_track_again, [(i, wanted[i].job.job) for i in todo]):
            tracked[index] = answer
        failed = False
    finally:
        pool.close(failed)
    views: dict[str, list[RunView]] = {}
    damaged: set[str] = set()
    for index, run in enumerate(wanted):
        if kept[index] is not None:
            if run.recorded not in damaged:
                views.setdefault(run.family, []).append(kept[index])
            continue
        result, unreadable = tracked[index]
        if run.recorded in damaged:
            views.pop(run.family, None)  # left out from the first bad frame file on
            continue
        if unreadable is not None:  # a frame file that cannot be read: the sequence is damaged
            exc = FileError(*unreadable)
            if not _inside(exc.path, run.sequence.root):
                raise exc
            sequences.damaged(run.recorded, exc)
            damaged.add(run.recorded)
            views.pop(run.family, None)
            continue
        view = view_of(run.title, result, run.sequence)
        view_cache.store(cache, run.job.key, view)
        views.setdefault(run.family, []).append(view)
    removed = view_cache.retain(cache, held)
    if removed:
        runs = f"{removed} run{'s' if removed != 1 else ''}"
        LOG.info(f"removed the kept views of {runs} that results.sqlite no longer holds")
    return views


def _configuration(c: dict[str, Any]) -> str:
    """A configuration as the tables name it: an external tracker and the parameters its
    sweep varies first (``sweep_report.configuration_label``)."""
    return c.get("label") or configuration_label("builtin", {}, c["strategy"], c["settings"])


MAX_FAMILY_SECTIONS = 12
"""Families with a section of their own (every run plotted, the featured run and its none run
tracked again); a sweep over more names the others in the page's notes."""


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def mean_cell(c: dict[str, Any], metric: str, value: Any = None, kind: str = "") -> Any:
    """A mean as the tables show it: with its 95 % interval and n where the configuration has
    its statistics over runs (``0.0258 [0.0229, 0.0275] n=3``). ``value``: the mean shown
    (default ``c[metric]``); ``kind``: ``percent`` (to 0.01) or ``complement`` (1 - the
    figure: the tracked fraction from the lost one)."""
    stats = c.get("stats") if isinstance(c.get("stats"), dict) else {}
    entry = stats.get(metric)
    shown = c.get(metric) if value is None else value
    if not _finite(shown):
        return shown
    number = (lambda v: f"{v:.2f}") if kind == "percent" else (lambda v: f"{v:.4g}")  # noqa: E731
    if not isinstance(entry, dict) or not isinstance(entry.get("n"), int):
        return round(shown, 2) if kind == "percent" else shown
    low, high = entry.get("ci_low"), entry.get("ci_high")
    if kind == "complement" and _finite(low) and _finite(high):
        low, high = 1.0 - high, 1.0 - low
    interval = f"[{number(low)}, {number(high)}]" if _finite(low) and _finite(high) else None
    return Mean(number(shown), interval, entry["n"])


def held_cell(c: dict[str, Any]) -> str | None:
    """``3/4``: the configuration's runs that held, of all (None before statistics over seeds)."""
    runs, successes = c.get("runs"), c.get("successes")
    return f"{successes}/{runs}" if isinstance(runs, int) and isinstance(successes, int) else None


def _rule(summary: dict[str, Any]) -> SuccessRule:
    stored = summary.get("success_rule") or {}
    return SuccessRule(float(stored.get("min_tracked_fraction", SuccessRule().min_tracked_fraction)))


def _unqualified(summary: dict[str, Any]) -> tuple[int, list[tuple[str, float]]]:
    """How many families had no configuration that held on enough runs, and each one's best rate."""
    missing = summary.get("unqualified") or {}
    return len(missing), [(family, rate) for family, rate in sorted(missing.items()) if _finite(rate)]


def _featured_configuration(
    family: str, configs: list[dict[str, Any]], best: dict[str, dict]
) -> tuple[dict, str] | None:
    """The configuration a family's section tracks again: its best, or where none held on
    enough runs the one that held most often (then the lowest mean ATE); None if every run
    failed."""
    if family in best:
        return best[family], "best"
    usable = [c for c in configs if c["family"] == family and _finite(c["ate_rmse_m"])]
    if not usable:
        return None
    chosen = min(usable, key=lambda c: (-(c.get("success_rate") or 0.0), c["ate_rmse_m"]))
    return chosen, f"most reliable (held on {held_cell(chosen) or '?'}; none held on enough runs)"


@dataclass(frozen=True)
class Featured:
    """The configuration a family's section tracks again, and why that one."""

    role_title: str
    configuration: str
    detector: str
    held: str | None
    why: str | None


@dataclass(frozen=True)
class FamilySection:
    """A family: every run of every configuration, and its featured run and none run."""

    key: str
    name: str
    configurations: int
    runs: int
    featured: Featured | None
    strip: Image | None
    maps: Image | None
    runs_shown: list[RunSection]


def _family_section(
    family: str,
    configs: list[dict[str, Any]],
    featured: tuple[dict, str] | None,
    strip: bytes | None,
    views: list[RunView],
    notes: Notes,
) -> FamilySection:
    mine = [c for c in configs if c["family"] == family]
    chosen = None
    if featured is not None:
        config, role = featured
        chosen = Featured(
            role_title=role.split(" (")[0].capitalize(),
            configuration=_configuration(config),
            detector=config["detector"],
            held=held_cell(config),
            why=role if role != "best" else None,
        )
    maps = [view.placed for view in views if view.placed is not None]
    picture = None
    if maps:  # the featured run's map beside its none run's, ghosts in red (method 2's two pictures)
        from depotbench.eval.report.maps import top_views

        picture = Image(figure_png(top_views(maps)), f"dense maps of {family}")
    return FamilySection(
        key=family,
        name=family_name(family),
        configurations=len(mine),
        runs=sum(c.get("runs") or c.get("sequences") or 0 for c in mine),
        featured=chosen,
        strip=Image(strip, f"runs of {family}") if strip is not None else None,
        maps=picture,
        runs_shown=[run_section(view, view.title, notes) for view in views],
    )


def _configuration_row(c: dict[str, Any], tracked: bool) -> list[Any]:
    """A configuration's cells under ``CONFIG_HEADER``, then the share of frames tracked (where
    ``tracked``) and the median tracking time."""
    share = [mean_cell(c, "lost_fraction", c["tracked_fraction"], "complement")] if tracked else []
    return [
        family_name(c["family"]),
        _configuration(c),
        c["detector"],
        held_cell(c),
        mean_cell(c, "ate_rmse_m"),
        mean_cell(c, "rho_percent", kind="percent"),
        mean_cell(c, "rejection_precision"),
        mean_cell(c, "rejection_recall"),
        *share,
        mean_cell(c, "track_ms_median"),
    ]


def sweep_page(folder: Path, notes: Notes, featured: int = MAX_FAMILY_SECTIONS, workers: int = 1) -> str:
    """The sweep's page; ``featured``: how many families (in natural order, numbers by value) get a section;
    ``workers``: processes that track the featured runs again."""
    from depotbench.eval.sweep.store import ResultStore

    summary = read_summary(folder / "summary.json")
    with ResultStore(folder / "results.sqlite", readonly=True) as store:
        # an older program's rows stay apart; rho against the sweep's chosen baseline, if any
        rows = with_rho(store.current_records(), Baseline.from_dict(summary.get("baseline")))
        held = store.keys()
    sequences = SweepSequences(folder, notes)
    configs = summary["configurations"]
    best = summary["best"]
    rule = _rule(summary)
    best_rows = [
        _configuration_row(c, tracked=True)
        for _, c in sorted(best.items(), key=lambda item: family_order(item[0]))
    ]
    chosen_baseline = Baseline.from_dict(summary.get("baseline"))
    against = (
        "each run's own run without rejection (none) on its sequence"
        if chosen_baseline is None
        else f"the sweep's chosen baseline ({chosen_baseline.label()}) on its sequence"
    )
    unqualified_count, unqualified = _unqualified(summary)
    stored_rule = summary.get("success_rule")
    threshold_plots = [Image(figure_png(fig), name) for name, fig in threshold_figures(configs)]
    front = pareto_figure(configs)
    pareto = None
    if front is not None:
        pareto_rows = [
            [
                family_name(c["family"]),
                _configuration(c),
                c["detector"],
                mean_cell(c, "ate_rmse_m"),
                mean_cell(c, "track_ms_median"),
            ]
            for c in summary["pareto"]
        ]
        pareto = {
            "image": Image(figure_png(front), "Pareto plot"),
            "table": Table(PARETO_HEADER, pareto_rows),
        }
    difficulty = _difficulty_rows(rows, sequences)
    families = sorted_families(c["family"] for c in configs)
    shown, left = families[:featured], families[featured:]
    if left:
        notes.add(
            f"the sections of {len(left)} of {len(families)} families (the page shows every run of at most "
            f"{featured} families, the first in order; the tables hold them all): "
            + ", ".join(map(family_name, left))
        )
    chosen = {family: _featured_configuration(family, configs, best) for family in shown}
    trackable = {f: c for f, c in chosen.items() if c is not None}
    views = _featured_runs(folder, rows, held, trackable, sequences, notes, workers)
    strips = {
        family: figure_png(fig) for family, _, fig in strip_figures(configs, rows, rule, only=set(shown))
    }
    family_sections = [
        _family_section(family, configs, chosen[family], strips.get(family), views.get(family, []), notes)
        for family in shown
    ]
    all_rows = [  # sorted is stable: keeps the rest of the order
        _configuration_row(c, tracked=False) for c in sorted(configs, key=lambda c: family_order(c["family"]))
    ]
    subtitle = (
        f"{len(rows)} runs, {len(configs)} configurations over {len({r['sequence'] for r in rows})} sequences"
    )
    return _render(
        "sweep_page.html.j2",
        notes,
        title=f"depotbench sweep: {folder.name}",
        subtitle=subtitle,
        best=Table([*CONFIG_HEADER, "tracked", "ms"], best_rows),
        against=against,
        unqualified_count=unqualified_count,
        unqualified=unqualified,
        rule=stored_rule if isinstance(stored_rule, dict) else None,
        threshold_plots=threshold_plots,
        pareto=pareto,
        difficulty=difficulty,
        families=family_sections,
        configurations=Table([*CONFIG_HEADER, "ms"], all_rows),
    )


def _knobs(row: dict[str, Any]) -> str:
    """A row's suite knobs as ``name=value`` words, the seed left to its own column."""
    text = row.get("knobs")
    try:
        knobs = json.loads(text) if isinstance(text, str) and text else {}
    except ValueError:
        return str(text)
    if not isinstance(knobs, dict):
        return str(text)
    return settings_text({k: v for k, v in sorted(knobs.items()) if k != "seed"})


def _difficulty_rows(rows: list[ScoredRun], sequences: SweepSequences) -> Table | None:
    """Per sequence, its seed and suite knobs (from the rows) and its scenario's difficulty
    (from its meta.json; ``–`` where the sequence is gone or none was recorded)."""
    found: list[tuple[str, Any, str, dict | None]] = []
    for recorded in sorted({r["sequence"] for r in rows}):
        mine = [r for r in rows if r["sequence"] == recorded]
        seed = next((r.get("seed") for r in mine if r.get("seed") is not None), None)
        knobs = next((_knobs(r) for r in mine if _knobs(r)), "")
        opened = sequences.get(recorded)
        difficulty = (opened.meta or {}).get("difficulty") if opened is not None else None
        found.append((recorded, seed, knobs, difficulty if isinstance(difficulty, dict) else None))
    columns = sorted({name for *_, difficulty in found if difficulty for name in difficulty})
    suite = any(seed is not None or knobs for _, seed, knobs, _ in found)
    if not columns and not suite:
        return None  # gone or damaged (noted), or not generated sequences (none recorded)
    header = ["sequence", *(["seed", "knobs"] if suite else []), *[c.replace("_", " ") for c in columns]]
    table_rows = [
        [
            Path(recorded).name,
            *([seed, knobs] if suite else []),
            *[(difficulty or {}).get(c) for c in columns],
        ]
        for recorded, seed, knobs, difficulty in found
        if difficulty or suite
    ]
    return Table(header, table_rows)


def render_report(source: Path, workers: int = 1) -> Rendered:
    """The page for a run folder or a sweep folder, and what it leaves out (``workers``: the
    processes a sweep's page tracks its featured runs again in)."""
    notes = Notes()
    # lexists: a summary.json or metrics.json that is a device or a dangling link is refused
    # by name when read, not mistaken for no file at all.
    if (source / "results.sqlite").is_file() and os.path.lexists(source / "summary.json"):
        return Rendered(sweep_page(source, notes, workers=workers), notes)
    if os.path.lexists(source / "metrics.json"):
        view = load_run(source, notes)
        return Rendered(run_page(view, notes), notes, view)
    raise InputError(f"{source}: neither a run folder (metrics.json) nor a sweep folder (results.sqlite)")


def warn(notes: Notes) -> None:
    """The one warning line of a page that leaves something out (the command line shows it
    as ``depotbench report: warning: ...``; ``-q`` hides it)."""
    line = notes.warning()
    if line is not None:
        LOG.warning(line)


def write_report(source: Path, out: Path, workers: int = 1) -> Path:
    """The page written atomically as OUT/index.html (OUT: a folder the caller owns); what it
    leaves out is warned about on stderr."""
    from depotbench.core.output import write_text_atomic

    rendered = render_report(source, workers)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "index.html"
    write_text_atomic(path, rendered.text)
    warn(rendered.notes)
    return path
