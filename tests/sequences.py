"""Small synthetic sequences written through the real writer, for I/O tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from sim.camera import Intrinsics
from sim.ground_truth import ObjectState
from sim.sequence import SequenceWriter

SMALL = Intrinsics(fx=50.0, fy=50.0, cx=31.5, cy=23.5, width=64, height=48)


def random_frame(rng: np.random.Generator, k: int, intrinsics: Intrinsics = SMALL):
    h, w = intrinsics.height, intrinsics.width
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 6.0, (h, w)).astype(np.float32)
    depth[0, :5] = 0.0  # no reading
    instances = np.zeros((h, w), dtype=np.uint16)
    instances[10:20, 30:40] = 7
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()
    pose[:3, 3] = rng.normal(0, 1, 3)
    person = ObjectState(
        instance_id=7,
        class_name="person",
        prior="dynamic",
        position_m=(1.0, 2.0 + 0.01 * k, 0.0),
        quat_xyzw=(0.0, 0.0, 0.0, 1.0),
        linear_velocity_mps=(0.0, 0.3, 0.0),
        angular_velocity_radps=(0.0, 0.0, 0.1),
        moving=True,
        box_xyxy=(30, 10, 40, 20),
        visible_pixels=100,
        unoccluded_pixels=160,
        truncated=False,
    )
    chair = ObjectState(
        8,
        "chair",
        "potential",
        (3.0, 1.0, 0.0),
        (0.0, 0.0, 0.0, 1.0),
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0),
        False,
        None,
        0,
    )
    flow = rng.normal(0, 1, (h, w, 2)).astype(np.float32)
    return rgb, depth, pose, instances, (person, chair), flow


def write_sequence(root: Path, n: int = 5, seed: int = 0, fps: float = 30.0, with_flow: bool = True):
    """Write an ``n``-frame sequence; returns the frames as given to the writer."""
    rng = np.random.default_rng(seed)
    frames = []
    with SequenceWriter(root, SMALL, fps=fps, meta={"scenario": {"name": "test"}, "seed": seed}) as w:
        for k in range(n):
            rgb, depth, pose, instances, objects, flow = random_frame(rng, k)
            t = 1.0 + k / fps
            w.add_frame(t, rgb, depth, pose, instances, objects, flow if with_flow else None)
            frames.append((t, rgb, depth, pose, instances, objects, flow))
    return frames
