"""SLAM on generated sequences: accuracy, determinism, degenerate input, rejection."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from depotbench.detectors.detection import Detection, Prior
from depotbench.eval.cli.main import main
from depotbench.eval.metrics.accuracy import improvement_rate
from depotbench.eval.run.harness import camera_of, run_sequence
from depotbench.scenes import library
from depotbench.scenes.schema import to_scenario
from depotbench.sim.sequence import Sequence
from depotbench.slam.config import RejectionConfig, SlamConfig, TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.rejection import STRATEGIES, classify, flow_to_previous, track_to_previous
from depotbench.slam.system import Slam
from depotbench.slam.types import REJECTION_CODES, Frame, Rejection, TrackingState

pytestmark = pytest.mark.render


def _generate(tmp_path_factory, name: str, frames: int) -> Path:
    from depotbench.sim.generate import generate

    scenario = library.get(name).model_copy(update={"frames": frames, "duration_s": None})
    return generate(to_scenario(scenario), tmp_path_factory.mktemp(name) / name, progress=False)


@pytest.fixture(scope="module")
def static_seq(tmp_path_factory) -> Path:
    return _generate(tmp_path_factory, "static_depot", 90)


@pytest.fixture(scope="module")
def crowd_seq(tmp_path_factory) -> Path:
    return _generate(tmp_path_factory, "crowd", 90)


STATIC_ATE_M = 0.0063
"""What the built-in may drift on ``static_seq``: 1.5x the worst of three ORB-SLAM3 runs on the
same 90 frames (3.5, 4.1, 4.2 mm; the ratio issue 40 allows), the built-in 5.4 mm at 0.5.2."""


def test_static_scene_is_tracked_to_millimetres(static_seq: Path, tmp_path: Path):
    metrics = run_sequence(static_seq, tmp_path / "run", "none", progress=False)
    assert metrics["lost_frames"] == 0 and metrics["tracked_frames"] == 90
    assert metrics["ate_m"]["rmse"] <= STATIC_ATE_M
    assert (tmp_path / "run" / "trajectory.txt").is_file()
    diagnostics = np.load(tmp_path / "run" / "diagnostics.npz")
    assert diagnostics["keypoint_counts"].sum() == len(diagnostics["rejection"]) == len(diagnostics["inlier"])
    assert diagnostics["inlier"].mean() > 0.3


@pytest.mark.slow  # 30 s; test_benchmark.py runs the built-in tracker twice on smoke-1 and compares the bytes
def test_same_input_same_trajectory(static_seq: Path, tmp_path: Path):
    for name in ("a", "b"):
        run_sequence(static_seq, tmp_path / name, "box_epipolar_flow", progress=False)
    assert (tmp_path / "a" / "trajectory.txt").read_bytes() == (
        tmp_path / "b" / "trajectory.txt"
    ).read_bytes()


def _run_every_strategy(sequence: Path, out: Path, max_lost: int = 0) -> dict[str, dict]:
    """Metrics of each strategy (true boxes); each run may lose at most ``max_lost`` frames,
    and every frame is either tracked or reported lost."""
    runs = {s: run_sequence(sequence, out / s, s, progress=False) for s in STRATEGIES}
    frames = len(Sequence.open(sequence))
    for strategy, metrics in runs.items():
        assert metrics["lost_frames"] <= max_lost, (strategy, metrics["lost_frames"])
        assert metrics["lost_frames"] + metrics["tracked_frames"] == frames, strategy
    return runs


@pytest.mark.slow  # 55 s with its sequence; walking_static covers the same claim in the default run
def test_crowd_degrades_the_baseline_and_every_strategy_improves_on_it(crowd_seq: Path, tmp_path: Path):
    """Twelve people fill most of the image. The baseline tracks them and drifts; the
    strategies reject them and keep too few points on some frames, which they report as
    lost: at most a fifth of the frames here. At 0.5.3 on the default seed (35), 90 frames:
    box_rule and box_epipolar_flow lose none, prior_flow 16 (15 at 0.5.2); ATE 0.44 m for
    none against 0.16, 0.12 and 0.28 m. Other seeds are harder: on seeds 1 and 3 the
    strategies lose 34-60 of 90 frames, and prior_flow drifts further than none on seed 1
    (1.64 against 0.96 m); seed 2 loses none."""
    runs = _run_every_strategy(crowd_seq, tmp_path, max_lost=18)
    ate = {s: m["ate_m"]["rmse"] for s, m in runs.items()}
    for strategy in STRATEGIES[1:]:
        assert runs[strategy]["rejection"]["recall"] > 0.9
    assert ate["none"] > 0.1  # people fill most of the image: the ORB-SLAM2 stand-in drifts
    for strategy in STRATEGIES[1:]:
        assert improvement_rate(ate["none"], ate[strategy]) > 25.0, (strategy, ate)


@pytest.fixture(scope="module")
def walking_seq(tmp_path_factory) -> Path:
    # 60 frames (2 s) hold the claim at a tenth of the cost of 150 (265 s at TUM's 640x480):
    # none 18 mm against 2.8-3.2 mm for the strategies at 0.8.0.
    return _generate(tmp_path_factory, "walking_static", 60)


def test_walkers_degrade_the_baseline_and_the_strategies_reject_them(walking_seq: Path, tmp_path: Path):
    """TUM fr3/walking_static in the depot: two people 1-2 m from a still camera. ORB-SLAM2
    maps and tracks their features; the flow strategies remove them. The box rule
    (method 2) rejects most of them but, by design, keeps keypoints that also lie in a
    potential object's box: the walkers cross in front of the desk, and what it keeps of
    them is enough to drag the trajectory (measured 0.54 -> 0.50 m with the bodies of
    issue 14), so for it only the rejection itself is asserted."""
    runs = _run_every_strategy(walking_seq, tmp_path)
    ate = {s: m["ate_m"]["rmse"] for s, m in runs.items()}
    for strategy in ("prior_flow", "box_epipolar_flow"):
        assert ate["none"] > 3 * ate[strategy], (strategy, ate)
        assert improvement_rate(ate["none"], ate[strategy]) > 50.0, (strategy, ate)
    box_rule = runs["box_rule"]["rejection"]
    assert (
        box_rule["recall"] > 0.6 and box_rule["moving_inliers"] < runs["none"]["rejection"]["moving_inliers"]
    )


def _frames(seq: Sequence, n: int) -> list[Frame]:
    camera = camera_of(seq)
    return [Frame(seq.frames[i].timestamp_s, seq.rgb(i), seq.depth_m(i), camera) for i in range(n)]


def test_degenerate_input_reports_a_state_and_never_crashes(static_seq: Path):
    seq = Sequence.open(static_seq)
    frames = _frames(seq, 6)
    camera = frames[0].camera
    slam = Slam(SlamConfig(strategy="prior_flow"), camera)
    states = [slam.process(f).state for f in frames[:3]]
    assert states == [TrackingState.OK] * 3
    same = slam.process(Frame(frames[2].timestamp_s + 0.033, frames[2].rgb, frames[2].depth_m, camera))
    assert same.state == TrackingState.OK  # a frame identical to the last
    black = Frame(4.0, np.zeros_like(frames[0].rgb), frames[3].depth_m, camera)
    result = slam.process(black)
    assert result.state == TrackingState.LOST and result.world_from_camera is None
    everywhere = (
        Detection((0.0, 0.0, float(camera.width), float(camera.height)), "person", Prior.DYNAMIC, 1.0),
    )
    rejected = slam.process(Frame(4.1, frames[4].rgb, frames[4].depth_m, camera, everywhere))
    assert rejected.state == TrackingState.LOST
    assert (rejected.diagnostics.rejection == REJECTION_CODES[Rejection.DYNAMIC_BOX]).all()
    back = slam.process(Frame(4.2, frames[5].rgb, frames[5].depth_m, camera))
    assert back.state == TrackingState.RELOCALIZED  # relocalised against the keyframes
    fresh = Slam(SlamConfig(), camera)
    no_depth = fresh.process(Frame(0.0, frames[0].rgb, np.zeros_like(frames[0].depth_m), camera))
    assert no_depth.state == TrackingState.NOT_INITIALIZED and no_depth.world_from_camera is None


def test_runs_unchanged_on_a_plain_tum_folder(static_seq: Path, tmp_path: Path, capsys):
    """A folder with only what TUM publishes: no meta.json, camera.yaml, associations or gt/."""
    tum = tmp_path / "my_recording"
    tum.mkdir()
    for name in ("rgb", "depth"):
        shutil.copytree(static_seq / name, tum / name)
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        shutil.copy(static_seq / name, tum / name)
    assert (
        main(["run", str(tum), "--strategy", "none", "--detector", "none", "-o", str(tmp_path / "out")]) == 0
    )
    out = capsys.readouterr().out
    assert "tracked 90/90" in out and "ATE rmse" in out
    assert main(["run", str(tum), "--detector", "groundtruth", "-o", str(tmp_path / "o2")]) == 2
    assert "needs a generated sequence" in capsys.readouterr().err


# -- rejection rules on constructed cases --------------------------------------------------


def _features(grey: np.ndarray, points: np.ndarray) -> FrameFeatures:
    n = len(points)
    return FrameFeatures(
        grey,
        points.astype(np.float32),
        points.astype(np.float64),
        np.zeros(n, int),
        np.zeros((n, 32), np.uint8),
        np.ones(n),
        np.zeros(n),
    )


def _textured(rng: np.random.Generator, shape=(240, 320)) -> np.ndarray:
    return cv2.GaussianBlur(rng.integers(0, 255, shape).astype(np.uint8), (5, 5), 1.5)


def test_box_rule_keeps_points_also_inside_a_static_box():
    grey = np.zeros((100, 100), np.uint8)
    points = np.array([[10, 10], [30, 30], [60, 60], [90, 90]], float)
    detections = (
        Detection((0, 0, 50, 50), "person", Prior.DYNAMIC, 0.9),
        Detection((25, 25, 70, 70), "chair", Prior.POTENTIAL, 0.9),
        Detection((80, 80, 100, 100), "dog", Prior.DYNAMIC, 0.3),
    )  # below min_confidence
    codes = classify("box_rule", _features(grey, points), None, detections, RejectionConfig())
    kept, box = REJECTION_CODES[Rejection.KEPT], REJECTION_CODES[Rejection.DYNAMIC_BOX]
    assert codes.tolist() == [box, kept, kept, kept]


def test_prior_flow_flags_only_the_potential_points_that_move():
    rng = np.random.default_rng(0)
    previous = _textured(rng)
    current = np.roll(previous, 3, axis=1)  # the camera pans: everything flows 3 px right
    current[150:200, 200:260] = np.roll(previous, 12, axis=1)[150:200, 200:260]  # a chair slides on
    points = np.array([[50, 50], [100, 120], [230, 175], [160, 60], [60, 200]], float)
    detections = (
        Detection((190, 140, 270, 210), "chair", Prior.POTENTIAL, 1.0),
        Detection((140, 40, 180, 80), "cup", Prior.POTENTIAL, 1.0),
        Detection((40, 180, 80, 220), "person", Prior.DYNAMIC, 1.0),
    )
    frames = (_features(current, points), _features(previous, points), detections, RejectionConfig(k=2.0))
    codes = classify("prior_flow", *frames)
    names = [list(REJECTION_CODES)[c] for c in codes]
    assert names == [
        Rejection.KEPT,
        Rejection.KEPT,
        Rejection.MOVING_FLOW,
        Rejection.KEPT,
        Rejection.DYNAMIC_BOX,
    ]
    # Without the flow stage LK runs on the points outside person boxes alone; with it (every
    # keypoint's flow, as a sweep caches it) the decisions are the same.
    stage = flow_to_previous(frames[1], frames[0], frames[3])
    assert classify("prior_flow", *frames, flow=stage).tolist() == codes.tolist()


def test_lk_flow_of_a_subset_is_the_subsets_rows_of_the_flow_of_all():
    """LK tracks each point on its own: the rejection strategies run it on the points they read."""
    rng = np.random.default_rng(5)
    previous = _textured(rng)
    current = np.roll(previous, (2, 5), axis=(0, 1))
    points = rng.uniform([10, 10], [310, 230], (300, 2)).astype(np.float32)
    every = track_to_previous(
        _features(previous, points), _features(current, points), points, RejectionConfig()
    )
    subset = np.flatnonzero(rng.uniform(size=300) < 0.6)
    some = track_to_previous(
        _features(previous, points), _features(current, points), points[subset], RejectionConfig()
    )
    np.testing.assert_array_equal(some[0], every[0][subset])
    np.testing.assert_array_equal(some[1], every[1][subset])


def test_epipolar_rule_flags_points_off_their_epipolar_line():
    rng = np.random.default_rng(1)
    previous = _textured(rng)
    current = np.roll(previous, 4, axis=1)  # pure horizontal translation: epipolar lines are horizontal
    current[100:140, 100:140] = np.roll(previous, 9, axis=0)[100:140, 100:140]  # a patch moves down
    grid = np.stack(np.meshgrid(np.arange(30, 300, 30), np.arange(30, 220, 30)), axis=-1).reshape(-1, 2)
    points = np.r_[grid.astype(float), [[120.0, 120.0]]]
    codes = classify(
        "box_epipolar_flow", _features(current, points), _features(previous, points), (), RejectionConfig()
    )
    assert codes[-1] != REJECTION_CODES[Rejection.KEPT]
    assert (codes[:-1] == REJECTION_CODES[Rejection.KEPT]).mean() > 0.8


def test_pose_jacobian_matches_finite_differences():
    from depotbench.core.camera import Intrinsics
    from depotbench.slam.geometry import exp_se3
    from depotbench.slam.optimize import _pose_jacobian, _residuals

    camera = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480)
    rng = np.random.default_rng(0)
    points = rng.normal(0, 1, (6, 3)) + [0, 0, 4]
    uv = rng.normal(300, 50, (6, 2))
    ur = uv[:, 0] - 10.0
    ur[1] = np.nan  # an observation without depth
    weight = np.ones(6)
    analytic = _pose_jacobian(points, camera, 40.0, np.isfinite(ur))
    numeric = np.zeros_like(analytic)
    for k in range(6):
        step = np.zeros(6)
        step[k] = 1e-6
        plus, minus = exp_se3(step), exp_se3(-step)
        r_plus = _residuals(points @ plus[:3, :3].T + plus[:3, 3], uv, ur, weight, camera, 40.0)
        r_minus = _residuals(points @ minus[:3, :3].T + minus[:3, 3], uv, ur, weight, camera, 40.0)
        numeric[:, :, k] = (r_plus - r_minus) / 2e-6
    np.testing.assert_allclose(analytic, numeric, atol=1e-5 * np.abs(numeric).max())


def test_settings_are_named_typed_and_range_checked():
    from depotbench.slam.config import ConfigError, parse_setting

    config = SlamConfig(strategy="prior_flow").with_settings(
        {"k": 2.5, "lk_window_px": 11, "n_features": 800}
    )
    assert (
        config.rejection.k == 2.5
        and config.rejection.lk_window_px == 11
        and config.tracking.n_features == 800
    )
    with pytest.raises(ConfigError, match="k = -1.0 is out of range"):
        SlamConfig().with_settings({"k": -1})
    with pytest.raises(ConfigError, match="unknown setting 'kk'"):
        SlamConfig().with_settings({"kk": 1})
    # Text is parsed once, at the edge (--set), into the field's type.
    assert parse_setting("k", "2.5") == 2.5 and parse_setting("n_features", "800") == 800
    assert parse_setting("motion_model_ransac", "True") is True
    with pytest.raises(ConfigError, match="is not a number"):
        parse_setting("epsilon_px", "wide")
    with pytest.raises(ConfigError, match="motion_model_ransac='maybe' is not true or false"):
        parse_setting("motion_model_ransac", "maybe")
    with pytest.raises(ConfigError, match="unknown setting 'kk'"):
        parse_setting("kk", "1")
    # After the edge only values pass: text, a fraction for a whole number, a number for a switch are refused.
    with pytest.raises(ConfigError, match="give a value, not text"):
        SlamConfig().with_settings({"k": "2.5"})
    with pytest.raises(ConfigError, match="must be a whole number"):
        SlamConfig().with_settings({"n_features": 800.5})
    assert SlamConfig().with_settings({"n_features": 800.0}).tracking.n_features == 800
    with pytest.raises(ConfigError, match="is not true or false"):
        SlamConfig().with_settings({"motion_model_ransac": 1})


def test_rotation_consistency_keeps_the_dominant_angle_changes():
    from depotbench.slam.system import _consistent_rotation

    rng = np.random.default_rng(0)
    consistent = rng.normal(10.0, 2.0, 200)  # the image rotated by ~10 degrees
    wrong = rng.uniform(0, 360, 20)  # mismatches: any angle change
    keep = _consistent_rotation(np.r_[consistent, wrong])
    assert keep[:200].mean() > 0.95
    assert keep[200:].mean() < 0.3
    assert _consistent_rotation(np.array([359.0, 1.0, -1.0])).all()  # wraps around 0/360


def test_constant_velocity_chain_stays_a_rigid_motion():
    """Regression: the motion model's pose chain used to lose orthogonality by 1 + sqrt(2) per
    frame (``invert`` transposes), so tracking without per-frame RANSAC diverged at ~40 frames."""
    from depotbench.slam.geometry import constant_velocity, invert
    from scipy.spatial.transform import Rotation

    step = np.eye(4)
    step[:3, :3] = Rotation.from_rotvec([0.002, -0.01, 0.004]).as_matrix()
    step[:3, 3] = [0.01, 0.0, 0.003]
    previous = np.eye(4)
    current = step.copy()
    current[:3, :3] += 1e-13  # the rounding a few compositions leave behind
    naive_previous, naive_current = previous.copy(), current.copy()
    for frame in range(60):
        previous, current = current, current @ constant_velocity(previous, current)
        if frame < 30:
            naive_velocity = invert(naive_previous) @ naive_current
            naive_previous, naive_current = naive_current, naive_current @ naive_velocity
    assert np.abs(current[:3, :3].T @ current[:3, :3] - np.eye(3)).max() < 1e-9
    expected = np.linalg.matrix_power(step, 61)
    assert np.allclose(current, expected, atol=1e-6)
    # The uncorrected chain is what broke: after 30 frames its rotation is no longer one
    # (1e-13 * (1 + sqrt(2))^30 ~ 3e-2; by frame 60 it overflows).
    assert np.abs(naive_current[:3, :3].T @ naive_current[:3, :3] - np.eye(3)).max() > 1e-3


@pytest.mark.slow  # 9 s
def test_tracking_without_per_frame_ransac_matches_the_ransac_mode(static_seq: Path, tmp_path: Path):
    """ORB-SLAM2's motion-model tracking (no RANSAC unless it fails) stays on the static scene."""
    metrics = {
        mode: run_sequence(
            static_seq, tmp_path / str(mode), "none", settings={"motion_model_ransac": mode}, progress=False
        )
        for mode in (False, True)
    }
    for mode in metrics.values():
        assert mode["lost_frames"] == 0 and mode["ate_m"]["rmse"] <= STATIC_ATE_M


def _window(seed: int):
    """A keyframe window seen by a moving RGB-D camera: true and perturbed poses and points,
    observations with pixel noise by pyramid level, keypoints without depth and outliers."""
    from depotbench.core.camera import Intrinsics
    from depotbench.slam.bundle import BundleWindow
    from depotbench.slam.geometry import exp_se3, invert

    rng = np.random.default_rng(seed)
    camera, bf = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480), 40.0
    world_from_camera = [
        exp_se3(np.r_[rng.normal(0, 0.03, 3), 0.15 * k, rng.normal(0, 0.02, 2)]) for k in range(6)
    ]
    true_poses = np.array([invert(p) for p in world_from_camera])
    true_points = np.c_[rng.uniform(-2, 3, 300), rng.uniform(-1.5, 1.5, 300), rng.uniform(2, 6, 300)]
    obs_pose, obs_point, uv, ur, weight = [], [], [], [], []
    for j, point in enumerate(true_points):
        for k in rng.choice(6, size=rng.integers(2, 5), replace=False):
            pc = true_poses[k, :3, :3] @ point + true_poses[k, :3, 3]
            u, v = camera.fx * pc[0] / pc[2] + camera.cx, camera.fy * pc[1] / pc[2] + camera.cy
            level = int(rng.integers(0, 4))
            sigma = 1.2**level
            obs_pose.append(k)
            obs_point.append(j)
            uv.append([u + rng.normal(0, 0.5 * sigma), v + rng.normal(0, 0.5 * sigma)])
            ur.append(np.nan if rng.uniform() < 0.1 else u - bf / pc[2] + rng.normal(0, 0.5 * sigma))
            weight.append(1.0 / sigma)
    uv, ur = np.array(uv), np.array(ur)
    outliers = rng.uniform(size=len(uv)) < 0.05
    uv[outliers] += rng.normal(0, 30, (int(outliers.sum()), 2))
    free = np.array([False, False, True, True, True, True])
    start = true_poses.copy()
    for k in np.flatnonzero(free):
        start[k] = exp_se3(np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.02, 3)]) @ true_poses[k]
    points = true_points + rng.normal(0, 0.02, true_points.shape)
    window = BundleWindow(
        start, free, points, np.array(obs_pose), np.array(obs_point), uv, ur, np.array(weight), camera, bf
    )
    return window, true_poses


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_local_bundle_adjustment_reaches_gtsams_minimum(seed: int):
    """depotbench.slam.bundle against GTSAM's Levenberg-Marquardt on the same factors: the same cost,
    the same solution, fixed keyframes untouched, and poses brought towards the truth."""
    from depotbench.slam.bundle import _Problem, bundle_adjust

    from tests.gtsam_reference import gtsam_bundle_adjust

    window, true_poses = _window(seed)
    poses, points, _, cost = bundle_adjust(window, 10)
    ref_poses, ref_points = gtsam_bundle_adjust(window, 10)
    start, free, start_points = window.poses, window.free, window.points
    problem = _Problem(window)
    ref_cost = problem.cost(ref_poses, ref_points)
    assert cost < 0.5 * problem.cost(start, start_points)
    # Both stop once an iteration gains less than 1e-5 of the cost: the minima agree to
    # about that, the poses to a tenth of a millimetre.
    assert cost == pytest.approx(ref_cost, rel=1e-4)
    np.testing.assert_allclose(poses[free], ref_poses[free], atol=1e-4)
    # A point seen twice, once as an outlier, can flee along its ray: both solvers let the
    # same ones go. The rest agree; points with a flat cost along their ray may stop a
    # fraction of a millimetre apart.
    fled = np.linalg.norm(points - start_points, axis=1) > 0.5
    np.testing.assert_array_equal(fled, np.linalg.norm(ref_points - start_points, axis=1) > 0.5)
    assert fled.sum() < 0.1 * len(fled)
    gap = np.linalg.norm(points - ref_points, axis=1)[~fled]
    assert np.median(gap) < 1e-5 and gap.max() < 2e-3
    np.testing.assert_array_equal(poses[~free], start[~free])
    before = np.linalg.norm(start[free, :3, 3] - true_poses[free, :3, 3], axis=1).mean()
    after = np.linalg.norm(poses[free, :3, 3] - true_poses[free, :3, 3], axis=1).mean()
    assert after < 0.5 * before


def test_a_cell_keeps_its_strong_corners_where_it_has_any():
    """ORB-SLAM's per-cell FAST: threshold 20, and 7 only in a cell that found nothing at 20;
    against the rule written out with a dictionary."""
    from depotbench.slam.features import strong_per_cell

    rng = np.random.default_rng(3)
    for _ in range(100):
        n = int(rng.integers(0, 400))
        cells = rng.integers(0, 30, n)
        score = rng.integers(7, int(rng.choice([22, 60])), n).astype(np.float32)
        strong_cells = {int(c) for c, v in zip(cells, score, strict=True) if v >= 20}
        expected = [bool(v >= 20 or int(c) not in strong_cells) for c, v in zip(cells, score, strict=True)]
        assert strong_per_cell(cells, score, 20).tolist() == expected


def test_the_quadtree_keeps_the_strongest_corner_of_each_quadrant():
    """Closed cases of ORB-SLAM's DistributeOctTree on a 64 x 64 level: 16 x 16 corners on a
    grid, 4 wanted: one split into quadrants, each keeping its highest response; 16 wanted:
    two splits, one per 16 x 16 square; as many wanted as there are corners, or more: all;
    corners in one quadrant only: the first split adds no node, and ORB-SLAM stops when a
    pass adds none, keeping the one strongest corner."""
    from depotbench.slam.features import distribute_numpy

    x, y = np.meshgrid(np.arange(2.0, 64.0, 4.0), np.arange(2.0, 64.0, 4.0))
    xs, ys = x.ravel(), y.ravel()
    response = np.random.default_rng(0).permutation(len(xs)).astype(np.float32)
    for side in (32, 16):
        kept = distribute_numpy(xs, ys, response, 64, 64, (64 // side) ** 2)
        squares = (ys // side) * (64 // side) + xs // side
        expected = [np.flatnonzero(squares == q)[np.argmax(response[squares == q])] for q in range(len(kept))]
        assert kept.tolist() == sorted(expected), side
    assert distribute_numpy(xs, ys, response, 64, 64, 256).tolist() == list(range(256))
    assert distribute_numpy(xs, ys, response, 64, 64, 1000).tolist() == list(range(256))
    corner = (xs < 32) & (ys < 32)  # a first split leaves one node: ORB-SLAM stops there
    kept = distribute_numpy(xs[corner], ys[corner], response[corner], 64, 64, 4)
    assert kept.tolist() == [int(np.argmax(response[corner]))]


def _texture(seed: int) -> np.ndarray:
    """A 640 x 480 image with corners of every strength: blurred noise, and boxes over it."""
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.integers(0, 256, (480, 640)).astype(np.float32), (0, 0), 1.5)
    image = np.clip((noise - 128) * 4 + 128, 0, 255).astype(np.uint8)
    for x, y, w, h in rng.integers(0, 600, (40, 4)):
        image[y % 440 : y % 440 + h // 10 + 5, x : x + w // 10 + 5] = rng.integers(0, 256)
    return image


@pytest.mark.parametrize("seed", [0, 1])
def test_the_extractor_keeps_orbs_own_candidates_and_orients_them_as_orb_does(seed: int):
    """Against OpenCV's ORB detecting 10x the budget with FAST scores at threshold 7, level by
    level: the same candidates (position in the level, score); and every keypoint kept sits
    exactly where ORB puts it in the full image, with ORB's orientation (within its float32
    arctangent) and the descriptor ORB computes there."""
    from depotbench.core.camera import Intrinsics
    from depotbench.slam.features import CANDIDATE_FACTOR, EDGE_PX, PATCH_PX, FeatureExtractor

    config = TrackingConfig()
    image = _texture(seed)
    orb = cv2.ORB_create(
        CANDIDATE_FACTOR * config.n_features, config.scale_factor, config.n_levels, EDGE_PX, 0, 2,
        cv2.ORB_FAST_SCORE, PATCH_PX, config.fast_threshold_min,
    )  # fmt: skip
    detected = orb.detect(image, None)
    extractor = FeatureExtractor(config)
    for level, level_image in enumerate(extractor.pyramid(image)):
        xs, ys, scores = extractor.candidates(level_image, level)
        scale = 1.2**level
        theirs = {
            (round(k.pt[0] / scale), round(k.pt[1] / scale), k.response)
            for k in detected
            if k.octave == level
        }
        assert set(zip(xs.tolist(), ys.tolist(), scores.tolist(), strict=True)) == theirs, level
        assert len(theirs) > 100
    camera = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480)
    features = extractor.extract(np.repeat(image[..., None], 3, axis=2), np.ones(image.shape), camera)
    assert len(features) > 900
    by_place = {(k.pt, k.octave): k for k in detected}
    found = [
        by_place[((float(x), float(y)), int(o))]
        for (x, y), o in zip(features.keypoints_px, features.octaves, strict=True)
    ]
    angles = np.array([k.angle for k in found])
    gap = np.abs((features.angles_deg - angles + 180) % 360 - 180)
    assert gap.max() < 1e-3
    _, descriptors = orb.compute(image, found)
    assert (descriptors != features.descriptors).any(
        axis=1
    ).sum() <= 2  # an angle within 1e-3 may round apart


@pytest.mark.parametrize("shape", [(1, 1), (38, 38), (30, 500), (60, 80)])
def test_an_image_too_small_for_the_pyramid_gives_what_fits(shape: tuple[int, int]):
    """Levels that would be smaller than a corner's border are not built (a 1 x 1 image has no
    level 4 to resize to): no keypoint where none fits, some on 60 x 80, every array aligned."""
    from depotbench.core.camera import Intrinsics
    from depotbench.slam.features import FeatureExtractor

    h, w = shape
    image = np.repeat(_texture(2)[:h, :w, None], 3, axis=2)
    features = FeatureExtractor(TrackingConfig()).extract(
        image, np.ones(shape), Intrinsics(50, 50, w / 2, h / 2, w, h)
    )
    assert len(features) == len(features.descriptors) == len(features.octaves) == len(features.depth_m)
    assert (len(features) > 0) == (min(shape) > 2 * 19)


def test_a_level_keeps_its_best_candidates_and_every_tie():
    """OpenCV's retainBest: the n highest scores, and all that tie the n-th."""
    from depotbench.slam.features import retain_best

    scores = np.array([9, 7, 12, 7, 30, 7, 8])
    assert retain_best(scores, 3).tolist() == [True, False, True, False, True, False, False]
    assert retain_best(scores, 5).tolist() == [True, True, True, True, True, True, True]  # 7 ties
    assert retain_best(scores, 4).tolist() == [True, False, True, False, True, False, True]
    assert retain_best(scores, 0).tolist() == [False] * 7
    assert retain_best(scores, 9).all()


def test_the_orientation_disc_is_round_and_symmetric():
    """ORB's disc of radius 15: row v reaches round(sqrt(15^2 - v^2)) near the centre, and the
    disc equals its transpose (its rows beyond 45 degrees come from its columns)."""
    from depotbench.slam.features import disc_half_widths

    widths = disc_half_widths(15)
    assert widths[0] == 15 and widths[15] == 3
    assert widths[:11].tolist() == [round(np.sqrt(225 - v * v)) for v in range(11)]
    v, u = np.mgrid[-15:16, -15:16]
    disc = np.abs(u) <= widths[np.abs(v)]
    np.testing.assert_array_equal(disc, disc.T)


def test_each_level_wants_orb_slams_share():
    """ORB-SLAM's mnFeaturesPerLevel for 1000 features, scale 1.2, 8 levels: 1000 (1 - 1/1.2)
    / (1 - 1.2^-8) = 217.2 at level 0, each next 1/1.2 of the last, rounded, and the last
    level what is left (60)."""
    from depotbench.slam.features import features_per_level

    assert features_per_level(1000, 1.2, 8).tolist() == [217, 181, 151, 126, 105, 87, 73, 60]
    assert features_per_level(50, 2.0, 3).tolist() == [29, 14, 7]


def test_the_builtin_tracker_runs_with_one_blas_thread(static_seq: Path, monkeypatch):
    """Tracking is sequential with small matrices: a BLAS pool of a thread per core spun
    against other work (the local BA's solve took 20 ms instead of 0.4 on a busy 2-core
    machine). Inside a run BLAS has one thread; after it, what it had before."""
    from depotbench.eval.trackers.builtin import BuiltinTracker
    from depotbench.eval.trackers.frames import FrameSource
    from depotbench.slam.config import SlamConfig
    from depotbench.slam.system import Slam
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads() -> list[int]:
        return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]

    seen = []

    class Stop(Exception):
        pass

    def first_frame(self, *args, **kwargs):
        seen.append(blas_threads())
        raise Stop

    monkeypatch.setattr(Slam, "process", first_frame)
    with threadpool_limits(2, user_api="blas"):
        before = blas_threads()
        with pytest.raises(Stop):
            BuiltinTracker(SlamConfig()).run(FrameSource(Sequence.open(static_seq)), progress=False)
        assert blas_threads() == before
    assert seen and all(n == 1 for n in seen[0])
    assert max(before) == 2  # the run did change something
