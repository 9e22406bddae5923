"""The same metrics computed by evo itself: the independent reference for our metrics."""

from __future__ import annotations

import copy

import numpy as np
from depotbench.eval.metrics.trajectory import Trajectory
from evo.core import metrics, sync
from evo.core.trajectory import PoseTrajectory3D


def to_evo(trajectory: Trajectory) -> PoseTrajectory3D:
    quat_wxyz = np.roll(trajectory.quats_xyzw, 1, axis=1)
    return PoseTrajectory3D(
        positions_xyz=trajectory.positions_m.copy(),
        orientations_quat_wxyz=quat_wxyz,
        timestamps=trajectory.timestamps_s.copy(),
    )


def evo_pair(ref: Trajectory, est: Trajectory, max_diff: float, align: str):
    r, e = sync.associate_trajectories(to_evo(ref), to_evo(est), max_diff=max_diff)
    e = copy.deepcopy(e)
    if align != "none":
        e.align(r, correct_scale=align == "sim3")
    return r, e


def evo_ape(ref: Trajectory, est: Trajectory, align: str = "se3", max_diff: float = 0.02) -> dict:
    r, e = evo_pair(ref, est, max_diff, align)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((r, e))
    return ape.get_all_statistics()


def evo_rpe(
    ref: Trajectory,
    est: Trajectory,
    delta: float,
    unit: str,
    all_pairs: bool,
    relation: str,
    align: str = "none",
    max_diff: float = 0.02,
) -> dict:
    r, e = evo_pair(ref, est, max_diff, align)
    pose_relation = {
        "trans": metrics.PoseRelation.translation_part,
        "rot": metrics.PoseRelation.rotation_angle_deg,
    }[relation]
    delta_unit = metrics.Unit.frames if unit == "frames" else metrics.Unit.meters
    rpe = metrics.RPE(pose_relation, delta, delta_unit, all_pairs=all_pairs)
    rpe.process_data((r, e))
    return rpe.get_all_statistics()
