"""The example external trackers (assets/examples/external) speak the protocol of
docs/external-trackers.md: run as programs on the files the bench would hand them, the
wrapped built-in tracker gives the built-in run exactly, and my_slam.py tracks and rejects
what lies in dynamic boxes. The bench's engine is not involved: each test writes the
program's inputs with depotbench.eval.trackers.protocol and reads its outputs back itself."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from depotbench.detectors.config import DetectorConfig, parse_detector
from depotbench.detectors.detection import Detection, Prior
from depotbench.eval.metrics.evaluate import ComparisonOptions, compare
from depotbench.eval.metrics.trajectory import Trajectory, read_tum
from depotbench.eval.run.cache import StageCache
from depotbench.eval.run.detections import detect_sequence
from depotbench.eval.run.harness import RunJob, Tracked, track
from depotbench.eval.sweep.spec import threshold_value
from depotbench.eval.trackers.builtin import true_moving_labels
from depotbench.eval.trackers.protocol import (
    read_detections,
    read_keypoints,
    write_detections,
    write_keypoints,
)
from depotbench.scenes import library
from depotbench.scenes.schema import Image, IntrinsicsSpec, to_scenario
from depotbench.sim.sequence import Sequence
from depotbench.sim.tum_files import read_pose_file
from depotbench.slam.types import REJECTION_CODES, Rejection

from tests.sequences import write_sequence

EXAMPLES = Path(__file__).resolve().parents[1] / "assets" / "examples" / "external"
FRAMES = 20
SMALL = {
    "smoke": None,  # already 160x120
    "walking_static": (320, 240),
    "dog_and_cat_roaming": (320, 240),
}
"""Scenario name: image size (fx scaled with it), small enough for a run of about a second."""
FAULTED = {"miss": "0.3", "jitter": "0.05", "false_positives": "0.5", "latency": "1"}


@pytest.fixture(scope="module")
def generated(tmp_path_factory) -> Callable[[str], Path]:
    """Each small sequence generated once, the first time a test asks for it."""
    from depotbench.sim.generate import generate

    made: dict[str, Path] = {}

    def get(name: str) -> Path:
        if name not in made:
            update: dict = {"frames": FRAMES, "duration_s": None}
            if SMALL[name] is not None:
                width, height = SMALL[name]
                update["image"] = Image(width=width, height=height)
                update["intrinsics"] = IntrinsicsSpec(fx=525.0 * width / 640)
            scenario = library.get(name).model_copy(update=update)
            made[name] = generate(to_scenario(scenario), tmp_path_factory.mktemp(name) / name, progress=False)
        return made[name]

    return get


def run_program(argv: list[str]) -> subprocess.CompletedProcess:
    """Run an example as the bench does: its own process, frames done on stderr."""
    done = subprocess.run(
        [sys.executable, *argv], capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done


def last_count(stderr: str) -> int:
    """The last plain-integer line of stderr: what the bench's progress bar shows."""
    return int([line for line in stderr.splitlines() if line.strip().isdigit()][-1])


def rejection_figures(kept: list[np.ndarray], labels: list[np.ndarray]) -> dict:
    """Rejection as a classification of keypoints against their true moving labels,
    computed as depotbench.eval.run.harness._rejection computes it for the built-in run."""
    rejected, moving = ~np.concatenate(kept), np.concatenate(labels)
    true_positive = int((rejected & moving).sum())
    return {
        "keypoints": len(moving),
        "moving_keypoints": int(moving.sum()),
        "rejected_keypoints": int(rejected.sum()),
        "precision": true_positive / int(rejected.sum()) if rejected.any() else None,
        "recall": true_positive / int(moving.sum()) if moving.any() else None,
    }


def moving_labels(sequence: Sequence, keypoints_px: tuple[np.ndarray, ...]) -> list[np.ndarray]:
    """Each keypoint labelled by the exact ground truth, as the bench labels a program's."""
    objects = sequence.objects()
    return [
        true_moving_labels(sequence, i, points, {o.instance_id for o in objects[i] if o.moving})
        for i, points in enumerate(keypoints_px)
    ]


SLOW = pytest.mark.slow
CASES = [
    # (scenario, strategy, detector faults, parameters as a sweep writes them to JSON); the
    # default run keeps one case a scenario that together hold both strategies, both
    # detectors and the whole-float setting
    pytest.param("smoke", "box_rule", None, {}, marks=SLOW),
    ("smoke", "box_epipolar_flow", FAULTED, {"epsilon_px": 0.5}),
    pytest.param(
        "walking_static", "box_rule", FAULTED, {"box_dilation_px": 4.0, "min_confidence": 0.6}, marks=SLOW
    ),
    ("walking_static", "box_epipolar_flow", None, {}),
    ("dog_and_cat_roaming", "box_rule", None, {"n_features": 600.0}),  # a whole float: an int setting
    pytest.param(
        "dog_and_cat_roaming", "box_epipolar_flow", FAULTED, {"l_thr1_px": 1.5, "n_features": 800}, marks=SLOW
    ),
]


@pytest.mark.render
@pytest.mark.parametrize(
    ("scenario", "strategy", "faults", "parameters"),
    CASES,
    ids=[
        f"{c[0]}-{c[1]}-{'faulted' if c[2] else 'groundtruth'}"
        for c in (case.values if hasattr(case, "values") else case for case in CASES)
    ],
)
def test_the_wrapped_builtin_tracker_gives_the_builtin_run_exactly(
    generated, tmp_path: Path, scenario: str, strategy: str, faults: dict | None, parameters: dict
):
    root = generated(scenario)
    sequence = Sequence.open(root)
    detector = parse_detector("groundtruth", faults=faults) if faults else DetectorConfig()
    detections = detect_sequence(sequence, detector)
    files = {name: tmp_path / name for name in ("detections", "parameters", "trajectory", "keypoints")}
    write_detections(files["detections"], sequence, detections.per_frame)
    files["parameters"].write_text(json.dumps({"strategy": strategy, **parameters}), encoding="utf-8")
    done = run_program(
        [str(EXAMPLES / "builtin_tracker.py"), "--sequence", str(root)]
        + [arg for name, path in files.items() for arg in (f"--{name}", str(path))]
    )
    settings = tuple(sorted((name, threshold_value(name, value)) for name, value in parameters.items()))
    # The bench's run, on cached stages as its sweeps use them (tests/test_stages.py: bit
    # for bit the live run).
    builtin = track(RunJob(root, strategy, detector, settings), StageCache(tmp_path / "cache"))

    assert last_count(done.stderr) == len(sequence)
    _assert_same_trajectory(files["trajectory"], builtin, sequence)
    _assert_same_decisions(files["keypoints"], builtin, sequence)


def _assert_same_trajectory(path: Path, builtin: Tracked, sequence: Sequence) -> None:
    """Pose for pose: timestamps and positions equal; rotations cross the file as
    quaternions, which equal the run's own, and so do the rotations the bench makes of
    them. The ATE, of positions only, is the built-in run's to the last bit."""
    expected = builtin.run.trajectory()
    estimate = read_tum(path)
    assert np.array_equal(estimate.timestamps_s, expected.timestamps_s)
    assert np.array_equal(estimate.positions_m, expected.positions_m)
    assert np.array_equal(read_pose_file(path, strict=False).quats_xyzw, expected.quats_xyzw)
    as_read = Trajectory.from_quaternions(expected.timestamps_s, expected.positions_m, expected.quats_xyzw)
    assert np.array_equal(estimate.rotations, as_read.rotations)
    gt = sequence.groundtruth
    reference = Trajectory.from_quaternions(gt.timestamps_s, gt.positions_m, gt.quats_xyzw, "groundtruth")
    assert compare(reference, estimate, ComparisonOptions()).to_dict()["ate_m"] == builtin.metrics["ate_m"]


def _assert_same_decisions(path: Path, builtin: Tracked, sequence: Sequence) -> None:
    """Every keypoint and decision of every frame, and so the same precision and recall."""
    decisions = read_keypoints(path, sequence)
    results = builtin.run.results
    kept_code = REJECTION_CODES[Rejection.KEPT]
    names = {code: reason.value for reason, code in REJECTION_CODES.items()}
    for i, result in enumerate(results):
        codes = result.diagnostics.rejection
        assert np.array_equal(decisions.keypoints_px[i], result.diagnostics.keypoints_px)
        assert np.array_equal(decisions.kept[i], codes == kept_code)
        assert decisions.reasons[i] == tuple("" if c == kept_code else names[int(c)] for c in codes)
    figures = rejection_figures(list(decisions.kept), moving_labels(sequence, decisions.keypoints_px))
    assert figures == {key: builtin.metrics["rejection"][key] for key in figures}
    assert figures["rejected_keypoints"] > 0 and figures["moving_keypoints"] > 0  # not vacuous


@pytest.mark.render
def test_my_slam_tracks_and_rejects_every_keypoint_in_a_dynamic_box(generated, tmp_path: Path):
    root = generated("smoke")
    sequence = Sequence.open(root)
    detections = detect_sequence(sequence, DetectorConfig())
    write_detections(tmp_path / "detections.txt", sequence, detections.per_frame)
    (tmp_path / "camera.yaml").write_text((root / "camera.yaml").read_text(), encoding="utf-8")
    margin = 3.0
    done = run_program(
        [str(EXAMPLES / "my_slam.py"), str(root), str(root / "associations.txt")]
        + [str(tmp_path / name) for name in ("camera.yaml", "detections.txt", "trajectory.txt", "kp.txt")]
        + ["--box-margin", str(margin)]
    )
    assert last_count(done.stderr) == len(sequence)

    estimate = read_tum(tmp_path / "trajectory.txt")
    gt = sequence.groundtruth
    reference = Trajectory.from_quaternions(gt.timestamps_s, gt.positions_m, gt.quats_xyzw)
    assert len(estimate) == len(sequence)
    ate_m = compare(reference, estimate, ComparisonOptions()).to_dict()["ate_m"]["rmse"]
    assert ate_m < 0.1  # it tracks: 2.6 cm when written

    decisions = read_keypoints(tmp_path / "kp.txt", sequence)
    rejected_any = False
    for i, boxes in enumerate(detections.per_frame):
        dynamic = [d.box_xyxy for d in boxes if d.prior is Prior.DYNAMIC]
        inside, near_edge = _in_boxes(decisions.keypoints_px[i], dynamic, margin)
        assert len(decisions.keypoints_px[i]) > 0
        assert np.array_equal(~decisions.kept[i][~near_edge], inside[~near_edge])
        assert decisions.reasons[i] == tuple("" if k else "box" for k in decisions.kept[i])
        rejected_any |= bool(inside.any())
    assert rejected_any


def _in_boxes(points: np.ndarray, boxes: list, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Which keypoints lie inside a box grown by ``margin`` (a keypoint's pixel-edge
    coordinate is its position + 0.5), and which lie within the file's 3 decimals of an
    edge, where the written position cannot say which side the program saw."""
    inside = np.zeros(len(points), bool)
    near = np.zeros(len(points), bool)
    x, y = points[:, 0] + 0.5, points[:, 1] + 0.5
    for x0, y0, x1, y1 in boxes:
        inside |= (x >= x0 - margin) & (x < x1 + margin) & (y >= y0 - margin) & (y < y1 + margin)
        for value, edge in ((x, x0 - margin), (x, x1 + margin), (y, y0 - margin), (y, y1 + margin)):
            near |= np.abs(value - edge) < 1e-3
    return inside, near


def test_detections_and_keypoints_cross_their_files_exactly(tmp_path: Path):
    """Write then read gives the same Detection objects and the same arrays, bit for bit:
    faulted boxes, NumPy floats (false positives are made of them), a class name with a
    space, keypoints at any float (read back as the float32 nearest, as OpenCV keeps them)."""
    write_sequence(tmp_path / "seq", n=4)
    sequence = Sequence.open(tmp_path / "seq")
    faults = {"jitter": "0.1", "false_positives": "1"}
    faulted = detect_sequence(sequence, parse_detector("groundtruth", faults=faults)).per_frame
    box = (np.float64(0.1) + 0.2, 1 / 3, np.float64(40.0), 47.999999999999)
    table = Detection(box, "dining table", Prior.POTENTIAL, np.float64(0.61))
    per_frame = (faulted[0] + (table,), (), faulted[2], faulted[3])
    write_detections(tmp_path / "detections.txt", sequence, per_frame)
    assert read_detections(tmp_path / "detections.txt", sequence) == per_frame

    rng = np.random.default_rng(0)
    width, height = sequence.intrinsics.width, sequence.intrinsics.height
    points = [rng.uniform([-0.5, -0.5], [width - 0.5, height - 0.5], (n, 2)) for n in (5, 0, 3, 7)]
    points[2] = points[2].astype(np.float32)  # OpenCV's keypoints are float32
    kept = [rng.random(len(p)) < 0.5 for p in points]
    reasons = [["" if k else "box" for k in flags] for flags in kept]
    stamps = [f.timestamp_s for f in sequence.frames]
    write_keypoints(tmp_path / "keypoints.txt", stamps, points, kept, reasons)
    back = read_keypoints(tmp_path / "keypoints.txt", sequence)
    # positions are kept as float32 (OpenCV's own): float32 ones come back bit for bit
    assert np.array_equal(back.keypoints_px[2], points[2])
    pairs = zip(back.keypoints_px, points, strict=True)
    assert all(np.array_equal(a, b.astype(np.float32)) for a, b in pairs)
    assert all(np.array_equal(a, b) for a, b in zip(back.kept, kept, strict=True))
    assert back.reasons == tuple(tuple(r) for r in reasons)
