"""Timed pose trajectories, TUM file I/O and timestamp association (evo semantics)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depotbench.core.errors import InputError
from depotbench.sim.tum_files import read_pose_file, write_pose_file
from scipy.spatial.transform import Rotation

DEFAULT_MAX_DIFF_S = 0.02
"""Association window, as TUM's associate.py and evaluate_ate.py use."""


class AssociationError(InputError):
    """Two trajectories share no timestamps within the window."""


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Poses ``world_from_body`` at timestamps. Operations return new trajectories."""

    timestamps_s: np.ndarray
    positions_m: np.ndarray
    rotations: np.ndarray
    name: str = ""

    def __post_init__(self) -> None:
        n = len(self.timestamps_s)
        if self.timestamps_s.shape != (n,) or self.positions_m.shape != (n, 3):
            raise ValueError("timestamps_s must be (N,), positions_m (N, 3)")
        if self.rotations.shape != (n, 3, 3):
            raise ValueError("rotations must be (N, 3, 3)")
        for array in (self.timestamps_s, self.positions_m, self.rotations):
            array.setflags(write=False)

    def __len__(self) -> int:
        return len(self.timestamps_s)

    @classmethod
    def from_poses(cls, timestamps_s: np.ndarray, poses: np.ndarray, name: str = "") -> Trajectory:
        poses = np.asarray(poses, dtype=np.float64)
        return cls(
            np.array(timestamps_s, dtype=np.float64),
            poses[:, :3, 3].copy(),
            poses[:, :3, :3].copy(),
            name,
        )

    @classmethod
    def from_quaternions(
        cls,
        timestamps_s: np.ndarray,
        positions_m: np.ndarray,
        quats_xyzw: np.ndarray,
        name: str = "",
    ) -> Trajectory:
        """Quaternions are normalised (TUM files store few decimals)."""
        rotations = Rotation.from_quat(np.asarray(quats_xyzw, dtype=np.float64)).as_matrix()
        return cls(
            np.array(timestamps_s, dtype=np.float64),
            np.array(positions_m, dtype=np.float64).reshape(-1, 3),
            rotations.reshape(-1, 3, 3),
            name,
        )

    @property
    def poses(self) -> np.ndarray:
        """(N, 4, 4) homogeneous ``world_from_body`` matrices."""
        poses = np.tile(np.eye(4), (len(self), 1, 1))
        poses[:, :3, :3] = self.rotations
        poses[:, :3, 3] = self.positions_m
        return poses

    @property
    def quats_xyzw(self) -> np.ndarray:
        return Rotation.from_matrix(self.rotations).as_quat(canonical=True)

    def subset(self, indices: np.ndarray | list[int]) -> Trajectory:
        idx = np.asarray(indices, dtype=int)
        return Trajectory(
            self.timestamps_s[idx].copy(),
            self.positions_m[idx].copy(),
            self.rotations[idx].copy(),
            self.name,
        )


def read_tum(path: Path | str) -> Trajectory:
    """Read a TUM trajectory file (``t tx ty tz qx qy qz qw``)."""
    path = Path(path)
    table = read_pose_file(path, strict=False)
    return Trajectory.from_quaternions(table.timestamps_s, table.positions_m, table.quats_xyzw, path.name)


def write_tum(path: Path | str, trajectory: Trajectory, header: str = "trajectory") -> None:
    write_pose_file(
        Path(path), trajectory.timestamps_s, trajectory.positions_m, trajectory.quats_xyzw, header
    )


def matching_indices(
    stamps_1: np.ndarray, stamps_2: np.ndarray, max_diff_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """For each stamp of ``stamps_1``, the nearest of ``stamps_2`` within ``max_diff_s``.

    Ties go to the earlier stamp. Stamps of ``stamps_2`` may be used more than
    once, exactly as evo's ``sync.matching_time_indices``.
    """
    if len(stamps_2) == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    if np.any(np.diff(stamps_2) < 0):
        return _matching_indices_unsorted(stamps_1, stamps_2, max_diff_s)
    upper = np.minimum(np.searchsorted(stamps_2, stamps_1, side="right"), len(stamps_2) - 1)
    diff_ub = stamps_2[upper] - stamps_1
    diff_lb = np.where(upper > 0, stamps_1 - stamps_2[np.maximum(upper - 1, 0)], np.inf)
    take_ub = (diff_ub <= max_diff_s) & (diff_ub < diff_lb)
    take_lb = ~take_ub & (diff_lb <= max_diff_s) & (diff_lb <= diff_ub)
    in_range = (stamps_1 >= stamps_2[0] - max_diff_s) & (stamps_1 <= stamps_2[-1] + max_diff_s)
    ok = in_range & (take_ub | take_lb)
    best = np.where(take_ub, upper, upper - 1)
    return np.flatnonzero(ok), best[ok]


def _matching_indices_unsorted(
    stamps_1: np.ndarray, stamps_2: np.ndarray, max_diff_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """``matching_indices`` for unsorted ``stamps_2``: evo's argmin over all pairs (the first
    index wins a tie), found by sorting instead of an N x M table of differences."""
    order = np.argsort(stamps_2, kind="stable")
    ordered = stamps_2[order]
    above = np.minimum(np.searchsorted(ordered, stamps_1, side="left"), len(ordered) - 1)
    below = np.maximum(above - 1, 0)
    # Among equal stamps the stable sort puts the smallest index first: take the run's first.
    below = np.searchsorted(ordered, ordered[below], side="left")
    diff_above = np.abs(ordered[above] - stamps_1)
    diff_below = np.abs(ordered[below] - stamps_1)
    index_above, index_below = order[above], order[below]
    take_below = (diff_below < diff_above) | ((diff_below == diff_above) & (index_below < index_above))
    best = np.where(take_below, index_below, index_above)
    ok = np.where(take_below, diff_below, diff_above) <= max_diff_s
    return np.flatnonzero(ok), best[ok]


def associate(
    reference: Trajectory,
    estimate: Trajectory,
    max_diff_s: float = DEFAULT_MAX_DIFF_S,
    offset_s: float = 0.0,
) -> tuple[Trajectory, Trajectory]:
    """Pairs of poses at (nearly) equal times, as evo's ``associate_trajectories``.

    The trajectory with fewer poses (the estimate on a tie) keeps all poses
    that find a partner; ``offset_s`` is added to the estimate's timestamps.
    """
    if max_diff_s < 0:
        raise InputError(f"max_diff_s must be >= 0, got {max_diff_s}")
    estimate_longer = len(estimate) > len(reference)
    short, long = (reference, estimate) if estimate_longer else (estimate, reference)
    shift = offset_s if estimate_longer else -offset_s
    idx_short, idx_long = matching_indices(short.timestamps_s, long.timestamps_s + shift, max_diff_s)
    if len(idx_short) == 0:
        raise AssociationError(
            f"no timestamps of {reference.name or 'the reference'} and "
            f"{estimate.name or 'the estimate'} lie within {max_diff_s} s of each other "
            f"(offset {offset_s} s); check that both use the same clock"
        )
    short, long = short.subset(idx_short), long.subset(idx_long)
    return (short, long) if estimate_longer else (long, short)
