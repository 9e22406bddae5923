"""ATE and RPE as evo computes them, and the improvement rate against a baseline.

Functions take associated trajectories (see ``depotbench.eval.metrics.trajectory.associate``) and
return frozen results; nothing is modified in place, so sweeps can reuse inputs.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from enum import StrEnum

import numpy as np
from depotbench.core.errors import InputError
from depotbench.eval.metrics.alignment import Alignment, Similarity, align
from depotbench.eval.metrics.trajectory import Trajectory
from scipy.spatial.transform import Rotation

RPE_REL_DELTA_TOL = 0.1
"""All-pairs RPE in metres accepts a pair whose path length is delta +- this fraction (evo)."""


class DeltaUnit(StrEnum):
    FRAMES = "frames"
    METRES = "m"


@dataclass(frozen=True)
class Statistics:
    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    count: int

    @classmethod
    def of(cls, errors: np.ndarray) -> Statistics:
        if errors.size == 0:
            raise InputError("no error samples: the trajectories are too short for this metric")
        return cls(
            rmse=float(np.sqrt(np.mean(errors**2))),
            mean=float(np.mean(errors)),
            median=float(np.median(errors)),
            std=float(np.std(errors)),
            min=float(np.min(errors)),
            max=float(np.max(errors)),
            sse=float(np.sum(errors**2)),
            count=int(errors.size),
        )

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class AteResult:
    """Absolute trajectory error (translation) after alignment."""

    statistics: Statistics
    errors_m: np.ndarray
    timestamps_s: np.ndarray
    alignment: Alignment
    transform: Similarity


def ate(reference: Trajectory, estimate: Trajectory, alignment: Alignment = Alignment.SE3) -> AteResult:
    """Translational ATE of associated trajectories (evo ``ape`` translation_part)."""
    if len(reference) != len(estimate):
        raise ValueError("ate needs associated trajectories of equal length")
    aligned, transform = align(estimate, reference, alignment)
    errors = np.linalg.norm(aligned.positions_m - reference.positions_m, axis=1)
    return AteResult(Statistics.of(errors), errors, reference.timestamps_s.copy(), alignment, transform)


@dataclass(frozen=True, eq=False)
class RpeResult:
    """Relative pose error, translational (m) and rotational (degrees)."""

    translation: Statistics
    rotation_deg: Statistics
    translation_errors_m: np.ndarray
    rotation_errors_deg: np.ndarray
    pairs: np.ndarray
    delta: float
    unit: DeltaUnit
    all_pairs: bool


def pairs_by_frames(n: int, delta: int, all_pairs: bool) -> np.ndarray:
    """Index pairs ``delta`` frames apart: every start (all pairs) or chained."""
    if delta < 1:
        raise InputError(f"RPE delta in frames must be >= 1, got {delta}")
    starts = np.arange(max(n - delta, 0)) if all_pairs else np.arange(0, n, delta)[:-1]
    return np.stack([starts, starts + delta], axis=1).astype(int).reshape(-1, 2)


def pairs_by_path(positions: np.ndarray, delta: float, tol: float, all_pairs: bool) -> np.ndarray:
    """Index pairs ``delta`` metres of travelled path apart, as evo's ``filter_pairs_by_path``."""
    if delta <= 0:
        raise InputError(f"RPE delta in metres must be > 0, got {delta}")
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    if all_pairs:
        travelled = np.concatenate([[0.0], np.cumsum(steps)])
        pairs = []
        for i in range(len(travelled) - 1):
            ahead = travelled[i + 1 :] - travelled[i]
            k = int(np.argmin(np.abs(ahead - delta)))
            if abs(ahead[k] - delta) <= tol:
                pairs.append((i, i + 1 + k))
        return np.array(pairs, dtype=int).reshape(-1, 2)
    ids = [0]
    current = 0.0
    for i, step in enumerate(steps, start=1):
        current += float(step)
        if current >= delta:
            ids.append(i)
            current = 0.0
    return np.array(list(zip(ids, ids[1:], strict=False)), dtype=int).reshape(-1, 2)


def rpe(
    reference: Trajectory,
    estimate: Trajectory,
    delta: float = 1,
    unit: DeltaUnit = DeltaUnit.FRAMES,
    all_pairs: bool = False,
    alignment: Alignment = Alignment.NONE,
    rel_delta_tol: float = RPE_REL_DELTA_TOL,
    pairs_from_reference: bool = False,
) -> RpeResult:
    """RPE of associated trajectories (evo ``rpe``, translation_part and angle_deg).

    The error of pair (i, j) is ``inv(inv(Q_i) Q_j) inv(P_i) P_j``. As in evo,
    pairs are chosen on the estimate unless ``pairs_from_reference``.
    """
    if len(reference) != len(estimate):
        raise ValueError("rpe needs associated trajectories of equal length")
    estimate, _ = align(estimate, reference, alignment)
    chooser = reference if pairs_from_reference else estimate
    if not np.isfinite(delta):
        raise InputError(f"RPE delta must be a finite number, got {delta}")
    if unit is DeltaUnit.FRAMES:
        if float(delta) != int(delta):
            raise InputError(f"RPE delta in frames must be a whole number, got {delta}")
        # A delta beyond the trajectory has no pairs (and would overflow an index).
        pairs = pairs_by_frames(len(chooser), int(min(delta, len(chooser))), all_pairs)
    else:
        pairs = pairs_by_path(chooser.positions_m, float(delta), rel_delta_tol * float(delta), all_pairs)
    if len(pairs) == 0:
        raise InputError(
            f"no pose pairs {delta} {unit.value} apart in {len(chooser)} poses; use a smaller delta"
        )
    q, p = reference.poses, estimate.poses
    i, j = pairs[:, 0], pairs[:, 1]
    ref_rel = np.linalg.inv(q[i]) @ q[j]
    est_rel = np.linalg.inv(p[i]) @ p[j]
    error = np.linalg.inv(ref_rel) @ est_rel
    trans = np.linalg.norm(error[:, :3, 3], axis=1)
    rot = np.degrees(Rotation.from_matrix(error[:, :3, :3]).magnitude())
    return RpeResult(
        Statistics.of(trans), Statistics.of(rot), trans, rot, pairs, float(delta), unit, all_pairs
    )


def improvement_rate(baseline: float, value: float) -> float:
    """rho = (mu - gamma) / mu * 100 %, with mu the no-rejection baseline's error."""
    if not np.isfinite(baseline) or baseline <= 0:
        raise InputError(f"the baseline error must be positive and finite, got {baseline}")
    return (baseline - value) / baseline * 100.0
