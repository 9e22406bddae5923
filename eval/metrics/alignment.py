"""Umeyama alignment of an estimated trajectory onto a reference (SE(3) or Sim(3))."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from depotbench.core.errors import InputError
from depotbench.eval.metrics.trajectory import Trajectory


class Alignment(StrEnum):
    NONE = "none"
    SE3 = "se3"
    SIM3 = "sim3"


class AlignmentError(InputError):
    """The positions are degenerate (too few, or all on one point)."""


@dataclass(frozen=True, eq=False)
class Similarity:
    """``x -> scale * rotation @ x + translation``."""

    rotation: np.ndarray
    translation: np.ndarray
    scale: float = 1.0

    @classmethod
    def identity(cls) -> Similarity:
        return cls(np.eye(3), np.zeros(3), 1.0)

    def apply(self, trajectory: Trajectory) -> Trajectory:
        """Left-multiply every pose; the scale acts on positions only (as evo)."""
        positions = self.scale * trajectory.positions_m @ self.rotation.T + self.translation
        rotations = np.einsum("ij,njk->nik", self.rotation, trajectory.rotations)
        return Trajectory(trajectory.timestamps_s.copy(), positions, rotations, trajectory.name)


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool) -> Similarity:
    """Least-squares similarity taking ``source`` points onto ``target`` (Umeyama, 1991)."""
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3:
        raise ValueError("source and target must both be (N, 3)")
    n = source.shape[0]
    mean_s, mean_t = source.mean(axis=0), target.mean(axis=0)
    centred_s, centred_t = source - mean_s, target - mean_t
    variance_s = float(np.sum(centred_s**2)) / n
    covariance = centred_t.T @ centred_s / n
    u, d, vt = np.linalg.svd(covariance)
    if np.count_nonzero(d > np.finfo(d.dtype).eps) < 2:
        raise AlignmentError(
            f"cannot align {n} positions: they are degenerate (fewer than 3 distinct, "
            "non-collinear points); use --align none"
        )
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1.0
    rotation = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / variance_s) if with_scale else 1.0
    translation = mean_t - scale * rotation @ mean_s
    return Similarity(rotation, translation, scale)


def align(estimate: Trajectory, reference: Trajectory, mode: Alignment) -> tuple[Trajectory, Similarity]:
    """Align associated trajectories (same length); returns the moved estimate and the transform."""
    if len(estimate) != len(reference):
        raise ValueError("align needs associated trajectories of equal length")
    if mode is Alignment.NONE:
        return estimate, Similarity.identity()
    transform = umeyama(estimate.positions_m, reference.positions_m, with_scale=mode is Alignment.SIM3)
    return transform.apply(estimate), transform
