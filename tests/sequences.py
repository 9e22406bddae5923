"""Small synthetic sequences written through the real writer, for I/O tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.sim.ground_truth import ObjectState
from depotbench.sim.sequence import SequenceWriter
from scipy.spatial.transform import Rotation

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


def tree_differences(a: Path, b: Path, skip: tuple[str, ...] = ()) -> list[str]:
    """What differs between two output folders, one line per file, saying how: files only
    one side has, and for a differing PNG the pixels that differ and by how much, for an
    .npz its arrays, for text the first differing line. Empty when byte-identical.

    A determinism failure is rare and costly to reproduce; the message is the evidence."""
    names_a = {p.relative_to(a) for p in a.rglob("*") if p.is_file() and p.name not in skip}
    names_b = {p.relative_to(b) for p in b.rglob("*") if p.is_file() and p.name not in skip}
    lines = [f"{rel}: only in {a}" for rel in sorted(names_a - names_b)]
    lines += [f"{rel}: only in {b}" for rel in sorted(names_b - names_a)]
    for rel in sorted(names_a & names_b):
        data_a, data_b = (a / rel).read_bytes(), (b / rel).read_bytes()
        if data_a != data_b:
            lines.append(f"{rel}: {_how_they_differ(rel.suffix, data_a, data_b)}")
    return lines


def _how_they_differ(suffix: str, data_a: bytes, data_b: bytes) -> str:
    import io

    import cv2

    if suffix == ".png":
        image_a = cv2.imdecode(np.frombuffer(data_a, np.uint8), cv2.IMREAD_UNCHANGED)
        image_b = cv2.imdecode(np.frombuffer(data_b, np.uint8), cv2.IMREAD_UNCHANGED)
        if image_a.shape != image_b.shape:
            return f"shapes {image_a.shape} and {image_b.shape}"
        delta = np.abs(image_a.astype(np.int64) - image_b.astype(np.int64))
        if delta.ndim == 3:
            delta = delta.max(axis=2)
        rows, cols = np.nonzero(delta)
        if not len(rows):
            return f"same pixels, different encoding ({len(data_a)} and {len(data_b)} bytes)"
        return (
            f"{len(rows)} pixels differ, by up to {delta.max()} "
            f"(first at row {rows[0]}, column {cols[0]}: {image_a[rows[0], cols[0]]} and "
            f"{image_b[rows[0], cols[0]]})"
        )
    if suffix == ".npz":
        arrays_a, arrays_b = np.load(io.BytesIO(data_a)), np.load(io.BytesIO(data_b))
        parts = []
        for key in sorted(set(arrays_a.files) | set(arrays_b.files)):
            if key not in arrays_a.files or key not in arrays_b.files:
                parts.append(f"{key} on one side only")
                continue
            x, y = arrays_a[key], arrays_b[key]
            if x.shape != y.shape:
                parts.append(f"{key} shapes {x.shape} and {y.shape}")
            elif not np.array_equal(x, y, equal_nan=True):
                unequal = ~((x == y) | (np.isnan(x) & np.isnan(y)))
                parts.append(
                    f"{key}: {int(unequal.sum())} values differ, by up to "
                    f"{float(np.nanmax(np.abs(x - y))):.3g}"
                )
        return "; ".join(parts) or "same arrays, different encoding"
    lines_a = data_a.decode(errors="replace").splitlines()
    lines_b = data_b.decode(errors="replace").splitlines()
    for k, (x, y) in enumerate(zip(lines_a, lines_b, strict=False)):
        if x != y:  # around the first differing character: long JSON lines share a prefix
            at = next((i for i, (p, q) in enumerate(zip(x, y, strict=False)) if p != q), min(len(x), len(y)))
            window = slice(max(0, at - 80), at + 80)
            return f"line {k + 1} differs at character {at + 1}: {x[window]!r} and {y[window]!r}"
    return f"{len(lines_a)} and {len(lines_b)} lines"
