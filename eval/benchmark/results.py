"""A benchmark's results file: what was scored, on which bytes, with which program, and
every run's figures, recomputable from the trajectories it names (``benchmark verify``)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError
from depotbench.core.files import MIB, file_digest, read_json

FORMAT = "depotbench-benchmark-results"
FORMAT_VERSION = 1
MAX_RESULTS_BYTES = 64 * MIB
"""tum-dyn-1 with 10 repeats is 700 runs of about 1 kB each."""
METRICS = ("ate_m", "rpe_translation_m", "rpe_rotation_deg")
"""The papers' three errors: ATE translation, RPE translation and rotation per frame."""
STATISTICS = ("rmse", "mean", "median", "std")
"""What the papers print of each (Palazzolo, Bescos, Yu et al.: RMSE, mean, median, STD)."""
REL_TOLERANCE = 1e-9
"""``verify``: a figure recomputed on another machine may differ in its last bits (BLAS);
one that differs by more was changed."""


@dataclass(frozen=True)
class RunFigures:
    """One run's figures: each error's statistics (None where the run gave no trajectory to
    score, fewer than 3 poses) and the share of frames it tracked (poses / frames)."""

    errors: dict[str, dict[str, float]] | None
    tracked_share: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def figures_of(sequence: Path, trajectory: Path | None, frames: int) -> RunFigures:
    """The figures of a trajectory file against the sequence's ground truth, as ``run``
    scores a run (ATE aligned in SE(3), RPE per frame: ``ComparisonOptions()``)."""
    from depotbench.eval.metrics.evaluate import ComparisonOptions, compare
    from depotbench.eval.metrics.trajectory import Trajectory, read_tum
    from depotbench.sim.sequence import Sequence

    if trajectory is None:
        return RunFigures(None, 0.0)
    estimate = read_tum(trajectory)
    opened = Sequence.open(sequence)
    gt = opened.groundtruth
    if gt is None:
        raise InputError(f"{sequence}: no groundtruth.txt to score against")
    if len(estimate) < 3:
        return RunFigures(None, len(estimate) / frames)
    reference = Trajectory.from_quaternions(gt.timestamps_s, gt.positions_m, gt.quats_xyzw, "groundtruth")
    comparison = compare(reference, estimate, ComparisonOptions()).to_dict()
    errors = {m: {s: comparison[m][s] for s in STATISTICS} for m in METRICS}
    return RunFigures(errors, len(estimate) / frames)


def load_results(path: Path) -> dict[str, Any]:
    """A results file (or the folder holding ``results.json``), checked for its format."""
    if path.is_dir():
        path = path / "results.json"
    data = read_json(path, MAX_RESULTS_BYTES, "benchmark results")
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f"{path}: not a depotbench benchmark results file (no format {FORMAT!r})")
    if data.get("format_version") != FORMAT_VERSION:
        raise InputError(
            f"{path}: results format {data.get('format_version')}, this depotbench reads {FORMAT_VERSION}"
        )
    data["_path"] = str(path)
    return data


def _close(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is b
    return math.isclose(a, b, rel_tol=REL_TOLERANCE, abs_tol=1e-12)


def verify(path: Path) -> list[str]:
    """Every problem of a results file (``verify_results``)."""
    return verify_results(load_results(path))


def verify_results(results: dict[str, Any]) -> list[str]:
    """Every problem of loaded results (``load_results``): a trajectory changed since it was
    scored (its SHA-256), a figure that its trajectory does not give, a sequence whose bytes
    are not the ones it names. Empty when every figure is recomputed as recorded."""
    from depotbench.eval.run.detections import sequence_fingerprint
    from depotbench.sim.sequence import Sequence

    root = Path(results["_path"]).parent
    problems = []
    fresh = (results.get("fresh") or {}).get("sequences") or []
    for sequence, label in [
        *((s, s["name"]) for s in results["sequences"]),
        *((s, f"fresh {s['name']}") for s in fresh),
    ]:
        folder = root / sequence["folder"]
        if not folder.is_dir():
            problems.append(f"{label}: its sequence folder {folder} is missing")
            continue
        key = sequence_fingerprint(Sequence.open(folder))
        if key != sequence["files_key"]:
            problems.append(
                f"{label}: the sequence's files changed (key {key}, results name {sequence['files_key']})"
            )
            continue
        for run in sequence["runs"]:
            where = f"{label} run {run['repeat'] + 1}"
            if run["status"] != "ok":
                continue
            trajectory = root / run["folder"] / "trajectory.txt"
            if run["trajectory_sha256"] is None:
                recomputed = RunFigures(None, 0.0)
            elif not trajectory.is_file():
                problems.append(f"{where}: {trajectory} is missing")
                continue
            else:
                if file_digest(trajectory, "trajectory").hex() != run["trajectory_sha256"]:
                    problems.append(f"{where}: {trajectory} changed since it was scored")
                recomputed = figures_of(folder, trajectory, sequence_frames(root / run["folder"], sequence))
            problems += [f"{where}: {p}" for p in _differences(run["figures"], recomputed.to_dict())]
    return problems


def sequence_frames(run_folder: Path, sequence: dict[str, Any]) -> int:
    """Frames the run was given (the metrics' count: a dropped frame is no frame)."""
    metrics = read_json(run_folder / "metrics.json", MIB, "run metrics")
    return int(metrics["frames"]) if isinstance(metrics, dict) else int(sequence["frames"])


def _differences(recorded: dict[str, Any], recomputed: dict[str, Any]) -> list[str]:
    found = []
    if not _close(recorded.get("tracked_share"), recomputed["tracked_share"]):
        found.append(
            f"tracked_share {recorded.get('tracked_share')} recorded, "
            f"{recomputed['tracked_share']} recomputed"
        )
    mine, theirs = recorded.get("errors"), recomputed["errors"]
    if (mine is None) != (theirs is None):
        return [*found, f"errors {mine} recorded, {theirs} recomputed"]
    for metric in METRICS if mine else ():
        for stat in STATISTICS:
            a, b = mine.get(metric, {}).get(stat), theirs[metric][stat]
            if not _close(a, b):
                found.append(f"{metric} {stat} {a} recorded, {b} recomputed")
    return found
