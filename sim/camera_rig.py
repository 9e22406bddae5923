"""Seeded, smooth camera motions: TUM-style hand-held moves and a ground robot.

Each rig is a function of time returning ``world_from_camera`` (4x4, optical
frame). All motions are sums of sinusoids or arc-length paths, so velocity is
continuous.
"""

from __future__ import annotations

import math

import numpy as np
from depotbench.sim.conventions import look_at
from depotbench.sim.paths import Path
from depotbench.sim.products import product
from depotbench.sim.spec import CameraSpec
from scipy.spatial.transform import Rotation

ROBOT_LOOP = np.array([[-2.6, -2.0], [2.6, -2.0], [2.6, 2.95], [-2.6, 2.95]])
ROBOT_CAMERA_HEIGHT_M = 0.45


class CameraRig:
    def __init__(self, spec: CameraSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.freqs = rng.uniform(0.6, 1.4, (3, 3)) * 2 * math.pi / spec.period_s
        self.phases = rng.uniform(0, 2 * math.pi, (3, 3))
        self.jitter_freqs = rng.uniform(0.4, 1.6, (2, 3)) * 2 * math.pi
        self.jitter_phases = rng.uniform(0, 2 * math.pi, (2, 3))
        robot = spec.motion == "robot"
        # The robot drives its own loop: its spec's position and target are not used (and
        # not validated), so it gets no base pose, which they might not define.
        self.base = None if robot else look_at(np.array(spec.position_m), np.array(spec.target_m))
        self.path = Path(ROBOT_LOOP, smoothing_m=1.2) if robot else None

    def _wave(self, row: int, t: float) -> np.ndarray:
        return np.sin(self.freqs[row] * t + self.phases[row])

    def _jitter(self, t: float, metres: float, degrees: float) -> np.ndarray:
        pose = np.eye(4)
        pose[:3, 3] = metres * np.sin(self.jitter_freqs[0] * t + self.jitter_phases[0])
        rotvec = math.radians(degrees) * np.sin(self.jitter_freqs[1] * t + self.jitter_phases[1])
        pose[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
        return pose

    def world_from_camera(self, t: float) -> np.ndarray:
        s = self.spec
        motion = s.motion
        if motion == "robot":
            return self._robot(t)
        assert self.base is not None
        if motion == "static":
            return product(self.base, self._jitter(t, 0.002, 0.2))
        if motion == "xyz":
            pose = self.base.copy()
            pose[:3, 3] += product(
                self.base[:3, :3], s.amplitude_m * np.array([1.0, 0.6, 0.8]) * self._wave(0, t)
            )
            return product(pose, self._jitter(t, 0.0, 0.3))
        if motion == "rpy":
            pose = self.base.copy()
            rotvec = math.radians(s.amplitude_deg) * np.array([0.6, 1.0, 0.5]) * self._wave(1, t)
            pose[:3, :3] = product(pose[:3, :3], Rotation.from_rotvec(rotvec).as_matrix())
            return product(pose, self._jitter(t, 0.002, 0.0))
        if motion == "halfsphere":
            target = np.array(s.target_m)
            offset = np.array(s.position_m) - target
            radius = float(np.linalg.norm(offset))
            azimuth = math.atan2(offset[1], offset[0]) + math.radians(s.amplitude_deg) * self._wave(2, t)[0]
            elevation = math.asin(offset[2] / radius) + math.radians(0.5 * s.amplitude_deg) * (
                0.5 + 0.5 * self._wave(2, t)[1]
            )
            eye = target + radius * np.array(
                [
                    math.cos(elevation) * math.cos(azimuth),
                    math.cos(elevation) * math.sin(azimuth),
                    math.sin(elevation),
                ]
            )
            return product(look_at(eye, target), self._jitter(t, 0.0, 0.3))
        raise ValueError(f"camera.motion: unknown motion {motion!r}")

    def _robot(self, t: float) -> np.ndarray:
        """A ground robot's camera: along its loop at a constant speed, looking ahead."""
        assert self.path is not None
        arc = self.spec.speed_mps * t
        xy = self.path.point(arc)
        heading = self.path.tangent(arc)
        eye = np.array([xy[0], xy[1], ROBOT_CAMERA_HEIGHT_M + 0.004 * math.sin(9.0 * t)])
        target = eye + np.array([heading[0], heading[1], -0.08])
        return look_at(eye, target)
