"""The simulator against physics and geometry: reprojection, masks, gait, contacts, features."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from depotbench.sim.camera_rig import CameraRig
from depotbench.sim.conventions import cv_from_gl_rotation, gl_from_cv_rotation, look_at
from depotbench.sim.sequence import Sequence
from depotbench.sim.simulation import Simulation
from depotbench.sim.spec import ActorSpec, CameraSpec, ChairSpec, ScenarioSpec, default_scenario
from depotbench.sim.world import build_world
from scipy.ndimage import map_coordinates

from tests.conftest import REPO
from tests.sequences import tree_differences

pytestmark = pytest.mark.render


def small(spec: ScenarioSpec, frames: int, scale: int = 4, **changes) -> ScenarioSpec:
    """The same scene at 1/scale resolution (same field of view)."""
    return dataclasses.replace(
        spec,
        frames=frames,
        width=640 // scale,
        height=480 // scale,
        focal_px=525.0 / scale,
        **changes,
    )


@pytest.fixture(scope="module")
def walking(tmp_path_factory) -> Sequence:
    from depotbench.sim.generate import generate

    out = tmp_path_factory.mktemp("sim") / "walking"
    spec = small(default_scenario(), frames=8, scale=2, flow=True)
    generate(spec, out, progress=False)
    return Sequence.open(out)


def test_camera_conventions_round_trip():
    pose = look_at(np.array([1.0, -2.0, 1.5]), np.array([0.0, 1.0, 1.0]))
    r = pose[:3, :3]
    assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
    assert np.allclose(cv_from_gl_rotation(gl_from_cv_rotation(r)), r)
    # MuJoCo looks along its camera's -z: the optical axis is -z of the OpenGL frame.
    assert np.allclose(gl_from_cv_rotation(r)[:, 2], -r[:, 2])
    # The optical axis (z) points at the target, image y points down (world -z side).
    direction = np.array([0.0, 1.0, 1.0]) - np.array([1.0, -2.0, 1.5])
    assert np.allclose(r[:, 2], direction / np.linalg.norm(direction))
    assert r[2, 1] < 0


def test_ground_truth_pose_is_the_rigs_pose(walking: Sequence):
    world = build_world(scenario_of(walking))
    for i in range(len(walking)):
        expected = world.rig.world_from_camera(i / 30.0)
        np.testing.assert_allclose(walking.world_from_camera(i), expected, atol=2e-6)


def scenario_of(seq: Sequence) -> ScenarioSpec:
    from depotbench.sim.spec import spec_from_dict

    return spec_from_dict(seq.meta["scenario"])


def bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return map_coordinates(image.astype(np.float64), [v, u], order=1, mode="nearest")


def _reproject(seq: Sequence, i: int):
    """Static-world pixels of frame i moved into frame i+1 with depth and true poses."""
    k = seq.intrinsics
    depth, inst = seq.depth_m(i), seq.instances(i)
    v, u = np.nonzero((depth > 0) & (inst == 0))
    z = depth[v, u].astype(np.float64)
    pts = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)
    w0, w1 = seq.world_from_camera(i), seq.world_from_camera(i + 1)
    world = pts @ w0[:3, :3].T + w0[:3, 3]
    cam1 = (world - w1[:3, 3]) @ w1[:3, :3]
    u1 = k.fx * cam1[:, 0] / cam1[:, 2] + k.cx
    v1 = k.fy * cam1[:, 1] / cam1[:, 2] + k.cy
    return u, v, u1, v1, cam1[:, 2]


def test_static_world_reprojects_with_true_poses(walking: Sequence):
    for i in range(len(walking) - 1):
        u, v, u1, v1, z1 = _reproject(walking, i)
        ui, vi = np.rint(u1).astype(int), np.rint(v1).astype(int)
        h, w = walking.intrinsics.height, walking.intrinsics.width
        inside = (ui >= 1) & (ui < w - 1) & (vi >= 1) & (vi < h - 1)
        depth1, inst1 = walking.depth_m(i + 1), walking.instances(i + 1)
        ok = inside.copy()
        ok[inside] = inst1[vi[inside], ui[inside]] == 0
        # Rounding to the nearest pixel shifts depth on slanted surfaces: sample bilinearly.
        sampled = bilinear(depth1, u1[ok], v1[ok])
        residual = np.abs(sampled - z1[ok])
        visible = residual < 0.05  # the rest is occluded in frame i+1 or at depth edges
        assert visible.mean() > 0.9
        assert np.median(residual[visible]) < 1e-3
        grey0 = cv2.cvtColor(walking.rgb(i), cv2.COLOR_RGB2GRAY).astype(np.float32)
        grey1 = cv2.cvtColor(walking.rgb(i + 1), cv2.COLOR_RGB2GRAY).astype(np.float32)
        warped = bilinear(grey1, u1[ok], v1[ok])
        photometric = np.abs(warped - grey0[v[ok], u[ok]])[visible]
        # Control: a 2-pixel error in the warp shows how sensitive the check is.
        shifted = np.abs(bilinear(grey1, u1[ok] + 2.0, v1[ok]) - grey0[v[ok], u[ok]])[visible]
        assert np.median(photometric) < 3.0
        assert np.median(photometric) < 0.3 * np.median(shifted)


def test_flow_ground_truth_matches_reprojection_and_moving_instances(walking: Sequence):
    for i in range(len(walking) - 1):
        flow = walking.flow(i)
        u, v, u1, v1, _ = _reproject(walking, i)
        np.testing.assert_allclose(flow[v, u, 0], u1 - u, atol=1e-3)
        np.testing.assert_allclose(flow[v, u, 1], v1 - v, atol=1e-3)
        inst0, inst1 = walking.instances(i), walking.instances(i + 1)
        grey0 = cv2.cvtColor(walking.rgb(i), cv2.COLOR_RGB2GRAY).astype(np.float32)
        grey1 = cv2.cvtColor(walking.rgb(i + 1), cv2.COLOR_RGB2GRAY).astype(np.float32)
        for obj in walking.objects()[i]:
            # Mostly unoccluded movers only: where something passes in front of an instance,
            # its pixels' flow lands on the occluder in the next frame (a dog behind a seated
            # person's gesturing arm: 1379 of 3029 pixels visible, 75 % landing on the dog).
            if not (
                obj.moving and obj.visible_pixels > 200 and obj.visible_pixels > 0.8 * obj.unoccluded_pixels
            ):
                continue
            vv, uu = np.nonzero(inst0 == obj.instance_id)
            tu, tv = uu + flow[vv, uu, 0], vv + flow[vv, uu, 1]
            h, w = inst1.shape
            inside = (tu >= 0) & (tu <= w - 1) & (tv >= 0) & (tv <= h - 1)
            same = inst1[np.rint(tv[inside]).astype(int), np.rint(tu[inside]).astype(int)] == obj.instance_id
            assert same.mean() > 0.85, obj
            warped = bilinear(grey1, tu[inside], tv[inside])
            assert np.median(np.abs(warped - grey0[vv[inside], uu[inside]])[same]) < 10.0


def test_boxes_are_mask_extents_and_flags_follow_velocities(walking: Sequence):
    objects = walking.objects()
    for i in range(len(walking)):
        inst = walking.instances(i)
        for obj in objects[i]:
            vv, uu = np.nonzero(inst == obj.instance_id)
            assert obj.visible_pixels == len(vv)
            if len(vv):
                assert obj.box_xyxy == (uu.min(), vv.min(), uu.max() + 1, vv.max() + 1)
            else:
                assert obj.box_xyxy is None
            speed = np.linalg.norm(obj.linear_velocity_mps)
            if obj.class_name in ("dog",) or (obj.class_name == "person" and speed > 0.1):
                assert obj.moving
            if obj.prior == "potential" and obj.class_name != "chair":
                assert not obj.moving and speed == 0.0
            if obj.class_name == "chair":
                assert obj.moving == (speed > 0.01 or np.linalg.norm(obj.angular_velocity_radps) > 0.05)


def test_walkers_do_not_slide_their_feet():
    spec = ScenarioSpec(
        frames=1,
        actors=(
            ActorSpec("person", speed_mps=1.3),
            ActorSpec("person", speed_mps=0.7, path="random_walk"),
        ),
    )
    world = build_world(spec)
    sim = Simulation(world)
    feet = [[world.model.body(f"actor{k}_foot_{s}").id for s in "lr"] for k in range(2)]
    pelvis = [world.model.body(f"actor{k}_pelvis").id for k in range(2)]
    half_height = [world.actors[k].parts[11].size[2] for k in range(2)]
    positions = []
    for frame in range(150):
        sim.advance_to(frame / 30.0)
        positions.append(sim.data.xpos.copy())
    xpos = np.array(positions)
    for k in range(2):
        body_speed = np.linalg.norm(np.diff(xpos[:, pelvis[k], :2], axis=0), axis=1).mean() * 30
        assert body_speed == pytest.approx(world.spec.actors[k].speed_mps, rel=0.05)
        for foot in feet[k]:
            bottom = xpos[:, foot, 2] - half_height[k]
            contact = (bottom[:-1] < 1e-3) & (bottom[1:] < 1e-3)
            speed = np.linalg.norm(np.diff(xpos[:, foot], axis=0), axis=1) * 30
            assert contact.mean() > 0.4  # a real stance phase exists
            assert speed[contact].max() < 0.05 * body_speed


def test_pushed_chair_moves_untouched_chair_stays():
    spec = ScenarioSpec(
        frames=1,
        actors=(ActorSpec("chair_pusher", speed_mps=0.9),),
        chairs=(ChairSpec((1.0, 0.5), 0.0), ChairSpec((-2.5, 2.8), 30.0)),
    )
    world = build_world(spec)
    sim = Simulation(world)
    start = sim.data.xpos[world.chair_bodies].copy()
    for frame in range(1, 120):
        sim.advance_to(frame / 30.0)
    moved = np.linalg.norm(sim.data.xpos[world.chair_bodies] - start, axis=1)
    assert moved[0] > 0.05
    assert moved[1] < 1e-3


def test_a_paths_single_points_and_tangents_are_numpys_to_the_bit():
    """Path.point and Path.tangent take a fast path for one arc length (Python floats with
    np.interp's arithmetic): over seeded loops, at arc lengths wrapped both ways, on the
    samples themselves and at the seam, they give the array path's bits."""
    from depotbench.sim.paths import Path as Loop

    rng = np.random.default_rng(7)
    for _ in range(6):
        loop = Loop(rng.uniform(-4, 4, size=(int(rng.integers(2, 8)), 2)))
        length = loop.length
        edges = [length, -length, 1e-300, -1e-300]
        arcs = np.concatenate([rng.uniform(-3 * length, 3 * length, 3000), loop._arc, -loop._arc, edges])
        points, tangents = loop.point(arcs), loop.tangent(arcs)
        for k, s in enumerate(arcs.tolist()):
            assert loop.point(s).tobytes() == points[k].tobytes(), s
            assert loop.tangent(s).tobytes() == tangents[k].tobytes(), s
            assert loop.point(np.float64(s)).tobytes() == points[k].tobytes(), s


def _tiny_spec(path: Path, **fields) -> Path:
    """A 96x72 scenario file with flow and the Kinect sensor model, for determinism tests."""
    base = {"name": path.stem, "image": {"width": 96, "height": 72}, "intrinsics": {"fx": 78.75}}
    path.write_text(json.dumps(base | {"flow": True, "sensor": "kinect"} | fields))
    return path


def test_same_spec_and_seed_same_bytes_in_two_processes(tmp_path: Path):
    """Two processes that differ in what must not matter: the string hash seed (set and
    dict layouts, memory), and llvmpipe rasterising in threads or, as suite workers do,
    in the calling thread. A failure names each differing file and how it differs."""
    spec = _tiny_spec(
        tmp_path / "tiny.yaml",
        seed=7,
        frames=3,
        actors=[{"kind": "person"}, {"kind": "cat", "speed_mps": 0.6}],
        chairs=[{"position_m": [1.0, 0.5]}],
        camera={"motion": "halfsphere"},
    )
    outs = []
    for name, env in (("a", {"PYTHONHASHSEED": "1"}), ("b", {"PYTHONHASHSEED": "2", "LP_NUM_THREADS": "0"})):
        out = tmp_path / name
        environ = {k: v for k, v in os.environ.items() if k != "LP_NUM_THREADS"} | env
        result = subprocess.run(
            [sys.executable, "-m", "depotbench.eval.cli", "generate", str(spec), "-o", str(out)],
            cwd=REPO,
            capture_output=True,
            text=True,
            env=environ,
        )
        assert result.returncode == 0, result.stderr
        outs.append(out)
    assert len(list(outs[0].rglob("*.png"))) > 10
    differences = tree_differences(*outs, skip=("meta.json",))
    assert not differences, "\n".join(differences)
    meta = [json.loads((o / "meta.json").read_text()) for o in outs]
    assert meta[0] == meta[1]


def test_product_is_matmul_summed_in_one_order():
    """depotbench.sim.products.product: numpy's ``@`` to rounding for every shape the generator
    multiplies (matrices, points, batches, row and column vectors), and to the bit the
    sum of Python floats taken in order, whatever the CPU."""
    from depotbench.sim.products import product, rigid_inverse

    rng = np.random.default_rng(3)
    shapes = [((3, 3), (3, 3)), ((3, 3), (3,)), ((500, 3), (3, 3)), ((500, 3), (3,)), ((3,), (3, 3))]
    shapes += [((7, 3, 3), (7, 3, 3)), ((4, 4), (6, 4, 4)), ((6, 4, 4), (4, 4)), ((3,), (3,))]
    for sa, sb in shapes:
        a, b = rng.normal(size=sa), rng.normal(size=sb)
        np.testing.assert_allclose(product(a, b), a @ b, rtol=1e-13, atol=1e-14)
    a, b = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    expected = [
        [(a[i, 0] * b[0, j] + a[i, 1] * b[1, j]) + a[i, 2] * b[2, j] for j in range(3)] for i in range(3)
    ]
    assert product(a, b).tolist() == [[float(v) for v in row] for row in expected]
    points = rng.normal(size=(40, 3))
    assert product(points, a).tolist() == [product(p, a).tolist() for p in points]
    with pytest.raises(ValueError, match="do not chain"):
        product(np.ones((3, 3)), np.ones(4))
    pose = look_at(np.array([1.0, -2.0, 1.5]), np.zeros(3))
    np.testing.assert_allclose(rigid_inverse(pose) @ pose, np.eye(4), atol=1e-14)


def _blas_kernels_differ() -> str | None:
    """Why the two-kernel test cannot run here, or None: OpenBLAS's Haswell kernels need
    AVX2 and FMA, and the test only means something where the two kernels round a
    product differently."""
    try:
        from numpy._core._multiarray_umath import __cpu_features__
    except ImportError:  # numpy 1.26
        from numpy.core._multiarray_umath import __cpu_features__

    if not (__cpu_features__.get("AVX2") and __cpu_features__.get("FMA3")):
        return "this CPU cannot run OpenBLAS's Haswell kernels"
    probe = (
        "import numpy as n; r = n.random.default_rng(0); "
        "print((r.random((50, 3)) @ r.random((3, 3))).tobytes().hex())"
    )
    outs = {
        subprocess.run(
            [sys.executable, "-c", probe],
            capture_output=True,
            text=True,
            env={**os.environ, "OPENBLAS_CORETYPE": core},
        ).stdout
        for core in ("Haswell", "Nehalem")
    }
    return None if len(outs) == 2 else "OpenBLAS gives the same product on both kernels here"


IPP_PROBE = """
import hashlib, numpy as np
from depotbench.sim import textures
from depotbench.sim.sensor import SensorModel
from depotbench.sim.spec import SensorSpec
h = hashlib.sha256()
for seed in range(4):
    rng = np.random.default_rng(seed)
    for draw in (textures.concrete, textures.wall, textures.crate, textures.cardboard, textures.wood):
        h.update(draw(rng).tobytes())
    for kind in ("dog", "cat", "pig"):
        h.update(textures.coat(rng, kind).tobytes())
rng = np.random.default_rng(9)
rgb = rng.integers(0, 256, (48, 64, 3)).astype(np.uint8)
flow = rng.normal(0, 3, (48, 64, 2)).astype(np.float32)
sensor = SensorModel(SensorSpec(motion_blur_exposure_s=0.02, rgb_noise_sigma=2.0), np.random.default_rng(1))
h.update(sensor.rgb(rgb, flow, 30.0).tobytes())
print(h.hexdigest())
"""


def test_textures_and_motion_blur_do_not_depend_on_intel_ipps_cpu_path():
    """OpenCV hands cubic and area resizes and remaps to Intel IPP, which picks its code
    by CPU and rounds differently on each: textures drawn on IPP's SSE 4.2 path differed
    from those on its AVX2 path (sim/ipp.py). Drawn on both, and with IPP off, they and
    the sensor model's motion blur are the same bytes."""
    digests = {
        path: subprocess.run(
            [sys.executable, "-c", IPP_PROBE],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
            env={**os.environ, "OPENCV_IPP": path},
        ).stdout
        for path in ("sse42", "disabled", "")
    }
    assert len(set(digests.values())) == 1, digests


@pytest.mark.slow  # 27 s; two processes give the same bytes in the default run
def test_same_spec_and_seed_same_bytes_on_two_blas_kernels(tmp_path: Path):
    """OpenBLAS picks its kernels by CPU type, and Haswell's fuse multiply and add where
    Nehalem's do not: poses, meshes and ground truth computed through ``@`` (and paths
    smoothed by np.convolve) differed in their last bits, so gt/objects.jsonl and now and
    then a pixel differed from one CPU type to another (sim/products.py). Every kind of
    actor, a pushed chair, flow, the depth sensor's model and a moving camera, generated
    on both kernels."""
    why_not = _blas_kernels_differ()
    if why_not:
        pytest.skip(why_not)
    spec = _tiny_spec(
        tmp_path / "kernels.yaml",
        seed=5,
        frames=4,
        actors=[
            {"kind": "person"},
            {"kind": "person", "path": "tum_walk"},
            {"kind": "chair_pusher", "speed_mps": 0.8},
            {"kind": "sitting_person", "path": "seated", "speed_mps": 0},
            {"kind": "dog", "speed_mps": 1.3},
            {"kind": "pig"},
            {"kind": "bird"},
        ],
        chairs=[{"position_m": [0.8, 0.2]}],
        camera={"motion": "xyz"},
    )
    runs = {
        core: subprocess.Popen(
            [
                sys.executable,
                "-m",
                "depotbench.eval.cli.main",
                "generate",
                str(spec),
                "-o",
                str(tmp_path / core),
            ],
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "OPENBLAS_CORETYPE": core},
        )
        for core in ("Haswell", "Nehalem")
    }
    for core, run in runs.items():
        _, err = run.communicate(timeout=300)
        assert run.returncode == 0, f"{core}: {err}"
    assert len(list((tmp_path / "Haswell").rglob("*.png"))) > 10
    differences = tree_differences(tmp_path / "Haswell", tmp_path / "Nehalem", skip=("meta.json",))
    assert not differences, "\n".join(differences)


@pytest.mark.parametrize("motion", ["static", "rpy", "robot"])
def test_camera_rigs_are_smooth(motion):
    world = build_world(ScenarioSpec(frames=1, camera=CameraSpec(motion=motion)))
    t = np.arange(0, 3, 1 / 30)
    positions = np.array([world.rig.world_from_camera(x)[:3, 3] for x in t])
    velocity = np.diff(positions, axis=0) * 30
    assert np.abs(np.diff(velocity, axis=0)).max() * 30 < 5.0  # bounded acceleration: no jumps


def test_the_robot_rig_ignores_position_and_target_as_validation_does(tmp_path: Path):
    """The robot drives its own loop, so validation does not check the camera's position
    and target for it; the rig must not use them either. Found by the fuzz test: a robot
    spec with position_m == target_m validated, then generate crashed in look_at."""
    from depotbench.eval.cli.main import main

    spec = tmp_path / "robot.yaml"
    camera = "{motion: robot, position_m: [0, 0, 0], target_m: [0, 0, 0]}"
    spec.write_text(f"name: r\nframes: 2\nimage: {{width: 48, height: 36}}\ncamera: {camera}\n")
    assert main(["validate", str(spec)]) == 0
    assert main(["generate", str(spec), "-o", str(tmp_path / "out")]) == 0
    default = CameraRig(CameraSpec(motion="robot"), np.random.default_rng(0))
    odd_spec = CameraSpec(motion="robot", position_m=(0, 0, 0), target_m=(0, 0, 0))
    odd = CameraRig(odd_spec, np.random.default_rng(0))
    for t in (0.0, 1.0, 2.5):
        np.testing.assert_array_equal(odd.world_from_camera(t), default.world_from_camera(t))


def test_orb_finds_well_spread_features_on_the_default_scenario(tmp_path: Path):
    from depotbench.sim.generate import generate

    out = generate(dataclasses.replace(default_scenario(), frames=30), tmp_path / "seq", progress=False)
    seq = Sequence.open(out)
    orb = cv2.ORB_create(nfeatures=1000)
    counts, densest = [], []
    for i in range(len(seq)):
        keypoints = orb.detect(cv2.cvtColor(seq.rgb(i), cv2.COLOR_RGB2GRAY), None)
        pts = np.array([k.pt for k in keypoints])
        counts.append(len(keypoints))
        cells = np.bincount((pts[:, 1] // 40).astype(int) * 16 + (pts[:, 0] // 40).astype(int))
        densest.append(cells.max() / len(keypoints))
    assert min(counts) >= 500
    # No 40 px cell (1/192 of the image) holds more than 6 % of a frame's features, in
    # any frame. (It was 5 % in 95 % of frames; a rack's upright-and-beam joint holds 5.2 %
    # in three frames since the seated person turned, 2026-11: a real corner, not a clump.)
    assert max(densest) <= 0.06


def test_missing_gl_gives_an_install_hint(tmp_path: Path):
    """A GL context that cannot be made is reported in one line with the package to install."""
    import os

    env = {**os.environ, "MUJOCO_GL": "egl", "MUJOCO_EGL_DEVICE_ID": "99"}
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "depotbench.eval.cli.main",
            "generate",
            "default",
            "-o",
            str(tmp_path / "out"),
            "--frames",
            "1",
        ],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2
    assert "apt-get install libegl1 libgl1-mesa-dri" in result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "out").exists() and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("kind", "speed"), [("dog", 1.3), ("cat", 0.5), ("pig", 0.7)])
def test_quadrupeds_plant_their_paws(kind, speed):
    spec = ScenarioSpec(frames=1, actors=(ActorSpec(kind, speed_mps=speed),))
    world = build_world(spec)
    actor = world.actors[0]
    t = np.arange(0, 4, 1 / 30)  # the frame rate, as for people
    poses = np.array([actor.pose(x)[0] for x in t])
    lower = [i for i, p in enumerate(actor.parts) if p.name.startswith("lower_leg")]
    body_speed = np.linalg.norm(np.diff(poses[:, 0, :2], axis=0), axis=1).mean() * 30
    assert body_speed == pytest.approx(speed, rel=0.05)
    for i in lower:
        # The paw is the shin capsule's lower end: its centre minus half its length along its axis.
        rotations = np.array([actor.pose(x)[1][i] for x in t])
        paw = poses[:, i] - rotations[:, :, 2] * actor.parts[i].size[1]
        height = paw[:, 2] - actor.paw_r
        contact = (height[:-1] < 1e-3) & (height[1:] < 1e-3)
        speed_paw = np.linalg.norm(np.diff(paw, axis=0), axis=1) * 30
        assert contact.mean() > 0.3
        assert speed_paw[contact].max() < 0.05 * body_speed


def test_bird_hops_and_flies():
    world = build_world(ScenarioSpec(frames=900, seed=3, actors=(ActorSpec("bird"),)))
    bird = world.actors[0]
    heights = np.array([bird.root(x)[0][2] for x in np.arange(0, 30, 1 / 30)]) - 0.1
    assert heights.min() == pytest.approx(0.0, abs=1e-9)  # it stands on the floor between hops
    assert (heights > 0.3).any()  # and it flies
    assert ((heights > 0.005) & (heights < 0.06)).any()  # and it hops


def test_people_carry_orb_features_like_the_background(tmp_path: Path):
    """Clothes, hair and skin give ORB corners: on TUM's walking sequences ORB-SLAM2 fails
    because people carry features; featureless people would make rejection moot. Keypoint
    density (per pixel) on people must be at least 0.25x that on the static world (measured
    on walking_static, perfect sensor: 0.49 with 0.7's walkers 1-2 m away; 0.29 median,
    0.21-0.51, with 0.8's TUM walkers, who come to 1-1.35 m, where their clothes' texture is
    magnified; the earlier smooth clothing gave 0.13)."""
    from depotbench.core.camera import Intrinsics
    from depotbench.scenes import library
    from depotbench.scenes.schema import Sensor, to_scenario
    from depotbench.sim.generate import generate
    from depotbench.slam.config import TrackingConfig
    from depotbench.slam.features import FeatureExtractor

    # The perfect sensor: the property is the figures' textures', not the sensor's noise.
    update = {"frames": 40, "duration_s": None, "sensor": Sensor()}
    scenario = library.get("walking_static").model_copy(update=update)
    seq = Sequence.open(generate(to_scenario(scenario), tmp_path / "seq", progress=False))
    extractor = FeatureExtractor(TrackingConfig())
    k = seq.intrinsics
    camera = Intrinsics(k.fx, k.fy, k.cx, k.cy, k.width, k.height)
    objects = seq.objects()
    ratios = []
    for i in range(0, len(seq), 2):  # TUM's walkers are out of view for part of the time
        person_ids = [o.instance_id for o in objects[i] if o.class_name == "person"]
        people = np.isin(seq.instances(i), person_ids)
        if people.mean() < 0.05:
            continue
        uv = np.rint(extractor.extract(seq.rgb(i), seq.depth_m(i), camera).keypoints_px).astype(int)
        on = people[np.clip(uv[:, 1], 0, people.shape[0] - 1), np.clip(uv[:, 0], 0, people.shape[1] - 1)]
        ratios.append((on.mean() / people.mean()) / ((~on).mean() / (~people).mean()))
    assert len(ratios) >= 5
    assert np.median(ratios) >= 0.25, ratios


def _pixel_centres(low: float, high: float) -> int:
    """Pixel centres (integers, OpenCV convention) strictly between two image coordinates."""
    return max(0, min(int(np.floor(high)), 10**6) - int(np.ceil(low)) + 1)


Box = tuple[float, float, float, float, float]
"""(centre x, centre y, depth, half width, half height) of a flat box facing the camera,
which sits at the origin and looks along -z."""


@pytest.mark.parametrize("offsamples", [0, 4])
def test_reading_rgba_gives_mujocos_own_pixels_and_depth(offsamples):
    """FrameRenderer reads the offscreen buffer as RGBA (llvmpipe's RGB read is a slow
    path); it must give the pixels and depth mjr_readPixels gives, whole and in a window,
    and through MuJoCo's own reader where the buffer is multisampled."""
    from depotbench.sim.mujoco_env import mujoco
    from depotbench.sim.render import FrameRenderer

    spec = mujoco.MjSpec()
    spec.visual.quality.offsamples = offsamples
    spec.worldbody.add_camera(name="camera", pos=[0, 0, 0], fovy=60)
    spec.worldbody.add_light(pos=[0, 0, 1], dir=[0, 0, -1])
    spheres = [(-0.3, 0.1, 2.0, 0.4, [1, 0.2, 0.1, 1]), (0.2, -0.1, 3.0, 0.5, [0.1, 0.6, 1, 1])]
    for x, y, z, radius, rgba in spheres:
        sphere = mujoco.mjtGeom.mjGEOM_SPHERE
        spec.worldbody.add_geom(type=sphere, size=[radius, 0, 0], pos=[x, y, -z], rgba=rgba)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    width, height = 96, 64
    renderer = FrameRenderer(model, width, height, np.zeros(model.ngeom, np.uint16))
    try:
        renderer._colour_pass(data, model.camera("camera").id)
        for rect in [(0, 0, width, height), (13, 7, 41, 29)]:
            rgb = np.empty((rect[3], rect[2], 3), np.uint8)
            depth = np.empty((rect[3], rect[2]), np.float32)
            mujoco.mjr_readPixels(rgb, depth, mujoco.MjrRect(*rect), renderer._context)
            rgba = np.empty((rect[3], rect[2], 4), np.uint8)
            ours = np.empty_like(depth)
            renderer._read(rect, rgba, ours)
            assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 2  # spheres and background
            np.testing.assert_array_equal(rgba[:, :, :3], rgb)
            np.testing.assert_array_equal(ours, depth)
    finally:
        renderer.close()


def _render_facing_boxes(
    boxes: dict[int, Box], width: int, height: int, fovy: float, walls: tuple[Box, ...] = ()
) -> tuple[np.ndarray, dict[int, tuple[int, bool]], list[int]]:
    """Render instance boxes (and static ``walls``): per-instance visible pixels and
    unoccluded areas, and how many instances each unoccluded pass draws. The areas the
    frame gives (read from its instance pass where no other window overlaps) must be
    the bit passes' for every instance seen."""
    from depotbench.sim.mujoco_env import mujoco
    from depotbench.sim.render import FrameRenderer, _bit_passes

    spec = mujoco.MjSpec()
    spec.visual.quality.offsamples = 0  # as the bench's worlds: no multisampling, exact pixels
    spec.worldbody.add_camera(name="camera", pos=[0, 0, 0], fovy=fovy)
    for instance, (x, y, z, hx, hy) in boxes.items():
        body = spec.worldbody.add_body(name=f"box{instance}", pos=[x, y, -z])
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[hx, hy, 0.01])
    for x, y, z, hx, hy in walls:
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, pos=[x, y, -z], size=[hx, hy, 0.01])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    body_instance = np.zeros(model.nbody, np.uint16)
    for instance in boxes:
        body_instance[model.body(f"box{instance}").id] = instance
    renderer = FrameRenderer(model, width, height, body_instance[model.geom_bodyid])
    camera = model.camera("camera").id
    try:
        frame = renderer.render(data, camera)
        projected = renderer._projected_boxes(data, camera, list(boxes))
        windows = {i: renderer._window(box) for i, box in zip(boxes, projected, strict=True)}
        unoccluded = renderer.unoccluded(data, camera, list(boxes))
    finally:
        renderer.close()
    geom_ids = frame.geom_ids
    visible = np.bincount(
        np.where(geom_ids >= 0, body_instance[model.geom_bodyid][geom_ids], 0).ravel(),
        minlength=len(boxes) + 1,
    )
    assert frame.unoccluded == {i: unoccluded[i] for i in boxes if visible[i] > 0}
    return visible, unoccluded, [len(bits) for bits in _bit_passes(list(boxes), windows)]


def _projected_rectangle(box: Box, width: int, height: int, fovy: float) -> tuple[int, bool]:
    """Closed form: the pixels a box's front face covers (cut at the image edge), and
    whether the image edge cuts it."""
    x, y, z, hx, hy = box
    focal = (height / 2) / np.tan(np.radians(fovy) / 2)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    z_front = z - 0.01
    u0, u1 = cx + focal * (x - hx) / z_front, cx + focal * (x + hx) / z_front
    v0, v1 = cy - focal * (y + hy) / z_front, cy - focal * (y - hy) / z_front
    cols = _pixel_centres(max(u0, -0.5), min(u1, width - 0.5))
    rows = _pixel_centres(max(v0, -0.5), min(v1, height - 0.5))
    return cols * rows, bool(u0 < 0 or v0 < 0 or u1 > width - 1 or v1 > height - 1)


def test_unoccluded_area_and_truncation_match_the_projected_rectangles():
    """Closed form: flat boxes facing the camera cover the pixel centres inside their projected
    rectangles. Box 1 is half behind a static wall and partly behind box 2; box 3 crosses the
    image's right edge. The unoccluded areas are the whole rectangles (cut at the image edge)."""
    width, height, fovy = 64, 48, 60.0
    boxes = {
        1: (0.1, 0.05, 3.0, 0.6, 0.45),
        2: (0.62, -0.1, 2.5, 0.2, 0.2),
        3: (2.0, 0.2, 3.0, 0.4, 0.3),
    }
    wall = (-0.5, 0.0, 2.0, 0.3, 1.0)
    visible, unoccluded, _ = _render_facing_boxes(boxes, width, height, fovy, walls=(wall,))
    for instance, box in boxes.items():
        assert unoccluded[instance] == _projected_rectangle(box, width, height, fovy), instance
    assert [unoccluded[i][1] for i in (1, 2, 3)] == [False, False, True]
    assert visible[1] < unoccluded[1][0]  # behind the wall and box 2
    assert visible[2] == unoccluded[2][0] and visible[3] == unoccluded[3][0]


def test_unoccluded_areas_of_more_overlapping_instances_than_one_pass_has_bits():
    """Closed form, 30 boxes facing the camera, each overlapping the next in the image and
    partly hidden by it: more instances with overlapping windows than one pass's 24 bits,
    so a second pass runs. Each unoccluded area is its whole projected rectangle."""
    from depotbench.sim.render import BITS

    width, height, fovy, n = 96, 72, 60.0, 30
    # all overlap; nearer ones further right
    boxes = {k + 1: (-0.3 + 0.02 * k, 0.03 * (k % 5), 4.0 - 0.05 * k, 0.3, 0.25) for k in range(n)}
    visible, unoccluded, passes = _render_facing_boxes(boxes, width, height, fovy)
    assert passes == [BITS, n - BITS]
    hidden = 0
    for instance, box in boxes.items():
        expected = _projected_rectangle(box, width, height, fovy)
        assert unoccluded[instance] == expected, instance
        hidden += visible[instance] < expected[0]
    assert hidden > n // 2  # most are partly behind the next one


def test_bit_passes_give_overlapping_windows_different_bits():
    """Windows apart may share a bit; overlapping ones never do; past 24, a new pass."""
    from depotbench.sim.render import BITS, _bit_passes, _overlap

    rng = np.random.default_rng(5)
    corners = rng.integers(0, 400, size=(80, 2))
    sizes = rng.integers(5, 120, size=(80, 2))
    windows = {i + 1: (*corners[i].tolist(), *(corners[i] + sizes[i]).tolist()) for i in range(80)}
    passes = _bit_passes(list(windows), windows)
    assert sorted(i for bits in passes for i in bits) == list(windows)
    for bits in passes:
        assert set(bits.values()) <= set(range(BITS))
        for a in bits:
            for b in bits:
                if a != b and _overlap(windows[a], windows[b]):
                    assert bits[a] != bits[b], (a, b)
    stacked = {i: (0, 0, 10, 10) for i in range(1, 31)}  # all on one another
    assert [len(bits) for bits in _bit_passes(list(stacked), stacked)] == [BITS, 30 - BITS]
    apart = {i: (0, 20 * i, 10, 20 * i + 10) for i in range(1, 31)}
    assert _bit_passes(list(apart), apart) == [dict.fromkeys(apart, 0)]


def test_unoccluded_area_of_a_scene_matches_drawing_each_instance_alone():
    """Brute force: draw every visible instance of the default scene entirely alone over the
    whole image, one per pass, with the depth test; the OR-ed bit passes (every instance at
    once, no depth buffer) and the frame's areas (the instance pass's, where no other
    instance's window overlaps) must give the same areas and border flags."""
    from depotbench.sim.render import SOLO_GROUP, FrameRenderer

    world = build_world(default_scenario(frames=12, seed=2))
    geom_instance = world.body_instance[world.model.geom_bodyid]
    renderer = FrameRenderer(world.model, 320, 240, geom_instance)
    sim = Simulation(world)
    groups = world.model.geom_group
    try:
        for k in range(0, 12, 3):
            sim.advance_to(k / 30)
            frame = renderer.render(sim.data, world.camera_id)
            seen = [int(i) for i in np.unique(frame.instances) if i > 0]
            assert list(frame.unoccluded) == seen
            batched = renderer.unoccluded(sim.data, world.camera_id, seen)
            for instance in seen:
                owned = (geom_instance == instance) & (groups < 5)
                before = groups[owned].copy()
                groups[owned] = SOLO_GROUP
                renderer._update_scene(sim.data, world.camera_id, renderer._solo)
                groups[owned] = before
                mask = renderer._segment() >= 0
                border = bool(mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
                alone = (int(mask.sum()), border)
                assert batched[instance] == frame.unoccluded[instance] == alone, (k, instance)
            assert len(seen) > 5
    finally:
        renderer.close()


@pytest.mark.parametrize(
    ("scene", "seed"),
    [(None, 0), pytest.param("crowd", 1, marks=pytest.mark.slow), ("dog_and_cat_roaming", 2)],  # crowd: 22 s
)
def test_instance_pass_shows_what_a_segmentation_pass_of_the_whole_scene_shows(scene, seed):
    """MuJoCo's own segmentation of the whole scene (the world drawn too, with the depth
    test) is the reference: the instance pass, whose pixels count where its depth equals
    the colour pass's, must give each pixel the same instance geom, bit for bit."""
    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.render import FrameRenderer

    changes = {"frames": 12, "duration_s": None, "seed": seed}
    spec = (
        default_scenario(frames=12, seed=seed)
        if scene is None
        else to_scenario(library.get(scene).model_copy(update=changes))
    )
    world = build_world(spec)
    geom_instance = world.body_instance[world.model.geom_bodyid]
    renderer = FrameRenderer(world.model, 320, 240, geom_instance)
    sim = Simulation(world)
    shown = 0
    try:
        for t in (0.2, 1.0, 1.9, 2.7):
            sim.advance_to(t)
            frame = renderer.render(sim.data, world.camera_id)
            renderer._update_scene(sim.data, world.camera_id, renderer._option)
            whole = np.flipud(renderer._segment())
            reference = np.where(geom_instance[whole] > 0, whole, -1)
            np.testing.assert_array_equal(frame.geom_ids, reference, err_msg=f"t={t}")
            shown += int((reference >= 0).sum())
    finally:
        renderer.close()
    assert shown > 20000


def test_leaving_out_geoms_outside_the_view_changes_no_pixel():
    """Culling by bounding spheres leaves out many geoms yet gives the same RGB, depth, geom
    ids and unoccluded areas, bit for bit, along the default scenario's path."""
    from depotbench.sim.render import FrameRenderer

    world = build_world(default_scenario(frames=12, seed=1))
    geom_instance = world.body_instance[world.model.geom_bodyid]
    culled = FrameRenderer(world.model, 320, 240, geom_instance)
    whole = FrameRenderer(world.model, 320, 240, geom_instance, cull=False)
    sim = Simulation(world)
    left_out = []
    try:
        for k in range(0, 12, 4):
            sim.advance_to(k / 10)
            a = culled.render(sim.data, world.camera_id)
            left_out.append(int(culled._outside_view(sim.data, world.camera_id).sum()))
            b = whole.render(sim.data, world.camera_id)
            for field in ("rgb", "depth", "geom_ids", "instances"):
                x, y = getattr(a, field), getattr(b, field)
                assert x.dtype == y.dtype and np.array_equal(x.view(np.uint8), y.view(np.uint8)), k
            assert a.unoccluded == b.unoccluded, k
            seen = list(a.unoccluded)
            assert culled.unoccluded(sim.data, world.camera_id, seen) == whole.unoccluded(
                sim.data, world.camera_id, seen
            ), k
    finally:
        culled.close()
        whole.close()
    assert min(left_out) > world.model.ngeom // 10, left_out


def test_rgb_matches_mujocos_own_renderer_but_for_texture_filtering():
    """FrameRenderer samples textures bilinearly from one mip level where MuJoCo's Renderer
    blends two (trilinear): faster on llvmpipe, and the images agree to within a grey level
    on average, and geometry, lighting and colours are the same. MuJoCo's is shown the
    pieces ours draws: far versions beyond FAR_M, the full ones nearer."""
    from depotbench.sim.mujoco_env import mujoco
    from depotbench.sim.render import HIDDEN_GROUP, FrameRenderer

    world = build_world(default_scenario(frames=12, seed=1))
    ours = FrameRenderer(world.model, 320, 240, world.body_instance[world.model.geom_bodyid])
    reference = mujoco.Renderer(world.model, 240, 320)
    sim = Simulation(world)
    try:
        for t in (0.0, 0.5, 1.1):
            sim.advance_to(t)
            rgb = ours.render(sim.data, world.camera_id).rgb
            far = ours._far_from(sim.data, world.camera_id)
            left_out = np.concatenate([ours._near_version[far], ours._far_version[~far]])
            assert far.any() and (~far).any(), t
            groups = world.model.geom_group.copy()
            world.model.geom_group[left_out] = HIDDEN_GROUP
            reference.update_scene(sim.data, world.camera_id)
            world.model.geom_group[:] = groups
            difference = np.abs(reference.render().astype(int) - rgb)
            assert difference.mean() < 1.0, t
            assert np.percentile(difference, 99) <= 8, t
    finally:
        ours.close()
        reference.close()
