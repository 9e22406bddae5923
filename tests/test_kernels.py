"""The compiled kernels (depotbench.slam.kernels) against their NumPy references, and the switch.

Every kernel is held to the NumPy function it replaces on inputs drawn from seeded
generators and on edge cases (no points, one point, points behind the camera, no depth).
Tolerances, and why:

- integers and decisions (Hamming distances, match indices, inlier masks, rejection codes,
  tracking states): exact;
- a refined pose: 1e-9 per matrix entry. Both run the same Gauss-Newton steps, which agree
  to ~1e-15 relative (summation order, LAPACK against an unblocked solve); over 200 random
  problems the largest gap measured 1.2e-15, so 1e-9 leaves six orders of margin for
  ill-conditioned draws while a real error (a Jacobian entry, a Huber weight) moves a pose
  by more than 1e-4;
- local bundle adjustment: the cost and the normal-equation blocks to 1e-12 relative, the
  step to 1e-9 relative, poses after 10 iterations to 1e-9 and points to 1e-9 times
  (1 + how far they moved): a point seen twice, once as an outlier, may flee along its ray
  by hundreds of kilometres, where the same relative rounding is a millimetre;
- the epipolar distance and flow magnitude: 1e-12 relative.

The default suite runs both paths (the kernels compiled, the references in NumPy), and a
short generated sequence is tracked on both with the same trajectory to 1e-9.
"""

from __future__ import annotations

import inspect
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from depotbench.core import jit as jit_module
from depotbench.core.camera import Intrinsics
from depotbench.core.errors import InputError
from depotbench.slam import bundle, kernels, optimize, rejection
from depotbench.slam.config import RejectionConfig, SlamConfig, TrackingConfig
from depotbench.slam.features import FrameFeatures
from depotbench.slam.geometry import exp_se3, hamming
from depotbench.slam.kernels import Kernels, matching
from depotbench.slam.kernels import optimize as optimize_kernels
from depotbench.slam.map import Map
from depotbench.slam.matcher import Matcher, consistent_rotation
from depotbench.slam.types import REJECTION_CODES, Rejection

from tests.conftest import REPO

CAMERA = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480)
BF = 40.0
COMPILED = (CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, BF)
CONSTANTS = (optimize.CHI2_STEREO, optimize.CHI2_MONO, optimize.GN_STEP_TOLERANCE)
DEPTH_CHECK = "depth_check" in inspect.signature(Matcher.search_by_projection).parameters
"""Whether the reference has the last frame's depth check yet (issue 40's local-mapping work)."""


@pytest.fixture
def path(monkeypatch: pytest.MonkeyPatch):
    """Set DEPOTBENCH_KERNELS for one test (the switch is read once per process)."""

    def use(value: str) -> None:
        monkeypatch.setenv(kernels.VARIABLE, value)
        kernels.kernels.cache_clear()

    yield use
    kernels.kernels.cache_clear()


# -- the switch -----------------------------------------------------------------------------


def test_the_switch_defaults_to_numba_and_takes_numpy(path, monkeypatch):
    monkeypatch.delenv(kernels.VARIABLE, raising=False)
    kernels.kernels.cache_clear()
    assert kernels.kernels() is Kernels.NUMBA and kernels.compiled()
    path(" NumPy ")
    assert kernels.kernels() is Kernels.NUMPY and not kernels.compiled()
    path("numba")
    assert kernels.kernels() is Kernels.NUMBA
    with kernels.using(Kernels.NUMPY):
        assert not kernels.compiled()
    assert kernels.compiled()


def test_a_bad_value_is_refused_in_one_line_naming_the_variable(path):
    path("fast")
    with pytest.raises(InputError) as caught:
        kernels.kernels()
    assert str(caught.value) == "DEPOTBENCH_KERNELS='fast': choose numpy or numba"
    with pytest.raises(InputError, match="DEPOTBENCH_KERNELS"):
        optimize.refine_pose(
            np.eye(4), np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), CAMERA, BF
        )


def test_numba_asked_for_but_missing_is_refused(path, monkeypatch):
    monkeypatch.setattr(jit_module.importlib.util, "find_spec", lambda name: None)
    path("numba")
    with pytest.raises(InputError, match=r"DEPOTBENCH_KERNELS=numba, but numba is not installed"):
        kernels.kernels()
    path("")
    assert kernels.kernels() is Kernels.NUMPY  # unset: NumPy where numba is missing


def test_each_entry_point_routes_through_the_switch(path, monkeypatch):
    """refine_pose calls the compiled kernel under numba and never under numpy."""
    called = []

    def fake(*args):
        called.append(len(args))
        return np.eye(4), np.ones(len(args[1]), bool)

    monkeypatch.setattr(optimize_kernels, "refine_pose", fake)
    args = (np.eye(4), np.c_[np.zeros((5, 2)), np.ones(5)], np.zeros((5, 2)), np.ones(5), np.ones(5))
    path("numpy")
    optimize.refine_pose(*args, CAMERA, BF)
    assert called == []
    path("numba")
    optimize.refine_pose(*args, CAMERA, BF)
    assert called == [15]


def test_without_a_writable_cache_folder_kernels_compile_in_memory(tmp_path: Path):
    """Numba raises when it finds no cache folder (a read-only install, no home); the kernel
    then compiles in each process instead. Shown in a child whose only cache locator is
    Numba's IPython one, which declines ordinary files."""
    script = (
        "from depotbench.core.jit import jit\n"
        "@jit\n"
        "def twice(x):\n"
        "    return 2 * x\n"
        "print(twice(21), twice._cache.__class__.__name__)\n"
    )
    (tmp_path / "probe.py").write_text(script)
    result = subprocess.run(
        [sys.executable, str(tmp_path / "probe.py")],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        cwd=REPO,
        env={**_environment(), "NUMBA_CACHE_LOCATOR_CLASSES": "IPythonCacheLocator"},
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split() == ["42", "NullCache"]
    assert "no writable cache folder for twice; compiling in memory" in result.stderr


def _environment() -> dict[str, str]:
    import os

    return {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}


# -- pose refinement ------------------------------------------------------------------------


def _pose_problem(rng: np.random.Generator, n: int, behind: float = 0.0, no_depth: float = 0.2):
    """Map points seen by a camera at a known pose, pixel noise by pyramid level, 10 %
    outliers, keypoints without depth, and a start perturbed from the truth."""
    points_w = np.c_[rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(1, 6, n)]
    true = exp_se3(np.r_[rng.normal(0, 0.05, 3), rng.normal(0, 0.1, 3)])
    pc = points_w @ true[:3, :3].T + true[:3, 3]
    flip = rng.uniform(size=n) < behind
    points_w[flip] = (np.c_[pc[flip, :2], -pc[flip, 2]] - true[:3, 3]) @ true[:3, :3]
    z = np.where(flip, 1.0, pc[:, 2])
    uv = np.c_[CAMERA.fx * pc[:, 0] / z + CAMERA.cx, CAMERA.fy * pc[:, 1] / z + CAMERA.cy]
    level = rng.integers(0, 8, n)
    uv += rng.normal(0, 1, (n, 2)) * 1.2 ** level[:, None]
    ur = uv[:, 0] - BF / z + rng.normal(0, 1, n)
    ur[rng.uniform(size=n) < no_depth] = np.nan
    outlier = rng.uniform(size=n) < 0.1
    uv[outlier] += rng.normal(0, 40, (int(outlier.sum()), 2))
    guess = exp_se3(np.r_[rng.normal(0, 0.02, 3), rng.normal(0, 0.05, 3)]) @ true
    return guess, points_w, uv, ur, 1.0 / 1.2**level


def _both_refinements(problem):
    reference = optimize.refine_pose_numpy(*problem, CAMERA, BF)
    return reference, optimize_kernels.refine_pose(*problem, *COMPILED, 4, 10, *CONSTANTS)


@pytest.mark.parametrize("seed", range(4))
def test_pose_refinement_equals_numpy(seed: int):
    rng = np.random.default_rng(seed)
    points = inliers = 0
    for _ in range(25):
        n = int(rng.integers(3, 600))
        problem = _pose_problem(rng, n, no_depth=rng.choice([0.0, 0.2, 1.0]))
        (pose_ref, inlier_ref), (pose_new, inlier_new) = _both_refinements(problem)
        np.testing.assert_allclose(pose_new, pose_ref, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(inlier_new, inlier_ref)
        points, inliers = points + n, inliers + int(inlier_ref.sum())
    assert inliers > 0.7 * points  # real problems: most points are inliers


def test_pose_refinement_edge_cases_equal_numpy():
    rng = np.random.default_rng(11)
    for n in (0, 1, 2):  # below 3 points nothing moves and every point stays
        (pose_ref, inlier_ref), (pose_new, inlier_new) = _both_refinements(_pose_problem(rng, n))
        np.testing.assert_array_equal(pose_new, pose_ref)
        np.testing.assert_array_equal(inlier_new, inlier_ref)
        assert inlier_ref.all() and len(inlier_ref) == n
    (pose_ref, inlier_ref), (pose_new, inlier_new) = _both_refinements(_pose_problem(rng, 3))
    np.testing.assert_allclose(pose_new, pose_ref, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(inlier_new, inlier_ref)
    # every point behind the camera: no inlier either way (the steps themselves are rounding,
    # see the next test)
    (pose_ref, inlier_ref), (pose_new, inlier_new) = _both_refinements(_pose_problem(rng, 50, behind=1.0))
    assert np.isfinite(pose_new).all() and not inlier_ref.any() and not inlier_new.any()


def test_pose_refinement_with_some_points_behind_the_camera_stays_finite():
    """Not held to the reference: its Jacobian of a point behind the camera is taken at
    z = 1e-6 (entries ~1e18), which leaves the normal equations singular to rounding, so any
    two solvers step apart (measured 5e-5 and 8e-3 on two of 50 draws). No call of 2,384 in
    eight 150-frame runs of walking_xyz started with a point behind the camera."""
    rng = np.random.default_rng(12)
    for _ in range(20):
        problem = _pose_problem(rng, int(rng.integers(20, 300)), behind=0.05)
        (pose_ref, inlier_ref), (pose_new, inlier_new) = _both_refinements(problem)
        assert np.isfinite(pose_new).all() and inlier_new.shape == inlier_ref.shape
        np.testing.assert_allclose(pose_new[:3, :3] @ pose_new[:3, :3].T, np.eye(3), atol=1e-9)


def test_rotation_vectors_become_opencvs_matrices():
    rng = np.random.default_rng(3)
    for scale in (0.0, 1e-17, 1e-9, 1e-3, 0.3, 3.0):
        for _ in range(50):
            rotvec = rng.normal(0, scale, 3) if scale else np.zeros(3)
            np.testing.assert_allclose(
                optimize_kernels.rodrigues(rotvec), cv2.Rodrigues(rotvec)[0], rtol=0, atol=1e-15
            )
            start = exp_se3(rng.normal(0, 1, 6))
            expected = exp_se3(np.r_[rotvec, rng.normal(0, 1, 3)])
            delta = np.r_[rotvec, expected[:3, 3]]
            np.testing.assert_allclose(
                optimize_kernels.exp_se3_left(delta, start), exp_se3(delta) @ start, atol=1e-15
            )


def test_the_solver_equals_numpy_and_refuses_what_numpy_cannot_solve():
    rng = np.random.default_rng(5)
    for n in (1, 6, 12, 30):
        a = rng.normal(size=(n, n)) + n * np.eye(n)
        b = rng.normal(size=n)
        solved, x = optimize_kernels.solve(a, b)
        assert solved
        np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-12, atol=1e-14)
    singular = np.ones((3, 3))
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.solve(singular, np.ones(3))
    assert not optimize_kernels.solve(singular, np.ones(3))[0]
    assert not optimize_kernels.solve(np.eye(3), np.array([1.0, np.nan, 0.0]))[0]
    assert not optimize_kernels.solve(np.full((2, 2), np.inf), np.ones(2))[0]


# -- local bundle adjustment ----------------------------------------------------------------


def _windows():
    from tests.test_slam import _window

    for seed in range(3):
        yield _window(seed)[0]


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


def test_bundle_cost_linearisation_and_step_equal_numpy():
    for window in _windows():
        reference, compiled = bundle._Problem(window), bundle._CompiledProblem(window)
        poses, points = window.poses, window.points
        assert compiled.cost(poses, points) == pytest.approx(reference.cost(poses, points), rel=1e-12)
        linear_ref, linear_new = reference.linearise(poses, points), compiled.linearise(poses, points)
        for block_ref, block_new in zip(linear_ref, linear_new, strict=True):
            assert block_new.shape == block_ref.shape
            assert _relative(block_new, block_ref) < 1e-12
        np.testing.assert_allclose(
            compiled._camera_points(poses, points), reference._camera_points(poses, points), atol=1e-12
        )
        for damping in (1e-5, 1e-2, 10.0):
            step_ref, step_new = reference.step(linear_ref, damping), compiled.step(linear_new, damping)
            for part_ref, part_new in zip(step_ref, step_new, strict=True):
                assert _relative(part_new, part_ref) < 1e-9


def _shuffled_with_a_repeat(window: bundle.BundleWindow, seed: int) -> bundle.BundleWindow:
    """The window's observations in a random order, plus a second observation of one point
    by a free keyframe that sees it already (a map never holds one; a caller's window may)."""
    rng = np.random.default_rng(seed)
    free_rows = np.flatnonzero(window.free[window.obs_pose])
    repeat = int(free_rows[0])
    rows = rng.permutation(np.r_[np.arange(len(window.obs_pose)), repeat])
    uv = window.uv[rows].copy()
    uv[rows == repeat] += 0.7  # the second sighting a little apart from the first
    return bundle.BundleWindow(
        window.poses,
        window.free,
        window.points,
        window.obs_pose[rows],
        window.obs_point[rows],
        uv,
        window.ur[rows],
        window.weight[rows],
        window.camera,
        window.bf,
    )


def _full_system_step(problem: bundle._CompiledProblem, linear: tuple, damping: float) -> tuple:
    """The damped Gauss-Newton step solved on the whole normal equations, poses and points
    together (no Schur complement): [[U, W], [W^T, V]] + damping I against -gradient."""
    u_blocks, g_pose, v_blocks, g_point, w_blocks = linear
    n_free, n_points = len(u_blocks), len(v_blocks)
    size = 6 * n_free + 3 * n_points
    h = np.zeros((size, size))
    for slot, block in enumerate(u_blocks):
        h[6 * slot : 6 * slot + 6, 6 * slot : 6 * slot + 6] = block
    for point, block in enumerate(v_blocks):
        at = 6 * n_free + 3 * point
        h[at : at + 3, at : at + 3] = block
    on_free = np.flatnonzero(problem.obs_slot >= 0)
    for row, observation in enumerate(on_free):
        slot, at = problem.obs_slot[observation], 6 * n_free + 3 * problem.obs_point[observation]
        h[6 * slot : 6 * slot + 6, at : at + 3] += w_blocks[row]
        h[at : at + 3, 6 * slot : 6 * slot + 6] += w_blocks[row].T
    step = np.linalg.solve(h + damping * np.eye(size), -np.r_[g_pose.ravel(), g_point.ravel()])
    return step[: 6 * n_free].reshape(-1, 6), step[6 * n_free :].reshape(-1, 3)


def test_the_reduced_system_needs_no_order_and_counts_a_keyframes_second_sighting():
    """The compiled reduced system is written in its upper triangle from each point's
    observations in slot order: whatever the observations' order, and with one point seen
    twice by one keyframe (both cross products on its diagonal block), its step is the one
    solved on the whole normal equations without the Schur complement; so is the NumPy
    reference's (whose dense W kept only one of the two sightings)."""
    for seed, window in enumerate(_windows()):
        window = _shuffled_with_a_repeat(window, seed)
        compiled, reference = bundle._CompiledProblem(window), bundle._Problem(window)
        linear = compiled.linearise(window.poses, window.points)
        linear_ref = reference.linearise(window.poses, window.points)
        for damping in (1e-5, 1.0):
            expected = _full_system_step(compiled, linear, damping)
            for step in (compiled.step(linear, damping), reference.step(linear_ref, damping)):
                for part, part_expected in zip(step, expected, strict=True):
                    assert _relative(part, part_expected) < 1e-8


def test_the_two_orders_of_the_reduced_systems_pair_sums_give_the_same_bytes():
    """``reduce`` sums a window's pairs of observations where they land (small windows) or as
    36 lanes a block (large ones, ``LANES_FROM_PAIRS``): the same sums in the same order, so
    the same bytes either way, a keyframe's second sighting of a point included."""
    windows = list(_windows())
    windows += [_shuffled_with_a_repeat(w, seed) for seed, w in enumerate(_windows())]
    for window in windows:
        problem = bundle._CompiledProblem(window)
        _, _, v_blocks, g_point, w_blocks = problem.linearise(window.poses, window.points)
        v_inverse = np.linalg.inv(v_blocks + np.eye(3))
        grouping = (problem.point_start, problem.point_obs, problem.free_slot)
        size = 6 * problem.n_free
        found = []
        for pairs in (optimize_kernels._pairs_in_place, optimize_kernels._pairs_in_lanes):
            reduced, rhs_sum = np.zeros((size, size)), np.zeros(size)
            pairs(reduced, rhs_sum, v_inverse, g_point, w_blocks, *grouping)
            found.append((reduced, rhs_sum))
        (in_place, rhs_in_place), (in_lanes, rhs_in_lanes) = found
        assert np.abs(in_place).max() > 0
        assert np.array_equal(in_place, in_lanes) and np.array_equal(rhs_in_place, rhs_in_lanes)
        assert not np.tril(in_lanes, -1).any()  # the upper triangle alone, as the solve reads it


def test_the_reduced_solve_reads_the_upper_triangle_and_refuses_an_indefinite_system():
    rng = np.random.default_rng(5)
    a = rng.standard_normal((18, 18))
    full = a @ a.T + 0.1 * np.eye(18)
    b = rng.standard_normal(18)
    upper = np.triu(full)  # the lower triangle left at zero, as the compiled reduce leaves it
    np.testing.assert_allclose(bundle.solve_reduced(upper, b), np.linalg.solve(full, b), rtol=1e-10)
    indefinite = np.diag(np.r_[np.ones(17), -1.0])
    assert bundle.solve_reduced(indefinite, b) is None
    assert bundle.solve_reduced(np.zeros((0, 0)), np.zeros(0)).shape == (0,)


def test_bundle_adjustment_equals_numpy(path):
    for window in _windows():
        path("numpy")
        poses_ref, points_ref, inlier_ref, cost_ref = bundle.bundle_adjust(window, 10)
        path("numba")
        poses_new, points_new, inlier_new, cost_new = bundle.bundle_adjust(window, 10)
        np.testing.assert_allclose(poses_new, poses_ref, rtol=0, atol=1e-9)
        # A point seen twice, once as an outlier, flees along its ray (test_slam's 0.5 m):
        # its cost is flat there, so rounding moves it by its displacement times ~1e-9
        # (measured 3e-9 of 525 km); every other point agrees to 1e-9 m (measured 2e-10).
        moved = np.linalg.norm(points_ref - window.points, axis=1)
        gap = np.linalg.norm(points_new - points_ref, axis=1)
        fled = moved > 0.5
        assert (gap[~fled] <= 1e-9).all()
        assert (gap[fled] <= 1e-7 * moved[fled]).all()
        np.testing.assert_array_equal(inlier_new, inlier_ref)
        assert cost_new == pytest.approx(cost_ref, rel=1e-12)


def _cut(window: bundle.BundleWindow, count: int, behind: bool) -> bundle.BundleWindow:
    """The window's first ``count`` points; with ``behind`` the first of them mirrored behind
    the camera of its first keyframe."""
    keep = np.arange(count)
    rows = np.isin(window.obs_point, keep)
    cut = bundle.BundleWindow(
        window.poses,
        window.free,
        window.points[keep].copy(),
        window.obs_pose[rows],
        window.obs_point[rows],
        window.uv[rows],
        window.ur[rows],
        window.weight[rows],
        window.camera,
        window.bf,
    )
    if behind:
        first = int(np.flatnonzero(cut.obs_point == 0)[0])
        camera_from_world = cut.poses[cut.obs_pose[first]]
        pc = camera_from_world[:3, :3] @ cut.points[0] + camera_from_world[:3, 3]
        pc[2] = -pc[2]
        cut.points[0] = camera_from_world[:3, :3].T @ (pc - camera_from_world[:3, 3])
    return cut


@pytest.mark.parametrize(
    ("count", "behind", "pose_atol"), [(1, False, 1e-6), (1, True, 0.0), (40, True, 1e-9)]
)
def test_bundle_edge_cases_equal_numpy(path, count: int, behind: bool, pose_atol: float):
    """One point (four free poses fit it exactly: a family of minima at cost ~1e-17, where the
    two stop 1e-7 apart); a point behind a keyframe (GTSAM's constant cost, no weight in the
    step; alone, nothing moves)."""
    cut = _cut(next(_windows()), count, behind)
    reference, compiled = bundle._Problem(cut), bundle._CompiledProblem(cut)
    assert compiled.cost(cut.poses, cut.points) == pytest.approx(
        reference.cost(cut.poses, cut.points), rel=1e-12
    )
    path("numpy")
    expected = bundle.bundle_adjust(cut, 5)
    path("numba")
    found = bundle.bundle_adjust(cut, 5)
    np.testing.assert_allclose(found[0], expected[0], rtol=0, atol=pose_atol)
    np.testing.assert_array_equal(found[2], expected[2])
    assert found[3] == pytest.approx(expected[3], rel=1e-3 if count == 1 and not behind else 1e-12)


# -- search by projection -------------------------------------------------------------------


def _scene(rng: np.random.Generator, n_keypoints: int, n_points: int):
    """A frame's keypoints (continuous positions: no two at the same distance from a point) and
    a map of points near them, descriptors a few to many bits from their keypoint's."""
    px = np.c_[rng.uniform(0, CAMERA.width, n_keypoints), rng.uniform(0, CAMERA.height, n_keypoints)]
    descriptors = rng.integers(0, 256, (n_keypoints, 32), dtype=np.uint8)
    features = FrameFeatures(
        np.zeros((CAMERA.height, CAMERA.width), np.uint8),
        px.astype(np.float32),
        px,
        rng.integers(0, 8, n_keypoints),
        descriptors,
        np.where(rng.uniform(size=n_keypoints) < 0.2, 0.0, rng.uniform(0.5, 5, n_keypoints)),
        rng.uniform(0, 360, n_keypoints),
    )
    source = rng.integers(0, max(n_keypoints, 1), n_points)
    depth = rng.uniform(0.5, 6, n_points)
    near = px[source] + rng.normal(0, 4, (n_points, 2)) if n_keypoints else rng.uniform(0, 480, (n_points, 2))
    near[rng.uniform(size=n_points) < 0.1] += 800  # some out of the image
    positions = np.c_[(near - [CAMERA.cx, CAMERA.cy]) / CAMERA.fx * depth[:, None], depth]
    positions[rng.uniform(size=n_points) < 0.05, 2] *= -1  # some behind the camera
    point_descriptors = descriptors[source].copy() if n_keypoints else np.zeros((n_points, 32), np.uint8)
    flips = rng.uniform(size=point_descriptors.shape) < rng.uniform(0, 0.6, (n_points, 1))
    point_descriptors ^= (flips * rng.integers(1, 256, point_descriptors.shape)).astype(np.uint8)
    map_ = Map()
    map_.add_points(positions, point_descriptors, 0)
    map_.alive[rng.uniform(size=n_points) < 0.05] = False
    return features, map_


def _search_arguments(rng: np.random.Generator, features: FrameFeatures, map_: Map, variant: int):
    n = len(map_.positions)
    point_ids = rng.permutation(n)[: int(rng.integers(0, n + 1))]
    pose = exp_se3(np.r_[rng.normal(0, 0.002, 3), rng.normal(0, 0.01, 3)])
    usable = rng.uniform(size=len(features)) < 0.9
    radius = 4.0 if variant % 2 else 15.0 * 1.2 ** rng.integers(0, 8, len(point_ids))
    kwargs = {}
    if variant in (1, 3):
        kwargs["exclude"] = rng.uniform(size=len(features)) < 0.2
    if variant >= 2:
        octaves = rng.integers(0, 8, len(point_ids))
        kwargs["octave_window"] = (octaves - 1, octaves + 1)
        kwargs["reference_angles"] = rng.uniform(0, 360, len(point_ids))
    if DEPTH_CHECK and variant in (1, 2):
        kwargs["depth_check"] = True
    return (map_, point_ids, pose, features, usable, radius), kwargs


@pytest.mark.parametrize("seed", range(3))
def test_search_by_projection_equals_numpy(seed: int):
    """The same matches in the same order, and the same projected ids: exact."""
    rng = np.random.default_rng(seed)
    matcher = Matcher(TrackingConfig(), CAMERA)
    matched = 0
    for trial in range(40):
        features, map_ = _scene(rng, int(rng.integers(0, 1200)), int(rng.integers(0, 900)))
        args, kwargs = _search_arguments(rng, features, map_, trial % 4)
        expected = matcher.search_by_projection(*args, **kwargs)
        found = matching.search_by_projection(matcher, *args, **kwargs)
        for part_expected, part_found in zip(expected, found, strict=True):
            np.testing.assert_array_equal(part_found, part_expected)
        matched += len(expected[0])
    assert matched > 1000  # the draws do match


def test_search_by_projection_edge_cases_equal_numpy():
    rng = np.random.default_rng(7)
    matcher = Matcher(TrackingConfig(), CAMERA)
    features, map_ = _scene(rng, 300, 200)
    ids, pose, usable = np.arange(200), np.eye(4), np.ones(300, bool)
    cases = [
        (map_, ids[:0], pose, features, usable, 4.0),  # no points
        (map_, ids[:1], pose, features, usable, 4.0),  # one point
        (map_, ids, pose, features, np.zeros(300, bool), 4.0),  # no usable keypoint
        (map_, ids, exp_se3(np.r_[0, np.pi, 0, 0, 0, 0]), features, usable, 4.0),  # all behind
    ]
    for args in cases:
        expected = matcher.search_by_projection(*args)
        found = matching.search_by_projection(matcher, *args)
        for part_expected, part_found in zip(expected, found, strict=True):
            np.testing.assert_array_equal(part_found, part_expected)


def test_equal_keypoints_at_equal_distance_go_to_the_lower_index():
    """One pixel at two pyramid levels, both as good by Hamming distance: the k-d tree of the
    reference orders them as it finds them; the kernel takes the lower keypoint index."""
    descriptor = np.arange(32, dtype=np.uint8)
    features = FrameFeatures(
        np.zeros((480, 640), np.uint8),
        np.array([[300.0, 200.0], [100.0, 100.0], [300.0, 200.0]], np.float32),
        np.array([[300.0, 200.0], [100.0, 100.0], [300.0, 200.0]]),
        np.array([2, 0, 1]),
        np.stack([descriptor, ~descriptor, descriptor]),
        np.ones(3),
        np.zeros(3),
    )
    map_ = Map()
    map_.add_points(
        np.array([[(301.0 - CAMERA.cx) / CAMERA.fx, (200.5 - CAMERA.cy) / CAMERA.fy, 1.0]]),
        descriptor[None],
        0,
    )
    kp, pid, _ = matching.search_by_projection(
        Matcher(TrackingConfig(), CAMERA), map_, np.array([0]), np.eye(4), features, np.ones(3, bool), 4.0
    )
    assert kp.tolist() == [0] and pid.tolist() == [0]


def test_the_depth_check_compares_right_image_columns():
    """A keypoint with depth matches only where its right-image column (u - bf / depth) lies
    within the radius of the point's; one without depth always passes. Hand-made: the point
    projects to (300.5, 200) at 2 m (right column 280.5); keypoints at (301, 200)."""
    descriptor = np.arange(32, dtype=np.uint8)
    position = [(300.5 - CAMERA.cx) / CAMERA.fx * 2.0, (200.0 - CAMERA.cy) / CAMERA.fy * 2.0, 2.0]
    map_ = Map()
    map_.add_points(np.array([position]), descriptor[None], 0)
    matcher = Matcher(TrackingConfig(), CAMERA)
    for depth, matched in ((2.0, True), (2.5, False), (1.8, False), (0.0, True)):
        # right columns: 281.0, 285.0, 278.8 against 280.5 within 1.5 px; no depth: no check
        features = FrameFeatures(
            np.zeros((480, 640), np.uint8),
            np.array([[301.0, 200.0]], np.float32),
            np.array([[301.0, 200.0]]),
            np.array([0]),
            descriptor[None],
            np.array([depth]),
            np.zeros(1),
        )
        args = (map_, np.array([0]), np.eye(4), features, np.ones(1, bool), 1.5)
        kp, _, _ = matching.search_by_projection(matcher, *args, depth_check=True)
        assert len(kp) == matched, depth
        assert len(matching.search_by_projection(matcher, *args)[0]) == 1
        if DEPTH_CHECK:
            assert len(matcher.search_by_projection(*args, depth_check=True)[0]) == matched


def _local_map(rng: np.random.Generator, features: FrameFeatures, map_: Map) -> None:
    """Give ``_scene``'s points what the local search reads: normals (most towards the camera,
    some oblique, some seen from behind) and distance ranges (some too near or too far)."""
    n = len(map_.positions)
    offset = map_.positions.copy()
    distance = np.linalg.norm(offset, axis=1)
    normal = offset + rng.normal(0, 0.3, (n, 3)) * (rng.uniform(size=n) < 0.5)[:, None] * distance[:, None]
    normal[rng.uniform(size=n) < 0.05] *= -1
    map_.normals[:] = normal / np.linalg.norm(normal, axis=1)[:, None]
    map_.max_distance[:] = distance * 1.2 ** rng.integers(0, 6, n) * rng.uniform(0.9, 1.1, n)
    map_.max_distance[rng.uniform(size=n) < 0.05] /= 2
    map_.min_distance[:] = map_.max_distance / 1.2**7


@pytest.mark.parametrize("seed", range(3))
def test_local_map_search_equals_numpy(seed: int):
    """search_local_points on both paths: the same matches in the same order, the same ids in
    view: exact, over draws with and without exclusions, at th 3 and 5 (after relocalisation)."""
    rng = np.random.default_rng(100 + seed)
    matcher = Matcher(TrackingConfig(), CAMERA)
    matched = 0
    for trial in range(40):
        features, map_ = _scene(rng, int(rng.integers(0, 1200)), int(rng.integers(0, 900)))
        _local_map(rng, features, map_)
        n = len(map_.positions)
        point_ids = rng.permutation(n)[: int(rng.integers(0, n + 1))]
        pose = exp_se3(np.r_[rng.normal(0, 0.002, 3), rng.normal(0, 0.01, 3)])
        usable = rng.uniform(size=len(features)) < 0.9
        exclude = rng.uniform(size=len(features)) < (0.3 if trial % 2 else 0.0)
        args = (map_, point_ids, pose, features, usable, exclude, 5.0 if trial % 3 == 0 else 3.0)
        with kernels.using(Kernels.NUMPY):
            expected = matcher.search_local_points(*args)
        with kernels.using(Kernels.NUMBA):
            found = matcher.search_local_points(*args)
        for part_expected, part_found in zip(expected, found, strict=True):
            np.testing.assert_array_equal(part_found, part_expected)
        matched += len(expected[0])
    assert matched > 400  # the draws do match (about 650 per seed)


def test_local_map_search_ties_go_to_the_nearer_then_the_lower_keypoint():
    """A point and keypoints at one pixel (two pyramid levels of one corner): equal descriptor
    distances go to the nearer keypoint, then the lower index; at one level the 0.8 ratio
    test refuses a best no better than the second (unless both are exact). Both paths."""
    descriptor = np.arange(32, dtype=np.uint8)
    ten_bits = descriptor.copy()
    ten_bits[:2] ^= np.array([0b11111, 0b11111], np.uint8)  # 10 bits from the point's
    px = np.array([[300.0, 200.0], [300.0, 200.0], [300.8, 200.2]])
    cases = {  # (octaves, descriptors of the three keypoints): expected keypoints
        "exact, one level: the lower index": ((1, 1, 5), (descriptor, descriptor, ~descriptor), [0]),
        "10 bits, one level: ambiguous": ((1, 1, 5), (ten_bits, ten_bits, ~descriptor), []),
        "10 bits, two levels: the lower index": ((1, 0, 5), (ten_bits, ten_bits, ~descriptor), [0]),
        "10 bits, the nearer wins": ((0, 0, 1), (ten_bits, ten_bits, ten_bits), [2]),
    }
    position = np.array([[(300.9 - CAMERA.cx) / CAMERA.fx, (200.3 - CAMERA.cy) / CAMERA.fy, 1.0]])
    for name, (octaves, descriptors, expected) in cases.items():
        features = FrameFeatures(
            np.zeros((480, 640), np.uint8),
            px.astype(np.float32),
            px,
            np.array(octaves),
            np.stack(descriptors),
            np.zeros(3),
            np.zeros(3),
        )
        map_ = Map()
        map_.add_points(position, descriptor[None], 0)
        map_.normals[:] = position / np.linalg.norm(position)
        map_.max_distance[:] = np.linalg.norm(position) * 1.1  # predicted level 1: levels 0 and 1
        map_.min_distance[:] = map_.max_distance / 1.2**7
        args = (map_, np.array([0]), np.eye(4), features, np.ones(3, bool), np.zeros(3, bool), 3.0)
        for value in (Kernels.NUMPY, Kernels.NUMBA):
            with kernels.using(value):
                found = Matcher(TrackingConfig(), CAMERA).search_local_points(*args)[0]
            assert found.tolist() == expected, (name, value)


@pytest.mark.parametrize("seed", range(3))
def test_fuse_candidates_equal_numpy(seed: int):
    """Fuse's candidate pairs on both paths: the same (point, keypoint) pairs in the same order,
    exactly, over draws with keypoints with and without depth and unusable ones."""
    from depotbench.slam.matcher import fuse_candidates

    rng = np.random.default_rng(200 + seed)
    tc = TrackingConfig()
    fused = 0
    for _ in range(40):
        features, map_ = _scene(rng, int(rng.integers(0, 1200)), int(rng.integers(0, 900)))
        _local_map(rng, features, map_)
        point_ids = rng.permutation(len(map_.positions))
        pose = exp_se3(np.r_[rng.normal(0, 0.002, 3), rng.normal(0, 0.01, 3)])
        usable = rng.uniform(size=len(features)) < 0.9
        args = (tc, CAMERA, map_, point_ids, pose, features, usable)
        with kernels.using(Kernels.NUMPY):
            expected = fuse_candidates(*args)
        with kernels.using(Kernels.NUMBA):
            found = fuse_candidates(*args)
        for part_expected, part_found in zip(expected, found, strict=True):
            np.testing.assert_array_equal(part_found, part_expected)
        fused += len(expected[0])
    assert fused > 150  # the draws do fuse (about 250 per seed)


def _keyframe_pair(rng: np.random.Generator, n: int, forward: bool):
    """Two keyframes seeing ``n`` points (half of each one's keypoints project from them, the
    rest are clutter), descriptors a few to many bits apart, some keypoints without depth;
    ``forward``: the second moved along the optical axis, its epipole inside the image."""
    points = np.c_[rng.uniform(-2, 2, (n, 2)), rng.uniform(1, 6, n)]
    step = np.r_[0.0, 0.0, 0.3] if forward else np.r_[rng.normal(0, 0.1, 2), rng.normal(0, 0.03)]
    pose2 = exp_se3(np.r_[step, rng.normal(0, 0.02, 3)])
    frames = []
    base = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    for pose in (np.eye(4), pose2):
        pc = points @ pose[:3, :3].T + pose[:3, 3]
        px = pc[:, :2] / pc[:, 2:] * CAMERA.fx + [CAMERA.cx, CAMERA.cy] + rng.normal(0, 0.7, (n, 2))
        clutter = np.c_[rng.uniform(0, 640, n // 2), rng.uniform(0, 480, n // 2)]
        px = np.r_[px, clutter]
        descriptors = np.r_[base, rng.integers(0, 256, (n // 2, 32), dtype=np.uint8)]
        flips = rng.uniform(size=descriptors.shape) < rng.uniform(0, 0.25, (len(px), 1))
        descriptors ^= (flips * rng.integers(1, 256, descriptors.shape)).astype(np.uint8)
        depth = np.r_[pc[:, 2], rng.uniform(0.5, 6, n // 2)] * (rng.uniform(size=len(px)) < 0.6)
        frames.append(
            FrameFeatures(
                np.zeros((480, 640), np.uint8),
                px.astype(np.float32),
                px,
                rng.integers(0, 4, len(px)),
                descriptors,
                depth,
                np.zeros(len(px)),
            )
        )
    return frames, pose2


def test_triangulation_search_equals_numpy():
    """search_for_triangulation on both paths: the same pairs in the same order, exactly, over
    sideways and forward moves (the epipole in the image) and keypoints already taken."""
    from depotbench.slam.matcher import search_for_triangulation

    rng = np.random.default_rng(7)
    tc = TrackingConfig()
    paired = 0
    for trial in range(60):
        (f1, f2), pose2 = _keyframe_pair(rng, int(rng.integers(0, 500)), forward=trial % 3 == 0)
        free1 = rng.uniform(size=len(f1)) < 0.8
        free2 = rng.uniform(size=len(f2)) < 0.8
        args = (tc, CAMERA, f1, free1, np.eye(4), f2, free2, pose2)
        with kernels.using(Kernels.NUMPY):
            expected = search_for_triangulation(*args)
        with kernels.using(Kernels.NUMBA):
            found = search_for_triangulation(*args)
        for part_expected, part_found in zip(expected, found, strict=True):
            np.testing.assert_array_equal(part_found, part_expected)
        paired += len(expected[0])
    assert paired > 3000  # the draws do pair


def test_keypoint_distribution_equals_numpy():
    """The quadtree on both paths: the same keypoints, exactly, over levels of every shape,
    spread and clustered corners, corners on one pixel, and budgets from none to all."""
    from depotbench.slam.features import distribute_numpy
    from depotbench.slam.kernels import features as compiled

    rng = np.random.default_rng(11)
    kept = 0
    for trial in range(300):
        n, width, height = int(rng.integers(0, 800)), int(rng.integers(20, 610)), int(rng.integers(20, 450))
        if trial % 3 == 0:  # clustered, as corners on people and shelves
            centres = rng.uniform(0, 1, (5, 2)) * [width, height]
            px = centres[rng.integers(0, 5, n)] + rng.normal(0, 8, (n, 2))
            px = np.clip(px, 0, [width - 1, height - 1])
        else:
            px = rng.uniform(0, 1, (n, 2)) * [width, height]
        if trial % 5 == 0:
            px = np.clip(np.round(px), 0, [width - 1, height - 1])  # several corners on one pixel
        response = rng.integers(7, 60, n).astype(np.float64)
        wanted = int(rng.integers(0, 300))
        expected = distribute_numpy(px[:, 0], px[:, 1], response, width, height, wanted)
        found = compiled.distribute(px[:, 0].copy(), px[:, 1].copy(), response, width, height, wanted)
        np.testing.assert_array_equal(found, expected)
        kept += len(expected)
    assert kept > 20000  # the draws do keep


def _textures(rng: np.random.Generator) -> list[np.ndarray]:
    """Images FAST meets: blurred noise at two scales (dense weak corners, as cloth), boxes
    and stripes (strong corners, as shelves), saturated black and white (the bounds clip at
    0 and 255), flat, and images too small to hold any corner inside the border."""
    smooth = cv2.GaussianBlur(rng.integers(0, 256, (240, 320)).astype(np.float32), (0, 0), 2.0)
    fine = cv2.GaussianBlur(rng.integers(0, 256, (97, 131)).astype(np.float32), (0, 0), 0.8)
    boxes = np.full((200, 260), 90, np.uint8)
    for x, y, w, h in rng.integers(0, 200, (25, 4)):
        boxes[y : y + h // 4 + 3, x : x + w // 4 + 3] = rng.integers(0, 256)
    stripes = np.tile(((np.arange(120) // 5) % 2 * 255).astype(np.uint8), (90, 1))
    saturated = np.where(rng.uniform(size=(80, 80)) < 0.5, 0, 255).astype(np.uint8)
    return [
        np.clip(smooth * 3 - 250, 0, 255).astype(np.uint8),
        fine.astype(np.uint8),
        boxes,
        np.ascontiguousarray(stripes.T),
        saturated,
        np.full((60, 60), 128, np.uint8),
        rng.integers(0, 256, (30, 30)).astype(np.uint8),
        rng.integers(0, 256, (7, 400)).astype(np.uint8),
    ]


def test_fast_corners_equal_opencvs_detector():
    """The compiled FAST against OpenCV's (the reference path): the same corners, scores and
    order, on every texture and threshold, and at the borders ORB uses."""
    from depotbench.slam.features import corners_opencv
    from depotbench.slam.kernels import features as compiled

    rng = np.random.default_rng(4)
    found = 0
    for image in _textures(rng) + _textures(rng):
        for threshold in (1, 7, 20, 60):
            for border in (3, 19):
                expected = corners_opencv(image, threshold, border)
                result = compiled.fast_corners(image, threshold, border)
                for part_expected, part_found in zip(expected, result, strict=True):
                    np.testing.assert_array_equal(part_found, part_expected)
                found += len(expected[0])
    assert found > 20000  # the textures do have corners


def test_a_fast_threshold_above_a_byte_finds_no_corner():
    """The byte-wise FAST holds the threshold in a byte: one above 255 is clamped (no pixel
    differs by more), not wrapped (300 would be 44 and find corners)."""
    from depotbench.slam.kernels import features as compiled

    image = _textures(np.random.default_rng(6))[1]
    assert len(compiled.fast_corners(image, 44, 3)[0]) > 0
    for threshold in (255, 256, 300):
        assert len(compiled.fast_corners(image, threshold, 3)[0]) == 0


def test_keypoint_moments_equal_numpy():
    """ORB's intensity centroid on both paths: the same integer moments."""
    from depotbench.slam.features import disc_half_widths, moments_numpy
    from depotbench.slam.kernels import features as compiled

    rng = np.random.default_rng(5)
    half_widths = disc_half_widths(15)
    for image in _textures(rng)[:5]:
        h, w = image.shape
        xs, ys = rng.integers(15, w - 15, 300), rng.integers(15, h - 15, 300)
        expected = moments_numpy(image, xs, ys, half_widths)
        result = compiled.moments(image, xs, ys, half_widths)
        for part_expected, part_found in zip(expected, result, strict=True):
            np.testing.assert_array_equal(part_found, part_expected)


def test_distinctive_descriptors_equal_numpy():
    """ComputeDistinctiveDescriptors on points seen 0 to 200 times (up to 24 the kernel sorts
    each row, above it counts; at TUM's length a point is seen by up to ~200 keyframes):
    random descriptors, near copies of one (medians tie, the first wins) and points whose
    descriptors are all equal."""
    from depotbench.slam.map import distinctive

    rng = np.random.default_rng(3)
    counts = np.r_[0, 1, 2, 2, 3, 4, 5, 7, 8, 12, 20, 40, 24, 25, 60, 200, 200, rng.integers(0, 15, 200)]
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    values = rng.integers(0, 256, (int(counts.sum()), 32), dtype=np.uint8)
    for point in (17, 15):  # near copies: few distinct distances, many ties
        base = values[starts[point]].copy()
        for k in range(counts[point]):
            values[starts[point] + k] = base ^ (rng.random(32) < 0.02).astype(np.uint8)
    for point in (10, 16):  # all equal
        values[starts[point] : starts[point] + counts[point]] = values[starts[point]]
    reference = distinctive(values, starts, counts)
    assert (reference[counts < 2] == -1).all() and (reference[counts >= 2] >= 0).all()
    np.testing.assert_array_equal(matching.distinctive(values, starts, counts), reference)
    assert reference[16] == 0  # all equal: the first
    assert reference[10] == 0  # all equal: the first


def test_hamming_and_rotation_checks_equal_numpy():
    rng = np.random.default_rng(2)
    for _ in range(200):
        n = int(rng.integers(1, 400))
        delta = rng.choice([rng.normal(0, 3, n), rng.uniform(-720, 720, n), np.round(rng.normal(0, 30, n))])
        delta[: n // 10] = rng.choice([0.0, -0.0, 360.0, -1e-20, 359.99999999999994, -360.0], n // 10)
        np.testing.assert_array_equal(matching.consistent_rotation(delta), consistent_rotation(delta))
    a = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    assert hamming(a, b).tolist() == [int(np.unpackbits(x ^ y).sum()) for x, y in zip(a, b, strict=True)]


def test_all_pairs_hamming_distances_equal_numpy_and_count_bits():
    """Relocalisation's and the reference keyframe search's distances, compiled (four 64-bit
    words a descriptor), against NumPy's lookup table and against counting the bits of each
    pair's XOR; empty sides included. Descriptors sliced out of larger arrays (not contiguous)
    and every bit pattern's extremes (all zeros, all ones)."""
    from depotbench.slam.geometry import hamming_matrix

    rng = np.random.default_rng(8)
    for n, m in ((0, 5), (5, 0), (1, 1), (37, 300), (300, 37)):
        a = rng.integers(0, 256, (n, 64), dtype=np.uint8)[:, ::2]  # strided: copied to words
        b = rng.integers(0, 256, (m, 32), dtype=np.uint8)
        if n and m:
            a[0], b[0] = 0, 255
        found = matching.hamming_matrix(a, b)
        assert found.dtype == np.int32 and found.shape == (n, m)
        np.testing.assert_array_equal(found, hamming_matrix(a, b))
        if n and m:
            assert found[0, 0] == 256  # all zeros against all ones
            assert found[5 % n, 7 % m] == int(np.unpackbits(a[5 % n] ^ b[7 % m]).sum())


# -- rejection tests ------------------------------------------------------------------------


def test_epipolar_distances_and_flow_test_equal_numpy():
    rng = np.random.default_rng(4)
    config = RejectionConfig()
    for n in (0, 1, 2, 8, 500):
        previous = rng.uniform(0, 640, (n, 2))
        current = previous + rng.normal(0, 3, (n, 2))
        f = rng.normal(size=(3, 3))
        distance_ref, magnitude_ref = rejection.epipolar_geometry_numpy(f, previous, current)
        distance_new, magnitude_new = rejection_kernel().epipolar_geometry(f, previous, current)
        np.testing.assert_allclose(distance_new, distance_ref, rtol=1e-12, atol=0)
        np.testing.assert_allclose(magnitude_new, magnitude_ref, rtol=1e-12, atol=0)
        none, magnitude = rejection_kernel().epipolar_geometry(np.zeros((0, 3)), previous, current)
        assert len(none) == 0 and rejection.epipolar_geometry_numpy(None, previous, current)[0] is None
        np.testing.assert_allclose(magnitude, magnitude_ref, rtol=1e-12)
        if n >= 2:
            for scale in (0.3, 3.0, 30.0):
                magnitudes = np.abs(rng.normal(0, scale, n))
                magnitudes[: n // 20] += 40.0
                expected = rejection.flow_outliers_numpy(magnitudes, config)
                found = rejection_kernel().flow_outliers(magnitudes, 2.0, config.l_thr1_px, config.l_thr2_px)
                np.testing.assert_array_equal(found, expected)


def rejection_kernel():
    from depotbench.slam.kernels import rejection as compiled

    return compiled


def test_method_3_decides_the_same_on_both_paths(path):
    """box_epipolar_flow on a textured frame shifted by (3, 2) px, a patch moving on its own:
    the same rejection codes (the RANSAC seeded alike)."""
    rng = np.random.default_rng(9)
    grey = cv2.GaussianBlur(rng.integers(0, 256, (240, 320), dtype=np.uint8), (5, 5), 0)
    shifted = np.roll(grey, (2, 3), axis=(0, 1))
    shifted[80:140, 120:200] = np.roll(grey, (6, 8), axis=(0, 1))[80:140, 120:200]
    points = np.c_[rng.uniform(20, 300, 400), rng.uniform(20, 220, 400)]

    def frame(image: np.ndarray) -> FrameFeatures:
        n = len(points)
        return FrameFeatures(
            image,
            points.astype(np.float32),
            points,
            np.zeros(n, int),
            np.zeros((n, 32), np.uint8),
            np.ones(n),
            np.zeros(n),
        )

    codes = {}
    for value in ("numpy", "numba"):
        path(value)
        cv2.setRNGSeed(1)
        codes[value] = rejection.classify(
            "box_epipolar_flow", frame(shifted), frame(grey), (), RejectionConfig(epsilon_px=1.0)
        )
    np.testing.assert_array_equal(codes["numba"], codes["numpy"])
    inside = (points[:, 0] >= 120) & (points[:, 0] < 200) & (points[:, 1] >= 80) & (points[:, 1] < 140)
    # the patch goes, by both tests
    found = codes["numpy"][inside]
    assert (found != 0).mean() > 0.6
    assert {REJECTION_CODES[r] for r in (Rejection.EPIPOLAR, Rejection.FLOW_OUTLIER)} <= set(found.tolist())
    assert (codes["numpy"][~inside] != 0).mean() < 0.05


# -- the whole tracker ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def walking_seq(tmp_path_factory) -> Path:
    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.generate import generate

    scenario = library.get("walking_xyz").model_copy(update={"frames": 25, "duration_s": None, "seed": 3})
    return generate(to_scenario(scenario), tmp_path_factory.mktemp("walking") / "seq", progress=False)


@pytest.mark.render
@pytest.mark.parametrize("strategy", ["none", "box_epipolar_flow"])
def test_the_tracker_gives_the_same_trajectory_on_both_paths(walking_seq: Path, strategy: str, path):
    """25 frames of walking_xyz tracked with DEPOTBENCH_KERNELS=numpy and =numba: the same
    states, keyframes and rejections, poses within 1e-9 (measured 6e-15 over 150 frames)."""
    from depotbench.detectors.config import DetectorConfig
    from depotbench.eval.run.detections import detect_sequence
    from depotbench.eval.trackers.builtin import BuiltinTracker
    from depotbench.eval.trackers.frames import FrameSource
    from depotbench.sim.sequence import Sequence

    sequence = Sequence.open(walking_seq)
    frames = FrameSource(sequence, detect_sequence(sequence, DetectorConfig()).per_frame)
    runs = {}
    for value in ("numpy", "numba"):
        path(value)
        runs[value] = BuiltinTracker(SlamConfig(strategy=strategy)).run(frames, False)
    reference, compiled = runs["numpy"], runs["numba"]
    assert compiled.states == reference.states
    assert compiled.keyframes == reference.keyframes
    for result_ref, result_new in zip(reference.results, compiled.results, strict=True):
        np.testing.assert_array_equal(result_new.diagnostics.rejection, result_ref.diagnostics.rejection)
    tracked = [(a, b) for a, b in zip(reference.poses, compiled.poses, strict=True) if a is not None]
    assert len(tracked) >= 22 and all(b is not None for _, b in tracked)
    assert max(float(np.abs(a - b).max()) for a, b in tracked) < 1e-9


WARMED_THEN_TRACKED = """
import importlib, sys
from numba.core.registry import CPUDispatcher
from depotbench.slam import kernels
from depotbench.slam.config import SlamConfig
from depotbench.eval.trackers.builtin import BuiltinTracker
from depotbench.eval.trackers.frames import FrameSource
from depotbench.sim.sequence import Sequence

def signatures():
    found = {}
    for name in ("features", "matching", "optimize", "rejection"):
        module = importlib.import_module("depotbench.slam.kernels." + name)
        for attr, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.__module__ == module.__name__:
                found[name + "." + attr] = set(value.signatures)
    return found

kernels.warm_up()
warmed = signatures()
sequence = Sequence.open(sys.argv[1])
run = BuiltinTracker(SlamConfig(strategy="box_epipolar_flow")).run(FrameSource(sequence, None), False)
after = signatures()
print(run.keyframes, sorted(k for k in after if after[k] - warmed[k]))
"""


@pytest.mark.render
def test_warm_up_compiles_every_kernel_a_run_calls(walking_seq: Path):
    """A kernel warm_up leaves out is compiled inside the first frame that calls it, in every
    process that has no cache yet: the test workers started by make test, each sweep worker
    (14 s for all of them on a busy 2-core machine). A fresh process warms up, tracks 40
    frames of walking_xyz with local mapping and method 3, and no top-level kernel gains a
    signature (kernels called only from other kernels compile inside their callers)."""
    result = subprocess.run(
        [sys.executable, "-c", WARMED_THEN_TRACKED, str(walking_seq)],
        capture_output=True, text=True, timeout=300, check=False, cwd=REPO, env=_environment(),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    keyframes, _, compiled_later = result.stdout.strip().partition(" ")
    assert int(keyframes) >= 3  # local mapping ran
    assert compiled_later == "[]"


@pytest.mark.render
def test_a_run_with_a_bad_switch_stops_in_one_line(walking_seq: Path, tmp_path: Path, path, capsys):
    from depotbench.eval.cli.main import main

    path("fast")
    code = main(["run", str(walking_seq), "--strategy", "none", "-o", str(tmp_path / "run")])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith("DEPOTBENCH_KERNELS='fast': choose numpy or numba"), err
    assert "Traceback" not in "\n".join(err)
    assert not (tmp_path / "run").exists()
