"""``export-rosbag`` takes a real folder's camera as ``run`` does (``--camera FILE``,
``--intrinsics``, ``--distortion``, ``--depth-factor``) and never writes a guessed one into
CameraInfo: a folder without camera.yaml and without a camera flag is refused in one line.

The bag is read back with ``rosbags``' AnyReader, decoding with the definitions stored in the
bag; expected numbers are the flags' and the file's, written here."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from depotbench.core.camera import Intrinsics
from depotbench.eval.cli.main import EXIT_INPUT_ERROR
from depotbench.sim.camera import orbslam_yaml

from tests.test_rosbag import listing, one_error_line, read_rosbags, run_cli, write_sequence

DEPTH_RAW = 6000
"""Every depth pixel's PNG value: 1.2 m at TUM's 5000 per metre, 6 m at 1000."""


def tum_folder(root: Path, width: int, height: int, frames: int = 3, start_s: float = 1.0) -> Path:
    """A real TUM-layout folder with no camera.yaml: flat images (a few kB each), depth
    ``DEPTH_RAW`` everywhere, ground truth at the frames' times (30 Hz from ``start_s``)."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_lines, depth_lines, gt_lines = [], [], []
    for k in range(frames):
        t = f"{start_s + k / 30:.6f}"
        cv2.imwrite(str(root / "rgb" / f"{t}.png"), np.full((height, width, 3), 40 * k, np.uint8))
        cv2.imwrite(str(root / "depth" / f"{t}.png"), np.full((height, width), DEPTH_RAW, np.uint16))
        rgb_lines.append(f"{t} rgb/{t}.png")
        depth_lines.append(f"{t} depth/{t}.png")
        gt_lines.append(f"{t} {k * 0.1:.4f} 0 0 0 0 0 1")
    for name, lines in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines), ("groundtruth.txt", gt_lines)):
        (root / name).write_text("# timestamp data\n" + "\n".join(lines) + "\n")
    return root


def camera_infos(bag: Path) -> list:
    messages, _ = read_rosbags(bag)
    return [
        m for topic in ("/camera/color/camera_info", "/camera/depth/camera_info") for _, m in messages[topic]
    ]


def test_a_folder_without_camera_yaml_or_flag_is_refused_naming_the_flags(tmp_path: Path, capsys):
    """Kinect-sized images once took the ROS default (fx 525) into CameraInfo, silently."""
    root = tum_folder(tmp_path / "office", 640, 480)
    code, _, err = run_cli(capsys, root, "-o", tmp_path / "bag")
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, str(root), "camera.yaml", "--camera FILE", "--intrinsics FX FY CX CY")
    assert listing(tmp_path) == ["office"]


def test_a_folder_named_for_a_tum_sensor_is_refused_with_that_sensor_s_flags(tmp_path: Path, capsys):
    """TUM publishes freiburg1's calibration (vision.in.tum.de, "Intrinsic Camera Calibration")."""
    root = tum_folder(tmp_path / "rgbd_dataset_freiburg1_xyz", 640, 480)
    code, _, err = run_cli(capsys, root, "-o", tmp_path / "bag")
    assert code == EXIT_INPUT_ERROR
    one_error_line(
        err,
        "--camera FILE",
        "--intrinsics 517.3 516.5 318.6 255.3 --distortion 0.2624 -0.9531 -0.0054 0.0026 1.1633",
    )
    assert listing(tmp_path) == ["rgbd_dataset_freiburg1_xyz"]


def test_intrinsics_distortion_and_depth_factor_flags_reach_camera_info_and_depth(tmp_path: Path, capsys):
    """A 320x240 folder (not the default's size) exports without writing a camera.yaml."""
    root = tum_folder(tmp_path / "office", 320, 240)
    bag = tmp_path / "bag"
    code, out, err = run_cli(
        capsys, root, "-o", bag, "--intrinsics", "400", "401", "160.5", "120.25",
        "--distortion", "0.1", "-0.2", "0.001", "0.002", "--depth-factor", "1000",
    )  # fmt: skip
    assert code == 0, err
    infos = camera_infos(bag)
    assert len(infos) == 6
    for info in infos:
        assert (info.width, info.height) == (320, 240)
        np.testing.assert_array_equal(info.k, [400, 0, 160.5, 0, 401, 120.25, 0, 0, 1])
        np.testing.assert_array_equal(info.d, [0.1, -0.2, 0.001, 0.002, 0.0])  # OpenCV's k3: 0
        assert info.distortion_model == "plumb_bob"
    messages, _ = read_rosbags(bag)
    depth = np.frombuffer(bytes(messages["/camera/depth/image"][0][1].data), "<f4")
    np.testing.assert_allclose(depth, DEPTH_RAW / 1000)


def test_a_camera_file_gives_the_whole_camera(tmp_path: Path, capsys):
    root = tum_folder(tmp_path / "office", 640, 480)
    camera = tmp_path / "kinect.yaml"
    given = Intrinsics(
        517.3, 516.5, 318.6, 255.3, 640, 480, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633), 5000.0
    )
    camera.write_text(orbslam_yaml(given))
    code, _, err = run_cli(capsys, root, "-o", tmp_path / "bag", "--camera", camera)
    assert code == 0, err
    for info in camera_infos(tmp_path / "bag"):
        assert (info.width, info.height) == (640, 480)
        np.testing.assert_allclose(info.k, [517.3, 0, 318.6, 0, 516.5, 255.3, 0, 0, 1])
        np.testing.assert_allclose(info.d, given.distortion)


def test_a_depth_factor_alone_leaves_the_calibration_a_guess_and_is_refused(tmp_path: Path, capsys):
    root = tum_folder(tmp_path / "office", 640, 480)
    code, _, err = run_cli(capsys, root, "-o", tmp_path / "bag", "--depth-factor", "1000")
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, "--intrinsics FX FY CX CY")


def test_a_generated_sequence_keeps_its_own_camera(tmp_path: Path, capsys):
    seq = tmp_path / "seq"
    write_sequence(seq, n=2)
    code, _, err = run_cli(capsys, seq, "-o", tmp_path / "bag", "--intrinsics", "400", "400", "32", "24")
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, "keeps its own camera")
    assert listing(tmp_path) == ["seq"]


@pytest.mark.parametrize(
    "flags", [("--intrinsics", "0", "400", "1", "1"), ("--distortion", "0.1", "0", "0", "0")]
)
def test_bad_camera_flags_are_one_line(tmp_path: Path, capsys, flags: tuple[str, ...]):
    root = tum_folder(tmp_path / "office", 64, 48, frames=1)
    code, _, err = run_cli(capsys, root, "-o", tmp_path / "bag", *flags)
    assert code == EXIT_INPUT_ERROR
    one_error_line(err)
    assert listing(tmp_path) == ["office"]
