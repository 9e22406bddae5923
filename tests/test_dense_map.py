"""slam.dense_map against what is known without it: plane geometry, voxel indices computed by
hand, closed-form pixel counts, a hand parse of the PLY bytes and OpenCV's projection."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from depotbench.core.camera import Intrinsics
from depotbench.detectors.detection import Detection, Prior
from depotbench.sim.camera import TUM_FREIBURG
from depotbench.slam.config import ConfigError, RejectionConfig
from depotbench.slam.dense_map import (
    DenseMap,
    DenseMapConfig,
    back_project,
    exclusion_mask,
    pixel_rays,
    write_ply,
)
from depotbench.slam.features import FrameFeatures
from depotbench.slam.rejection import classify
from depotbench.slam.types import REJECTION_CODES, FrameDiagnostics, Rejection, TrackingState
from scipy.spatial.transform import Rotation

VOXEL = 0.02
CAMERA = Intrinsics(fx=517.3, fy=516.5, cx=78.6, cy=55.3, width=160, height=120)


def _pose(rotvec, translation) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    pose[:3, 3] = translation
    return pose


def _rgb(camera: Intrinsics, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8)


def _by_hand(frames, voxel: float = VOXEL):
    """The voxel map computed independently: pinhole back-projection pixel by pixel, then
    floor(p / voxel), np.unique and np.add.at. Returns (voxel indices, mean points, mean colours)."""
    world, colour = [], []
    for pose, rgb, depth, camera in frames:
        v, u = np.nonzero(depth > 0)
        z = depth[v, u]
        camera_points = np.stack([(u - camera.cx) * z / camera.fx, (v - camera.cy) * z / camera.fy, z], 1)
        world.append(np.einsum("ij,nj->ni", pose[:3, :3], camera_points) + pose[:3, 3])
        colour.append(rgb[v, u].astype(np.float64))
    world, colour = np.concatenate(world), np.concatenate(colour)
    scaled = world / voxel
    margin = np.abs(scaled - np.rint(scaled)).min()
    assert margin > 1e-6, "test setup: a point lies on a voxel face"
    index, inverse = np.unique(np.floor(scaled).astype(np.int64), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    count = np.bincount(inverse)
    mean = np.zeros((len(index), 3))
    np.add.at(mean, inverse, world)
    mean_colour = np.zeros((len(index), 3))
    np.add.at(mean_colour, inverse, colour)
    return index, mean / count[:, None], np.rint(mean_colour / count[:, None]).astype(np.uint8)


def _sorted_rows(index: np.ndarray, *arrays: np.ndarray):
    order = np.lexsort(index.T[::-1])
    return (index[order], *(a[order] for a in arrays))


# (a) the closed case


def test_a_flat_wall_lands_on_its_plane_in_the_voxels_counted_by_hand():
    pose = _pose(0.3 * np.array([1.0, 2.0, 3.0]) / math.sqrt(14), [0.4, -0.2, 1.1])
    depth = np.full((CAMERA.height, CAMERA.width), 1.7)
    rgb = _rgb(CAMERA, 1)
    dense = DenseMap(DenseMapConfig(voxel_m=VOXEL))
    assert dense.add_keyframe(pose, rgb, depth, CAMERA, None) == CAMERA.width * CAMERA.height

    # every point on the wall plane n . p = n . t + 1.7, n the camera's optical axis in the world
    normal = pose[:3, 2]
    offset = normal @ pose[:3, 3] + 1.7
    assert np.abs(dense.points() @ normal - offset).max() < 1e-12

    index, mean, colour = _by_hand([(pose, rgb, depth, CAMERA)])
    assert len(dense) == len(index) == len(np.unique(np.floor(dense.points() / VOXEL), axis=0))
    got = _sorted_rows(dense.voxels(), dense.points(), dense.colours())
    assert np.array_equal(got[0], index)
    assert np.allclose(got[1], mean, rtol=0, atol=1e-12)
    assert np.array_equal(got[2], colour)
    assert dense.counts().sum() == CAMERA.width * CAMERA.height


def test_a_only_valid_in_range_unexcluded_depth_goes_in():
    depth = np.full((CAMERA.height, CAMERA.width), 1.0)
    depth[0, :] = 0.0
    depth[1, :] = np.nan
    depth[2, :] = 0.05  # nearer than min_depth_m
    depth[3, :] = 9.0  # farther than max_depth_m
    exclude = np.zeros(depth.shape, bool)
    exclude[10:20, 30:50] = True
    dense = DenseMap()
    added = dense.add_keyframe(np.eye(4), _rgb(CAMERA, 2), depth, CAMERA, exclude)
    assert added == (CAMERA.height - 4) * CAMERA.width - 10 * 20
    assert dense.counts().sum() == added
    assert np.allclose(dense.points()[:, 2], 1.0)


def test_a_memory_grows_with_voxels_not_keyframes():
    depth = np.full((CAMERA.height, CAMERA.width), 1.3)
    rgb = _rgb(CAMERA, 3)
    dense = DenseMap()
    dense.add_keyframe(np.eye(4), rgb, depth, CAMERA)
    size, nbytes, points = len(dense), dense.nbytes, dense.points()
    for _ in range(5):
        dense.add_keyframe(np.eye(4), rgb, depth, CAMERA)
    assert (len(dense), dense.nbytes, dense.keyframes) == (size, nbytes, 6)
    assert np.allclose(dense.points(), points, rtol=0, atol=1e-12)
    assert dense.counts().sum() == 6 * CAMERA.width * CAMERA.height


# (b) two keyframes of one wall


def test_b_two_views_of_one_wall_land_in_the_same_voxels():
    wall_z = 2.01  # a world plane z = 2.01: mid-voxel (100.5 voxels), so one voxel layer
    pose_a = np.eye(4)
    pose_b = _pose([0.02, 0.1, 0.0], [0.05, 0.03, 0.4])
    rays = pixel_rays(CAMERA)
    depth_a = np.full((CAMERA.height, CAMERA.width), wall_z)
    direction = np.concatenate([rays, np.ones((*rays.shape[:2], 1))], axis=-1) @ pose_b[:3, :3].T
    depth_b = (wall_z - pose_b[2, 3]) / direction[..., 2]  # z-depth where each ray of B meets the wall
    rgb_a, rgb_b = _rgb(CAMERA, 4), _rgb(CAMERA, 5)

    only_a, only_b, both = DenseMap(), DenseMap(), DenseMap()
    only_a.add_keyframe(pose_a, rgb_a, depth_a, CAMERA)
    only_b.add_keyframe(pose_b, rgb_b, depth_b, CAMERA)
    both.add_keyframe(pose_a, rgb_a, depth_a, CAMERA)
    both.add_keyframe(pose_b, rgb_b, depth_b, CAMERA)

    assert np.abs(both.points()[:, 2] - wall_z).max() < 1e-12
    assert set(both.voxels()[:, 2]) == {100}
    voxels_a = {tuple(v) for v in only_a.voxels()}
    voxels_b = {tuple(v) for v in only_b.voxels()}
    assert {tuple(v) for v in both.voxels()} == voxels_a | voxels_b
    # A samples its footprint every 4 mm, so each wall voxel inside it is A's: B's voxels there are A's
    lo, hi = only_a.points()[:, :2].min(axis=0) + VOXEL, only_a.points()[:, :2].max(axis=0) - VOXEL
    inner_b = [
        v
        for v, p in zip(only_b.voxels(), only_b.points(), strict=True)
        if (lo <= p[:2]).all() and (p[:2] <= hi).all()
    ]
    assert len(inner_b) > len(voxels_b) // 2
    assert {tuple(v) for v in inner_b} <= voxels_a
    # the merged means are those of both keyframes' readings together, computed by hand
    index, mean, colour = _by_hand([(pose_a, rgb_a, depth_a, CAMERA), (pose_b, rgb_b, depth_b, CAMERA)])
    got = _sorted_rows(both.voxels(), both.points(), both.colours())
    assert np.array_equal(got[0], index)
    assert np.allclose(got[1], mean, rtol=0, atol=1e-12)
    assert np.array_equal(got[2], colour)


# (c) what a keyframe leaves out

PERSON = Detection((20, 30, 60, 90), "person", Prior.DYNAMIC, 0.9)  # 40 x 60 = 2400 pixels
CHAIR = Detection((50, 70, 80, 100), "chair", Prior.STATIC, 0.9)  # overlaps PERSON on 10 x 20 = 200
DOUBTFUL = Detection((100, 10, 120, 30), "person", Prior.DYNAMIC, 0.3)  # below min_confidence
BOOK = Detection((85, 45, 100, 60), "book", Prior.POTENTIAL, 0.9)
DETECTIONS = (PERSON, CHAIR, DOUBTFUL, BOOK)
KEYPOINTS = np.array(
    [[30, 40], [55, 80], [110, 20], [130, 100], [90, 50]], dtype=np.float32
)  # person only, person and chair, doubtful box, free, book
R = 15


def _disk_count(r: int) -> int:
    """Lattice points with dx^2 + dy^2 <= r^2 (Gauss's circle problem), counted by columns."""
    return sum(2 * math.isqrt(r * r - dx * dx) + 1 for dx in range(-r, r + 1))


def _quarter_disk_count(r: int) -> int:
    return sum(math.isqrt(r * r - dx * dx) + 1 for dx in range(0, r + 1))


def _diagnostics(codes) -> FrameDiagnostics:
    codes = np.array([REJECTION_CODES[c] for c in codes], dtype=np.int8)
    n = len(codes)
    return FrameDiagnostics(
        0.0, TrackingState.OK, KEYPOINTS[:n], ("",) * n, codes, np.zeros(n, bool), keyframe=True
    )


def _decide(strategy: str) -> list[Rejection]:
    """The box decisions of slam.rejection.classify itself (no previous frame: no flow tests)."""
    n = len(KEYPOINTS)
    features = FrameFeatures(
        grey=np.zeros((CAMERA.height, CAMERA.width), np.uint8),
        keypoints_px=KEYPOINTS,
        undistorted_px=KEYPOINTS.astype(np.float64),
        octaves=np.zeros(n, np.int32),
        descriptors=np.zeros((n, 32), np.uint8),
        depth_m=np.ones(n),
        angles_deg=np.zeros(n),
    )
    codes = classify(strategy, features, None, DETECTIONS, RejectionConfig())
    by_code = {code: r for r, code in REJECTION_CODES.items()}
    return [by_code[int(c)] for c in codes]


def _mask(strategy, codes, **config):
    return exclusion_mask(strategy, _diagnostics(codes), DETECTIONS, CAMERA, DenseMapConfig(**config))


def test_c_box_rule_leaves_out_the_rejecting_box_less_its_static_overlap():
    codes = _decide("box_rule")
    K, D = Rejection.KEPT, Rejection.DYNAMIC_BOX
    assert codes == [D, K, K, K, K]  # the person-and-chair point is kept; the doubtful box ignored
    mask = _mask("box_rule", codes)
    expected = np.zeros(mask.shape, bool)
    expected[30:90, 20:60] = True
    expected[70:90, 50:60] = False
    assert mask.sum() == 40 * 60 - 10 * 20
    assert np.array_equal(mask, expected)
    dilated = _mask("box_rule", codes, box_dilation_px=3)
    assert dilated.sum() == (40 + 6) * (60 + 6) - (10 + 6) * (20 + 6)


def test_c_a_dynamic_box_that_rejected_nothing_stays_in():
    kept = [Rejection.KEPT] * len(KEYPOINTS)
    assert not _mask("box_rule", kept).any()
    # the only point rejected by a box is in the person: the doubtful box holds a kept point
    assert not _mask("box_rule", [Rejection.DYNAMIC_BOX, *kept[1:]])[10:30, 100:120].any()


def test_c_flow_rejections_leave_out_disks_round_those_keypoints_only():
    K, E, F = Rejection.KEPT, Rejection.EPIPOLAR, Rejection.FLOW_OUTLIER
    mask = _mask("box_epipolar_flow", [K, K, K, E, F])
    assert mask.sum() == 2 * _disk_count(R)  # disks at (130, 100) and (90, 50), inside the image
    v, u = np.mgrid[0 : CAMERA.height, 0 : CAMERA.width]
    expected = ((u - 130) ** 2 + (v - 100) ** 2 <= R * R) | ((u - 90) ** 2 + (v - 50) ** 2 <= R * R)
    assert np.array_equal(mask, expected)
    for r in (0, 1, 2, 7):
        assert _mask("box_epipolar_flow", [K, K, K, E], keypoint_radius_px=r).sum() == _disk_count(r)
    corner = exclusion_mask(
        "box_epipolar_flow",
        FrameDiagnostics(
            0.0,
            TrackingState.OK,
            np.zeros((1, 2), np.float32),
            ("",),
            np.array([REJECTION_CODES[E]]),
            np.zeros(1, bool),
        ),
        (),
        CAMERA,
    )
    assert corner.sum() == _quarter_disk_count(R)


def test_c_each_strategys_map_differs_as_its_decisions_do():
    K, D, M, E = Rejection.KEPT, Rejection.DYNAMIC_BOX, Rejection.MOVING_FLOW, Rejection.EPIPOLAR
    box_rule = _decide("box_rule")
    prior_flow = _decide("prior_flow")
    epipolar = _decide("box_epipolar_flow")
    assert prior_flow == epipolar == [D, D, K, K, K]  # these reject everything in a dynamic box
    prior_flow[4] = M  # the book's point moved against the camera's flow (set Q)
    epipolar[3] = E  # the free point is off its epipolar line
    masks = {
        "none": _mask("none", _decide("none")),
        "box_rule": _mask("box_rule", box_rule),
        "prior_flow": _mask("prior_flow", prior_flow),
        "box_epipolar_flow": _mask("box_epipolar_flow", epipolar),
    }
    counts = {name: int(m.sum()) for name, m in masks.items()}
    assert counts == {
        "none": 0,
        "box_rule": 2400 - 200,
        "prior_flow": 2400 + _disk_count(R),
        "box_epipolar_flow": 2400 + _disk_count(R),
    }
    assert (masks["prior_flow"] ^ masks["box_epipolar_flow"]).sum() == 2 * _disk_count(R)
    assert (masks["prior_flow"] & ~masks["box_rule"]).sum() == 200 + _disk_count(R)
    # and the map built with each mask leaves those pixels' readings out
    depth = np.full((CAMERA.height, CAMERA.width), 1.0)
    for name, mask in masks.items():
        assert (
            DenseMap().add_keyframe(np.eye(4), _rgb(CAMERA, 6), depth, CAMERA, mask)
            == depth.size - counts[name]
        )


def test_c_refuses_codes_the_strategy_cannot_give():
    K, D, E = Rejection.KEPT, Rejection.DYNAMIC_BOX, Rejection.EPIPOLAR
    with pytest.raises(ValueError, match="not all box_rule's"):
        _mask("box_rule", [D, E])
    with pytest.raises(ValueError, match="not all none's"):
        _mask("none", [D, K])
    with pytest.raises(ValueError, match="unknown strategy"):
        _mask("boxes", [K])
    with pytest.raises(ConfigError):
        DenseMapConfig(min_depth_m=3.0, max_depth_m=2.0)


# (d) the PLY file

PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4", "uint": "<u4",
             "float": "<f4", "double": "<f8"}  # fmt: skip


def _parse_ply(path: Path) -> np.ndarray:
    """A binary little-endian PLY of one vertex element, read with the header's own words."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").splitlines()
    assert lines[0] == "ply" and lines[1] == "format binary_little_endian 1.0"
    elements = [line.split() for line in lines if line.startswith("element")]
    assert len(elements) == 1 and elements[0][1] == "vertex"
    count = int(elements[0][2])
    fields = [(line.split()[2], PLY_TYPES[line.split()[1]]) for line in lines if line.startswith("property")]
    dtype = np.dtype(fields)
    assert len(data) - end == count * dtype.itemsize
    return np.frombuffer(data, dtype=dtype, offset=end)


def _cloud():
    rng = np.random.default_rng(7)
    return rng.normal(size=(500, 3)) * 3.0, rng.integers(0, 256, (500, 3), dtype=np.uint8)


def test_d_ply_reads_back_through_trimesh_and_by_hand(tmp_path: Path):
    dense = DenseMap()
    depth = np.full((CAMERA.height, CAMERA.width), 1.5)
    dense.add_keyframe(_pose([0.1, 0.2, 0.3], [1.0, 2.0, 3.0]), _rgb(CAMERA, 8), depth, CAMERA)
    points, colours = dense.points(), dense.colours()
    path = write_ply(tmp_path / "map.ply", points, colours)

    loaded = trimesh.load(path)
    assert isinstance(loaded, trimesh.PointCloud)
    assert np.array_equal(loaded.vertices, points.astype(np.float32).astype(np.float64))
    assert np.array_equal(np.asarray(loaded.colors)[:, :3], colours)

    body = _parse_ply(path)
    assert body.dtype.names[:6] == ("x", "y", "z", "red", "green", "blue")
    assert body.dtype["x"] == np.float32 and body.dtype["red"] == np.uint8
    assert np.array_equal(np.stack([body["x"], body["y"], body["z"]], 1), points.astype(np.float32))
    assert np.array_equal(np.stack([body["red"], body["green"], body["blue"]], 1), colours)
    assert [p.name for p in tmp_path.iterdir()] == ["map.ply"]


def test_d_ply_refuses_to_overwrite_unless_asked(tmp_path: Path):
    points, colours = _cloud()
    path = write_ply(tmp_path / "map.ply", points, colours)
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_ply(path, points[:10], colours[:10])
    assert path.read_bytes() == before
    write_ply(path, points[:10], colours[:10], overwrite=True)
    assert len(_parse_ply(path)) == 10
    with pytest.raises(ValueError, match="colours must be uint8"):
        write_ply(tmp_path / "bad.ply", points, colours.astype(np.int32))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.ply"]


# (e) a distorted lens

FR1 = TUM_FREIBURG["freiburg1"]


def _project(points_world: np.ndarray, pose: np.ndarray) -> np.ndarray:
    rotation = pose[:3, :3].T
    rvec, _ = cv2.Rodrigues(rotation)
    tvec = -rotation @ pose[:3, 3]
    projected, _ = cv2.projectPoints(points_world, rvec, tvec, FR1.matrix, np.array(FR1.distortion))
    return projected.reshape(-1, 2)


def test_e_distorted_back_projection_reprojects_through_opencv():
    assert FR1.distorted
    v, u = np.mgrid[0 : FR1.height, 0 : FR1.width]
    depth = 1.0 + 0.002 * u + 0.001 * v
    points = back_project(depth, pixel_rays(FR1), np.ones(depth.shape, bool))
    pixels = np.stack([u.ravel(), v.ravel()], 1)
    assert np.abs(_project(points, np.eye(4)) - pixels).max() < 0.01
    # the plain pinhole would miss by pixels at the corners: the check has teeth
    pinhole = Intrinsics(FR1.fx, FR1.fy, FR1.cx, FR1.cy, FR1.width, FR1.height)
    plain = back_project(depth, pixel_rays(pinhole), np.ones(depth.shape, bool))
    assert np.abs(_project(plain, np.eye(4)) - pixels).max() > 1.0


def test_e_the_map_of_a_distorted_camera_reprojects_through_opencv():
    pose = _pose([0.1, -0.2, 0.05], [0.3, 0.1, -0.2])
    depth = np.zeros((FR1.height, FR1.width))
    rows, cols = np.r_[0 : FR1.height : 40, FR1.height - 1], np.r_[0 : FR1.width : 40, FR1.width - 1]
    depth[np.ix_(rows, cols)] = 1.2  # readings 7 cm apart or more: one per voxel
    dense = DenseMap()
    dense.add_keyframe(pose, _rgb(FR1, 9), depth, FR1)
    assert len(dense) == len(rows) * len(cols)
    projected = _project(dense.points(), pose)
    nearest = np.rint(projected).astype(int)
    assert {tuple(p) for p in nearest} == {(c, r) for r in rows for c in cols}
    assert np.abs(projected - nearest).max() < 0.01


def test_c_a_fractional_box_holds_the_pixels_a_keypoint_on_them_would_be_rejected_in():
    person = Detection((20.5, 30.2, 60.5, 90.7), "person", Prior.DYNAMIC, 0.9)
    diagnostics = FrameDiagnostics(
        0.0,
        TrackingState.OK,
        KEYPOINTS[:1],
        ("",),
        np.array([REJECTION_CODES[Rejection.DYNAMIC_BOX]]),
        np.zeros(1, bool),
    )
    for dilation, columns, rows in ((0.0, 40, 60), (0.3, 40, 61), (1.0, 42, 62)):
        mask = exclusion_mask(
            "box_rule", diagnostics, (person,), CAMERA, DenseMapConfig(box_dilation_px=dilation)
        )
        v, u = np.mgrid[0 : CAMERA.height, 0 : CAMERA.width]
        x0, y0, x1, y1 = person.box_xyxy
        expected = (u >= x0 - dilation) & (u < x1 + dilation) & (v >= y0 - dilation) & (v < y1 + dilation)
        assert mask.sum() == columns * rows
        assert np.array_equal(mask, expected)
