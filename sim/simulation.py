"""Advance a built world in time: kinematic actors and camera, physical chairs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from depotbench.core.errors import ScenarioError
from depotbench.sim.conventions import cv_from_gl_rotation, gl_from_cv_rotation, quat_wxyz
from depotbench.sim.mujoco_env import mujoco
from depotbench.sim.world import World


@dataclass(frozen=True, eq=False)
class Snapshot:
    """Everything ground truth needs from one instant."""

    time_s: float
    world_from_camera: np.ndarray
    body_positions: np.ndarray
    body_rotations: np.ndarray
    qvel: np.ndarray


class Simulation:
    def __init__(self, world: World) -> None:
        self.world = world
        self.model = world.model
        self.data = mujoco.MjData(world.model)
        self.time_s = 0.0
        self._targets = self._kinematic_targets(0.0)
        self._apply(*self._targets)
        mujoco.mj_forward(self.model, self.data)
        self._check_warnings()

    def _kinematic_targets(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Mocap positions and quaternions (wxyz) of every actor part and the camera at t."""
        pos = self.data.mocap_pos.copy()
        quat = self.data.mocap_quat.copy()
        if self.world.actors:
            poses = [actor.pose(t) for actor in self.world.actors]
            ids = np.concatenate(self.world.actor_mocap)
            pos[ids] = np.concatenate([positions for positions, _ in poses])
            quat[ids] = quat_wxyz(np.concatenate([rotations for _, rotations in poses]))  # one batch
        pose = self.world.rig.world_from_camera(t)
        pos[self.world.camera_mocap] = pose[:3, 3]
        quat[self.world.camera_mocap] = quat_wxyz(gl_from_cv_rotation(pose[:3, :3]))
        return pos, quat

    def _apply(self, pos: np.ndarray, quat: np.ndarray) -> None:
        self.data.mocap_pos[:] = pos
        self.data.mocap_quat[:] = quat

    def advance_to(self, t: float) -> None:
        """Move to time t. With chairs, physics runs in substeps while the kinematic
        bodies move linearly between frames (so contacts see a continuous push)."""
        target = self._kinematic_targets(t)
        if self.world.chair_bodies:
            start_pos, start_quat = self._targets
            end_quat = np.where(
                np.sum(start_quat * target[1], axis=1, keepdims=True) < 0, -target[1], target[1]
            )
            n = self.world.substeps
            a = (np.arange(1, n + 1) / n)[:, None, None]  # every substep's poses in one go
            positions = (1 - a) * start_pos + a * target[0]
            quats = (1 - a) * start_quat + a * end_quat
            quats /= np.linalg.norm(quats, axis=2, keepdims=True)
            for k in range(n):
                self._apply(positions[k], quats[k])
                mujoco.mj_step(self.model, self.data)
            self._apply(*target)
        else:
            self._apply(*target)
            self.data.time = t
        self._targets = target
        self.time_s = t
        mujoco.mj_forward(self.model, self.data)
        self._check_warnings()

    def _check_warnings(self) -> None:
        """A warning from MuJoCo means the physics (hence the ground truth) went wrong: stop."""
        if not self.data.warning.number.any():
            return
        for kind, stat in enumerate(self.data.warning):
            if stat.number:
                raise ScenarioError(
                    f"the simulation failed at t = {self.time_s:.3f} s: "
                    f"{mujoco.mju_warningText(kind, stat.lastinfo)} (check chairs and paths that overlap "
                    "racks, props or each other)"
                )

    def snapshot(self) -> Snapshot:
        rotation = cv_from_gl_rotation(self.data.cam_xmat[self.world.camera_id].reshape(3, 3))
        pose = np.eye(4)
        pose[:3, :3] = rotation
        pose[:3, 3] = self.data.cam_xpos[self.world.camera_id]
        return Snapshot(
            self.time_s,
            pose,
            self.data.xpos.copy(),
            self.data.xmat.reshape(-1, 3, 3).copy(),
            self.data.qvel.copy(),
        )
