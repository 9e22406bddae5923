"""The generator's compiled loops (``sim/kernels.py``) against their NumPy references, to the
bit: every generated sequence's bytes, and the frozen benchmarks' keys, hang on them. Each
case runs the reference with ``DEPOTBENCH_KERNELS=numpy`` and the kernels with numba on the
same inputs and seeds, and compares every bit of the output and the random streams left
behind (a kernel path that drew one value more would shift every later frame)."""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np
import pytest
from depotbench.core.camera import Intrinsics
from depotbench.core.jit import Kernels, compiled, using
from depotbench.scenes.schema import sensor_spec
from depotbench.sim.flow import exact_flow, rigid_motions
from depotbench.sim.generate import generate
from depotbench.sim.sensor import SensorModel
from depotbench.sim.spec import SensorSpec, default_scenario
from scipy.spatial.transform import Rotation

pytestmark = pytest.mark.skipif(not compiled(), reason="numba not installed: only the NumPy path runs")

TUM = sensor_spec("tum")
K = Intrinsics(535.4, 539.2, 320.1, 247.6, 640, 480)


def _both(function):
    """``function()`` on the NumPy path, then on the compiled one."""
    with using(Kernels.NUMPY):
        reference = function()
    with using(Kernels.NUMBA):
        kernel = function()
    return reference, kernel


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _pose(rng: np.random.Generator, spread: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(rng.normal(0, spread, 3)).as_matrix()
    pose[:3, 3] = rng.normal(0, spread, 3)
    return pose


def _flow_inputs(seed: int, moving_share: float):
    """A 640x480 frame: depths over the Kinect's range with a tenth missing, bodies moving
    in ``moving_share`` of it, and two camera poses."""
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.2, 9.0, (480, 640)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0.0
    n_bodies = 17
    bodies = np.where(rng.random(depth.shape) < moving_share, rng.integers(1, n_bodies, depth.shape), 0)
    pos0, pos1 = rng.normal(0, 2, (n_bodies, 3)), rng.normal(0, 2, (n_bodies, 3))
    rot0 = Rotation.random(n_bodies, random_state=seed).as_matrix()
    rot1 = Rotation.random(n_bodies, random_state=seed + 10).as_matrix()
    pos0[0], pos1[0], rot0[0], rot1[0] = 0, 0, np.eye(3), np.eye(3)
    motion = rigid_motions(pos0, rot0, pos1, rot1)
    return depth, bodies, K, _pose(rng, 0.3), _pose(rng, 0.3), motion


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("moving_share", [0.0, 0.3, 1.0])
def test_exact_flow_is_numpys_to_the_bit(seed: int, moving_share: float) -> None:
    inputs = _flow_inputs(seed, moving_share)
    reference, kernel = _both(lambda: exact_flow(*inputs))
    assert _same_bits(reference, kernel)  # NaN where depth is missing, and every -0.0
    assert np.isnan(reference[inputs[0] == 0]).all()


def _sensor_inputs(seed: int):
    """A textured 640x480 frame, its flow (NaN where depth is missing, a few infinities as a
    body at the camera's plane gives), and a depth map with readings on and beside the
    range's bounds."""
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    rgb[:, 300:] = 250  # a bright region: blur and gain push it past 255, clipped
    depth, bodies, *rest = _flow_inputs(seed, 0.3)
    flow = exact_flow(depth, bodies, *rest) * np.float32(0.05)  # a few px a frame
    flow[rng.random(depth.shape) < 1e-3] = np.inf
    near, far = np.float32(0.4), np.float32(8.0)
    depth.flat[:6] = [near, np.nextafter(near, 0), np.nextafter(near, 9), far, np.nextafter(far, 9), 0]
    return rgb, flow, depth


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize(
    "sensor",
    [TUM, sensor_spec("kinect"), SensorSpec(rgb_noise_sigma=3.0), SensorSpec(depth_noise=True)],
    ids=["tum", "kinect", "noise-only", "depth-noise-only"],
)
def test_the_sensor_model_is_numpys_to_the_bit(seed: int, sensor: SensorSpec) -> None:
    """Three frames in a row (the exposure and white balance carry state from frame to frame),
    RGB then depth with a delay, as generate calls them."""
    rgb, flow, depth = _sensor_inputs(seed)

    def run():
        model = SensorModel(sensor, np.random.default_rng(seed))
        out = []
        for delay in (0.0, 0.2, 0.1):
            out += [model.rgb(rgb, flow, 30.0), model.depth(depth, flow, delay)]
        return out, model.rng.bit_generator.state, model._colour_rng.bit_generator.state

    (reference, state, colour), (kernel, kernel_state, kernel_colour) = _both(run)
    for a, b in zip(reference, kernel, strict=True):
        assert _same_bits(a, b)
    assert state == kernel_state and colour == kernel_colour  # the same draws, no more, no fewer


def test_a_generated_tum_sequence_is_the_same_bytes_on_both_paths(tmp_path: Path) -> None:
    scenario = dataclasses.replace(
        default_scenario(frames=8, seed=3), width=160, height=120, focal_px=131.25, sensor=TUM, flow=True
    )

    def run(name: str):
        generate(scenario, tmp_path / name, progress=False)
        digest = hashlib.sha256()
        for path in sorted(p for p in (tmp_path / name).rglob("*") if p.is_file() and p.name != "meta.json"):
            digest.update(path.relative_to(tmp_path / name).as_posix().encode() + path.read_bytes())
        return digest.hexdigest()

    with using(Kernels.NUMPY):
        reference = run("numpy")
    with using(Kernels.NUMBA):
        kernel = run("numba")
    assert reference == kernel
