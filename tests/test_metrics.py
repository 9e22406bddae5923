"""Our ATE/RPE against evo on constructed cases, randomised cases, and real TUM data."""

from __future__ import annotations

import numpy as np
import pytest
from depotbench.core.errors import InputError
from depotbench.eval.metrics.accuracy import DeltaUnit, Statistics, ate, improvement_rate, rpe
from depotbench.eval.metrics.alignment import Alignment, AlignmentError
from depotbench.eval.metrics.evaluate import ComparisonOptions, compare
from depotbench.eval.metrics.trajectory import AssociationError, Trajectory, associate, read_tum
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.evo_reference import evo_ape, evo_rpe

REL = 1e-6
STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def assert_stats_match(ours: Statistics, reference: dict) -> None:
    for key in STATS:
        assert getattr(ours, key) == pytest.approx(reference[key], rel=REL, abs=1e-12), key


def handheld(n: int = 300, seed: int = 0, rate_hz: float = 30.0, t0: float = 1000.0) -> Trajectory:
    """A smooth hand-held-like trajectory: sinusoidal translation and rotation."""
    rng = np.random.default_rng(seed)
    t = t0 + np.arange(n) / rate_hz
    phase = rng.uniform(0, 2 * np.pi, size=6)
    s = np.arange(n) / rate_hz
    positions = np.stack(
        [
            0.4 * np.sin(0.7 * s + phase[0]),
            0.2 * np.sin(1.1 * s + phase[1]),
            1.5 + 0.3 * np.sin(0.5 * s),
        ],
        axis=1,
    )
    rotvec = np.stack(
        [
            0.2 * np.sin(0.9 * s + phase[3]),
            0.3 * np.sin(0.6 * s + phase[4]),
            0.1 * np.sin(1.3 * s + phase[5]),
        ],
        axis=1,
    )
    return Trajectory(t, positions, Rotation.from_rotvec(rotvec).as_matrix())


def transformed(traj: Trajectory, rotation: np.ndarray, translation: np.ndarray, scale: float = 1.0):
    return Trajectory(
        traj.timestamps_s.copy(),
        scale * traj.positions_m @ rotation.T + translation,
        np.einsum("ij,njk->nik", rotation, traj.rotations),
    )


def noisy(traj: Trajectory, seed: int, sigma_m: float = 0.01, sigma_rad: float = 0.01) -> Trajectory:
    rng = np.random.default_rng(seed)
    noise_rot = Rotation.from_rotvec(rng.normal(0, sigma_rad, (len(traj), 3))).as_matrix()
    return Trajectory(
        traj.timestamps_s.copy(),
        traj.positions_m + rng.normal(0, sigma_m, traj.positions_m.shape),
        noise_rot @ traj.rotations,
    )


def our_ate(ref, est, align: Alignment, max_diff: float = 0.02):
    r, e = associate(ref, est, max_diff)
    return ate(r, e, align)


def our_rpe(ref, est, delta, unit: DeltaUnit, all_pairs: bool, align=Alignment.NONE):
    r, e = associate(ref, est)
    return rpe(r, e, delta, unit, all_pairs, align)


def test_pure_offset_closed_form_and_evo():
    ref = handheld()
    est = transformed(ref, np.eye(3), np.array([0.3, -0.4, 0.0]))
    result = our_ate(ref, est, Alignment.NONE)
    assert result.statistics.rmse == pytest.approx(0.5, rel=1e-12)
    assert result.statistics.std == pytest.approx(0.0, abs=1e-12)
    assert_stats_match(result.statistics, evo_ape(ref, est, "none"))
    assert our_ate(ref, est, Alignment.SE3).statistics.rmse < 1e-9


def test_rotation_about_origin():
    ref = handheld(seed=1)
    rotation = Rotation.from_euler("zyx", [40, -15, 10], degrees=True).as_matrix()
    est = noisy(transformed(ref, rotation, np.zeros(3)), seed=2, sigma_m=0.002)
    for align in ("none", "se3"):
        assert_stats_match(our_ate(ref, est, Alignment(align)).statistics, evo_ape(ref, est, align))
    # The rotation is undone by alignment, leaving only the noise.
    assert our_ate(ref, est, Alignment.SE3).statistics.rmse < 0.005


def test_sim3_scale():
    ref = handheld(seed=3)
    rotation = Rotation.from_euler("xyz", [5, 80, -30], degrees=True).as_matrix()
    est = noisy(transformed(ref, rotation, np.array([1.0, 2.0, -0.5]), scale=0.37), seed=4, sigma_m=0.001)
    result = our_ate(ref, est, Alignment.SIM3)
    assert_stats_match(result.statistics, evo_ape(ref, est, "sim3"))
    assert result.transform.scale == pytest.approx(1 / 0.37, rel=0.01)
    assert_stats_match(our_ate(ref, est, Alignment.SE3).statistics, evo_ape(ref, est, "se3"))


def test_per_frame_drift_ate_and_rpe():
    ref = handheld(seed=5)
    drift = np.cumsum(np.tile([0.0005, 0.0002, -0.0001], (len(ref), 1)), axis=0)
    yaw_drift = Rotation.from_euler("z", np.arange(len(ref))[:, None] * 0.02, degrees=True).as_matrix()
    est = Trajectory(ref.timestamps_s.copy(), ref.positions_m + drift, yaw_drift @ ref.rotations)
    assert_stats_match(our_ate(ref, est, Alignment.SE3).statistics, evo_ape(ref, est, "se3"))
    result = our_rpe(ref, est, 1, DeltaUnit.FRAMES, False)
    assert_stats_match(result.translation, evo_rpe(ref, est, 1, "frames", False, "trans"))
    assert_stats_match(result.rotation_deg, evo_rpe(ref, est, 1, "frames", False, "rot"))
    # Closed form: a constant yaw drift of 0.02 deg per frame gives that rotational RPE.
    assert result.rotation_deg.mean == pytest.approx(0.02, rel=1e-6)


@pytest.mark.parametrize("all_pairs", [False, True])
def test_rpe_in_metres(all_pairs):
    ref = handheld(seed=6, n=400)
    est = noisy(ref, seed=7, sigma_m=0.003, sigma_rad=0.004)
    result = our_rpe(ref, est, 0.25, DeltaUnit.METRES, all_pairs)
    assert_stats_match(result.translation, evo_rpe(ref, est, 0.25, "m", all_pairs, "trans"))
    assert_stats_match(result.rotation_deg, evo_rpe(ref, est, 0.25, "m", all_pairs, "rot"))


@pytest.mark.parametrize("delta", [1, 5, 17])
def test_rpe_all_pairs_frames(delta):
    ref = handheld(seed=8)
    est = noisy(ref, seed=9)
    result = our_rpe(ref, est, delta, DeltaUnit.FRAMES, True)
    assert len(result.pairs) == len(ref) - delta
    assert_stats_match(result.translation, evo_rpe(ref, est, delta, "frames", True, "trans"))
    assert_stats_match(result.rotation_deg, evo_rpe(ref, est, delta, "frames", True, "rot"))


def test_rpe_with_sim3_alignment_matches_evo():
    ref = handheld(seed=10)
    est = noisy(transformed(ref, np.eye(3), np.zeros(3), scale=2.0), seed=11)
    result = our_rpe(ref, est, 10, DeltaUnit.FRAMES, False, Alignment.SIM3)
    assert_stats_match(result.translation, evo_rpe(ref, est, 10, "frames", False, "trans", "sim3"))


def test_association_different_rates_and_jitter():
    """A 100 Hz reference against a jittered 30 Hz estimate, as with real mocap."""
    ref = handheld(n=1000, seed=12, rate_hz=100.0)
    est = noisy(handheld(n=300, seed=12, rate_hz=30.0), seed=13)
    rng = np.random.default_rng(14)
    est = Trajectory(est.timestamps_s + rng.uniform(-0.008, 0.008, len(est)), est.positions_m, est.rotations)
    assert_stats_match(our_ate(ref, est, Alignment.SE3).statistics, evo_ape(ref, est, "se3"))
    r, e = associate(ref, est, 0.002)
    assert len(r) == len(e) < len(est)
    assert np.all(np.abs(r.timestamps_s - e.timestamps_s) <= 0.002)


def test_association_without_overlap_is_an_input_error():
    ref = handheld(t0=0.0)
    est = handheld(t0=500.0)
    with pytest.raises(AssociationError, match="within 0.02 s"):
        associate(ref, est)


def test_degenerate_alignment_is_an_input_error():
    ref = handheld(n=10)
    still = Trajectory(ref.timestamps_s, np.zeros((10, 3)), ref.rotations)
    with pytest.raises(AlignmentError, match="degenerate"):
        ate(ref, still, Alignment.SE3)


def test_improvement_rate():
    assert improvement_rate(0.2, 0.05) == pytest.approx(75.0)
    assert improvement_rate(0.1, 0.2) == pytest.approx(-100.0)
    with pytest.raises(InputError):
        improvement_rate(0.0, 0.1)


def test_statistics_closed_form():
    s = Statistics.of(np.array([3.0, 4.0]))
    assert (s.rmse, s.mean, s.median, s.std, s.min, s.max, s.sse) == pytest.approx(
        (np.sqrt(12.5), 3.5, 3.5, 0.5, 3.0, 4.0, 25.0)
    )


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(12, 120),
    align=st.sampled_from(["none", "se3", "sim3"]),
    delta=st.integers(1, 8),
    all_pairs=st.booleans(),
    scale=st.floats(0.2, 5.0),
)
def test_randomised_against_evo(seed, n, align, delta, all_pairs, scale):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.01, 0.05, n))
    ref = Trajectory(t, rng.normal(0, 1, (n, 3)), Rotation.random(n, random_state=seed % 2**31).as_matrix())
    rotation = Rotation.random(random_state=(seed + 1) % 2**31).as_matrix()
    est = noisy(transformed(ref, rotation, rng.normal(0, 2, 3), scale), seed + 2, 0.05, 0.05)
    est = Trajectory(est.timestamps_s + rng.uniform(-0.004, 0.004, n), est.positions_m, est.rotations)
    assert_stats_match(our_ate(ref, est, Alignment(align), 0.005).statistics, evo_ape(ref, est, align, 0.005))
    r, e = associate(ref, est, 0.005)
    if len(r) > delta:
        result = rpe(r, e, delta, DeltaUnit.FRAMES, all_pairs, Alignment(align))
        assert_stats_match(
            result.translation, evo_rpe(ref, est, delta, "frames", all_pairs, "trans", align, 0.005)
        )
        assert_stats_match(
            result.rotation_deg, evo_rpe(ref, est, delta, "frames", all_pairs, "rot", align, 0.005)
        )


@pytest.mark.parametrize(
    ("reference", "estimate", "align", "rmse"),
    [
        ("freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt", "se3", 0.013473),
        ("freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt", "sim3", 0.013394),
        ("fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt", "se3", 0.008146),
    ],
)
def test_real_tum_reference_figures(tum_trajectories, reference, estimate, align, rmse):
    """The figures evo 1.38.1 and TUM's evaluate_ate.py print (shared/data README)."""
    ref = read_tum(tum_trajectories / reference)
    est = read_tum(tum_trajectories / estimate)
    result = compare(ref, est, ComparisonOptions(alignment=Alignment(align)))
    assert round(result.ate.statistics.rmse, 6) == rmse
    assert_stats_match(result.ate.statistics, evo_ape(ref, est, align))
    if reference.startswith("freiburg1"):
        assert result.pairs == 786


def test_real_tum_rpe_reference_figure(tum_trajectories):
    ref = read_tum(tum_trajectories / "freiburg1_xyz-groundtruth.txt")
    est = read_tum(tum_trajectories / "freiburg1_xyz-rgbdslam.txt")
    result = compare(ref, est, ComparisonOptions(alignment=Alignment.NONE))
    assert round(result.rpe.translation.rmse, 6) == 0.005759
    assert round(result.rpe.translation.mean, 6) == 0.004814
