"""``sim.flow.flow_at`` takes the static world's pixels with scalar coefficients and only the
moving bodies' through gathered ones: the flow must stay the same to the bit as the one
gathered 3x4 per pixel it replaced (every generated sequence's bytes hang on it)."""

from __future__ import annotations

import numpy as np
import pytest
from depotbench.core.camera import Intrinsics
from depotbench.sim.flow import flow_at, rigid_motions
from depotbench.sim.products import product, rigid_inverse
from scipy.spatial.transform import Rotation


def _gathered(u, v, z, bodies, k, world_from_cam0, world_from_cam1, body_motion):
    """The formula as it was: one gathered 3x4 per pixel."""
    z = z.astype(np.float64)
    x, y = (u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z
    through = product(product(rigid_inverse(world_from_cam1), body_motion), world_from_cam0)
    t = through[bodies, :3]
    cam1 = t[:, :, 0] * x[:, None] + t[:, :, 1] * y[:, None] + t[:, :, 2] * z[:, None] + t[:, :, 3]
    u1 = k.fx * cam1[:, 0] / cam1[:, 2] + k.cx
    v1 = k.fy * cam1[:, 1] / cam1[:, 2] + k.cy
    return np.stack([u1 - u, v1 - v], axis=-1)


def _pose(rng: np.random.Generator) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.2, 3)).as_matrix()
    pose[:3, 3] = rng.normal(0, 1, 3)
    return pose


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("moving_share", [0.0, 0.2, 1.0])
def test_the_per_body_flow_is_the_gathered_flow_to_the_bit(seed: int, moving_share: float):
    rng = np.random.default_rng(seed)
    k = Intrinsics(535.4, 539.2, 320.1, 247.6, 640, 480)
    v, u = (a.ravel().astype(np.float64) for a in np.mgrid[0:480, 0:640])
    z = rng.uniform(0.3, 8.0, u.size).astype(np.float32)
    n_bodies = 31
    bodies = np.where(rng.random(u.size) < moving_share, rng.integers(1, n_bodies, u.size), 0)
    pos0, pos1 = rng.normal(0, 2, (n_bodies, 3)), rng.normal(0, 2, (n_bodies, 3))
    rot0 = Rotation.random(n_bodies, random_state=seed).as_matrix()
    rot1 = Rotation.random(n_bodies, random_state=seed + 10).as_matrix()
    pos0[0], pos1[0], rot0[0], rot1[0] = 0, 0, np.eye(3), np.eye(3)  # body 0: the static world
    motion = rigid_motions(pos0, rot0, pos1, rot1)
    cam0, cam1 = _pose(rng), _pose(rng)
    new = flow_at(u, v, z, bodies, k, cam0, cam1, motion)
    old = _gathered(u, v, z, bodies, k, cam0, cam1, motion)
    assert new.dtype == old.dtype and new.shape == old.shape
    assert np.array_equal(new.view(np.int64), old.view(np.int64))  # every bit, NaN and -0.0 too
