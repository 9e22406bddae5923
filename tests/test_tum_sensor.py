"""The TUM sensor profile (issue 51), each effect against something it does not compute:
the published depth-noise model's numbers, closed forms for the rolling shutter and the
blur, TUM's association rule re-implemented here from its description, and the
configured spreads of the recorded ground truth."""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np
import pytest
from depotbench.scenes.schema import TUM_SENSOR, Sensor, sensor_spec
from depotbench.sim.generate import generate
from depotbench.sim.sensor import SensorClock, SensorModel
from depotbench.sim.sequence import Sequence
from depotbench.sim.spec import ScenarioSpec, SensorSpec, default_scenario
from scipy.spatial.transform import Rotation


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed))


@pytest.mark.parametrize(
    ("depth_m", "published_sigma_m"),
    # Nguyen, Izadi and Lovell (2012), sigma_z = 0.0012 + 0.0019 (z - 0.4)^2, worked by hand.
    [(1.0, 0.001884), (2.0, 0.006064), (3.0, 0.014044)],
)
def test_depth_noise_spread_is_the_published_one(depth_m: float, published_sigma_m: float) -> None:
    model = SensorModel(SensorSpec(depth_noise=True), _rng(1))
    readings = model.depth(np.full((200, 200), depth_m, np.float32))
    assert abs(readings.mean() - depth_m) < 4 * published_sigma_m / 200
    assert readings.std() == pytest.approx(published_sigma_m, rel=0.02)


def test_disparity_quantisation_leaves_only_disparity_steps() -> None:
    model = SensorModel(SensorSpec(depth_noise=True, disparity_quantisation=True), _rng(2))
    readings = model.depth(np.full((100, 100), 3.0, np.float32)).astype(np.float64)
    steps = 580.0 * 0.075 / readings * 8  # Kinect focal x baseline / z, in 1/8 px
    assert np.allclose(steps, np.round(steps), atol=1e-3)
    assert readings.std() > 0.014  # quantisation adds to the noise, never removes it


def _edge_image(h: int = 120, w: int = 160, edge: int = 80) -> np.ndarray:
    image = np.zeros((h, w, 3), np.uint8)
    image[:, edge:] = 200
    return image


def _crossings(image: np.ndarray, bright: float = 200.0) -> np.ndarray:
    """Per row, the sub-pixel column where a dark-to-bright step is half way: the dark area
    left of it (a step interpolated over one pixel, read by its area, not by its samples)."""
    red = image[:, :, 0].astype(np.float64)
    return (1.0 - red / bright).sum(axis=1) - 0.5


def test_rolling_shutter_moves_each_row_by_its_readout_delay() -> None:
    """A pan moving everything 12 px per frame: row r is read (r/(h-1) - 1/2) x readout
    after the middle row, so its edge sits that much further along: the closed form."""
    fps, readout, speed = 30.0, 0.030, 12.0
    image = _edge_image()
    flow = np.zeros((*image.shape[:2], 2), np.float32)
    flow[..., 0] = speed
    model = SensorModel(SensorSpec(rolling_shutter_readout_s=readout), _rng())
    shutter = model.rgb(image, flow, fps)
    h = image.shape[0]
    expected = 80 - 0.5 + (np.arange(h) / (h - 1) - 0.5) * readout * fps * speed
    assert np.abs(_crossings(shutter) - expected).max() < 0.05
    assert _crossings(shutter)[-1] - _crossings(shutter)[0] == pytest.approx(readout * fps * speed, abs=0.1)


def test_blur_smears_a_point_over_its_motion_during_the_exposure() -> None:
    """A point moving 30 px per frame seen for 10 ms at 30 Hz smears over 9 px, centred on it."""
    fps, exposure, speed = 30.0, 0.010, 30.0
    image = np.zeros((20, 80, 3), np.uint8)
    image[10, 40] = 255
    flow = np.zeros((20, 80, 2), np.float32)
    flow[..., 0] = speed
    blurred = SensorModel(SensorSpec(motion_blur_exposure_s=exposure), _rng()).rgb(image, flow, fps)
    row = blurred[10, :, 0].astype(np.float64)
    lit = np.flatnonzero(row > 0)
    length = exposure * fps * speed
    assert lit[-1] - lit[0] == pytest.approx(length, abs=1.5)
    assert (row * np.arange(80)).sum() / row.sum() == pytest.approx(40.0, abs=0.1)
    assert row.sum() == pytest.approx(255, rel=0.05)  # the light is spread, not lost


def _tum_associate(rgb: np.ndarray, depth: np.ndarray, max_difference: float = 0.02) -> list[tuple[int, int]]:
    """TUM's associate.py, from its description: every pair closer than max_difference,
    taken closest first, each stamp used once."""
    pairs = sorted((abs(a - b), i, j) for i, a in enumerate(rgb) for j, b in enumerate(depth))
    used_a, used_b, matches = set(), set(), []
    for diff, i, j in pairs:
        if diff < max_difference and i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            matches.append((i, j))
    return sorted(matches)


def test_depth_delay_is_recovered_by_tums_association(tmp_path: Path) -> None:
    sensor = SensorSpec(depth_delay_mean_s=0.004, timestamp_jitter_s=0.0015, dropped_frame_rate=0.1)
    sequence = _generate(tmp_path / "seq", sensor, frames=30)
    rgb = np.loadtxt(sequence.root / "rgb.txt", usecols=0)
    depth = np.loadtxt(sequence.root / "depth.txt", usecols=0)
    pairs = _tum_associate(rgb, depth)
    assert len(pairs) == len(rgb) == len(sequence)
    offsets = np.array([depth[j] - rgb[i] for i, j in pairs])
    clock = SensorClock(sensor, 30, 30.0, _clock_rng(sensor))
    kept = ~clock.dropped
    assert np.allclose(offsets, clock.depth_delays[kept], atol=2e-6)
    assert np.all(offsets >= 0) and offsets.max() <= 0.25 / 30 + 2e-6  # stamps keep 6 decimals
    assert [f.depth_timestamp_s - f.timestamp_s for f in sequence.frames] == pytest.approx(offsets, abs=2e-6)


def _clock_rng(sensor: SensorSpec) -> np.random.Generator:
    """The clock's own stream, as generate draws it: the sensor stream's second spawned child."""
    from depotbench.sim.world import scenario_streams

    model = SensorModel(sensor, scenario_streams(_SEED)[4])
    return np.random.default_rng(model._timing_seed)


_SEED = 5


def _scenario(sensor: SensorSpec, frames: int) -> ScenarioSpec:
    base = default_scenario(frames=frames, seed=_SEED)
    return dataclasses.replace(base, width=96, height=72, focal_px=78.75, sensor=sensor)


def _generate(out: Path, sensor: SensorSpec, frames: int) -> Sequence:
    generate(_scenario(sensor, frames), out, progress=False)
    return Sequence.open(out)


def test_dropped_frames_are_absent_and_the_rate_is_the_configured_one(tmp_path: Path) -> None:
    sensor = SensorSpec(dropped_frame_rate=0.035)
    clock = SensorClock(sensor, 20000, 30.0, _rng(3))
    share = clock.dropped.mean()
    assert abs(share - 0.035) < 4 * np.sqrt(0.035 * 0.965 / 20000)
    assert not clock.dropped[0]
    lossy = SensorSpec(dropped_frame_rate=0.3)
    sequence = _generate(tmp_path / "drop", lossy, frames=20)
    kept = np.round((sequence.timestamps_s - sequence.timestamps_s[0]) * 30).astype(int)
    assert list(kept) == list(np.flatnonzero(~SensorClock(lossy, 20, 30.0, _clock_rng(lossy)).dropped))
    assert len(sequence) < 20 and len(sequence.groundtruth.timestamps_s) == len(sequence)


def test_recorded_ground_truth_has_the_configured_noise_and_offset() -> None:
    sensor = SensorSpec(gt_position_noise_m=0.001, gt_rotation_noise_deg=0.1)
    clock = SensorClock(sensor, 5000, 30.0, _rng(4))
    poses = np.array([clock.recorded_pose(k, np.eye(4)) for k in range(5000)])
    assert poses[:, :3, 3].std(axis=0) == pytest.approx([0.001] * 3, rel=0.05)
    angles = np.degrees(Rotation.from_matrix(poses[:, :3, :3]).as_rotvec())
    assert angles.std(axis=0) == pytest.approx([0.1] * 3, rel=0.05)
    timed = SensorClock(SensorSpec(gt_time_offset_s=0.005, gt_rate_hz=100.0), 300, 30.0, _rng(5))
    residual = timed.recorded - (timed.stamps + 0.005)
    assert np.abs(residual).max() <= 0.005 + 1e-12  # the nearest 100 Hz sample
    assert np.allclose(timed.recorded * 100, np.round(timed.recorded * 100))


def test_white_balance_drift_has_its_stationary_spread() -> None:
    model = SensorModel(SensorSpec(white_balance_drift=0.02), _rng(6))
    logs = np.array([np.log(model._white_balance(30.0)) for _ in range(30000)])
    assert logs.std(axis=0) == pytest.approx([0.02] * 3, rel=0.1)
    lag = np.mean([np.corrcoef(logs[:-30, c], logs[30:, c])[0, 1] for c in range(3)])
    assert lag == pytest.approx(np.exp(-1.0), abs=0.05)  # a one-second correlation time


def _digest(root: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file() and p.name != "meta.json"):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


@pytest.mark.slow
def test_tum_profile_is_byte_identical_per_seed_and_keeps_the_exact_truth(tmp_path: Path) -> None:
    tum = sensor_spec("tum")
    first = _generate(tmp_path / "a", tum, frames=12)
    second = _generate(tmp_path / "b", tum, frames=12)
    assert _digest(first.root) == _digest(second.root)
    clean = _generate(tmp_path / "clean", SensorSpec(), frames=12)
    assert not (clean.root / "gt" / "camera_poses.txt").exists()
    # The exact truth: each frame's pose at its capture, as the clean sequence has it.
    capture = {round(t, 3): k for k, t in enumerate(clean.timestamps_s)}
    for index, stamp in enumerate(first.timestamps_s):
        k = min(capture, key=lambda t: abs(t - stamp))
        assert np.allclose(first.world_from_camera(index), clean.world_from_camera(capture[k]), atol=1e-6)
    recorded = first.groundtruth.positions_m - np.array(
        [first.world_from_camera(i)[:3, 3] for i in range(len(first))]
    )
    assert 0 < np.abs(recorded).max() < 0.02  # noise and a 5 ms offset: millimetres


def test_tum_preset_is_kinect_plus_the_documented_fields() -> None:
    tum, kinect = Sensor.tum(), Sensor.kinect()
    changed = {k for k, v in tum.model_dump().items() if kinect.model_dump()[k] != v}
    assert changed == set(TUM_SENSOR)
    docs = (Path(__file__).parents[1] / "docs" / "scenarios.md").read_text(encoding="utf-8")
    assert all(f"`{name}`" in docs for name in TUM_SENSOR)
