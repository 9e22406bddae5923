"""A real TUM-layout folder's camera (issue 39 point 6): given by a settings file or by flags,
recorded in metrics.json, and, where none is given, a guess that the run names in one warning.

Checked against what is independent of the bench's reader: numbers typed here (TUM's
published fr1 calibration, tests.sequences.SMALL), OpenCV's own PNG decoder for the depth
read (depth_m = raw / factor), and the Brown-Conrady distortion written out in numpy.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from depotbench.core.camera import CameraOverride, CameraSource, Intrinsics
from depotbench.core.errors import InputError
from depotbench.detectors.config import DetectorConfig, DetectorKind
from depotbench.eval.cli import main as cli_main
from depotbench.eval.cli.camera import camera_from_args
from depotbench.eval.run.harness import RunJob, prepare
from depotbench.sim.camera import TUM_DEFAULT, read_camera_file
from depotbench.sim.sequence import Sequence, SequenceWriter

import depotbench
from tests.sequences import SMALL, random_frame, write_sequence

TUM_FILES = ("rgb", "depth", "rgb.txt", "depth.txt", "associations.txt", "groundtruth.txt")
"""What a real TUM folder holds: no camera.yaml, meta.json or gt/."""
FR1 = (517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633))
"""TUM's published freiburg1 calibration (vision.in.tum.de, "Intrinsic Camera Calibration")."""
NO_BOXES = DetectorConfig(DetectorKind.NONE)
"""A real folder has no ground truth to draw boxes from."""


def as_real(generated: Path, root: Path) -> Path:
    """A generated sequence's TUM files alone, in a folder named ``root``: it reads as a real one."""
    root.mkdir()
    for name in TUM_FILES:
        source = generated / name
        (shutil.copytree if source.is_dir() else shutil.copyfile)(source, root / name)
    return root


@pytest.fixture
def small_real(tmp_path: Path) -> Path:
    """4 frames of 64x48 (tests.sequences.SMALL) in a folder whose name names no TUM sensor."""
    write_sequence(tmp_path / "generated", n=4)
    return as_real(tmp_path / "generated", tmp_path / "my_recording")


def vga_real(tmp_path: Path, name: str, camera: Intrinsics = TUM_DEFAULT) -> Path:
    """3 random frames of 640x480, the size TUM's calibrations and the ROS default are for
    (or of ``camera``'s size)."""
    rng = np.random.default_rng(7)
    generated = tmp_path / f"{name}-generated"
    with SequenceWriter(generated, camera, fps=30.0, meta={"scenario": {"name": "vga"}}) as writer:
        for k in range(3):
            rgb, depth, pose, instances, objects, _ = random_frame(rng, k, camera)
            writer.add_frame(1.0 + k / 30.0, rgb, depth, pose, instances, objects)
    return as_real(generated, tmp_path / name)


def cli(argv: list[str]) -> int:
    """``depotbench run SEQUENCE ... --detector none`` through the real entry point (a real
    folder has no boxes to detect from)."""
    try:
        return cli_main.main(["run", *argv, "--detector", "none"])
    except SystemExit as exc:  # argparse's refusals
        return int(exc.code)


def metrics_camera(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())["camera"]


def one_line(err: str, kind: str) -> str:
    """The one line on stderr; argparse's own refusals come from the top parser (``depotbench:``)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith((f"depotbench run: {kind}: ", f"depotbench: {kind}: ")), lines[0]
    return lines[0]


# -- no camera given: a guess, said in one line --------------------------------------------------


def test_a_folder_named_like_no_tum_sensor_warns_once_and_records_the_ros_default(tmp_path, capsys):
    root = vga_real(tmp_path, "my_recording")
    assert cli([str(root), "-o", str(tmp_path / "run")]) == 0
    warning = one_line(capsys.readouterr().err, "warning")
    assert str(root) in warning and "no camera given" in warning
    assert "the ROS/Kinect default" in warning and "names no TUM sensor" in warning
    camera = metrics_camera(tmp_path / "run")
    assert (camera["fx"], camera["fy"], camera["cx"], camera["cy"]) == (525.0, 525.0, 319.5, 239.5)
    assert camera["depth_factor"] == 5000.0 and not any(camera["distortion"].values())
    assert camera["source"] == camera["depth_factor_source"] == "default"


def test_a_folder_named_freiburg1_warns_that_it_uses_tums_fr1_calibration(tmp_path, capsys):
    root = vga_real(tmp_path, "rgbd_dataset_freiburg1_xyz")
    assert cli([str(root), "-o", str(tmp_path / "run")]) == 0
    warning = one_line(capsys.readouterr().err, "warning")
    assert "TUM's freiburg1 calibration" in warning and "'rgbd_dataset_freiburg1_xyz'" in warning
    camera = metrics_camera(tmp_path / "run")
    fx, fy, cx, cy, distortion = FR1
    assert (camera["fx"], camera["fy"], camera["cx"], camera["cy"]) == (fx, fy, cx, cy)
    assert tuple(camera["distortion"][k] for k in ("k1", "k2", "p1", "p2", "k3")) == distortion
    assert camera["source"] == "tum"


def test_the_guess_is_said_once_per_folder_however_many_jobs_prepare_it(tmp_path, caplog):
    root = vga_real(tmp_path, "my_recording")
    with caplog.at_level(logging.WARNING, logger="depotbench"):
        for strategy in ("none", "box_rule", "none"):
            prepare(RunJob(root, strategy))
    assert [r.getMessage().count("no camera given") for r in caplog.records] == [1]


def test_a_guessed_camera_of_another_size_than_the_images_is_one_line_saying_what_to_give(
    small_real, tmp_path, capsys
):
    out = tmp_path / "run"
    assert cli([str(small_real), "-o", str(out)]) == 2
    line = one_line(capsys.readouterr().err, "error")
    assert "image is 64x48, but the camera guessed for the folder is 640x480" in line
    assert "--intrinsics FX FY CX CY" in line and not out.exists()


# -- a camera given ------------------------------------------------------------------------------


def test_intrinsics_flags_set_the_camera_metrics_json_records(small_real, tmp_path, capsys, caplog):
    out = tmp_path / "run"
    with caplog.at_level(logging.WARNING, logger="depotbench"):
        code = cli([str(small_real), "-o", str(out), "--intrinsics", "50", "51", "31.5", "23.25"])
    assert code == 0 and not caplog.records and "warning" not in capsys.readouterr().err
    camera = metrics_camera(out)
    assert (camera["fx"], camera["fy"], camera["cx"], camera["cy"]) == (50.0, 51.0, 31.5, 23.25)
    assert (camera["width"], camera["height"]) == (64, 48)  # from the images: flags give no size
    assert camera["source"] == "flags" and camera["detail"] == "--intrinsics"
    assert camera["depth_factor"] == 5000.0 and camera["depth_factor_source"] == "default"


def test_the_benchs_own_camera_yaml_as_camera_file_sets_its_camera(small_real, tmp_path):
    settings = tmp_path / "generated" / "camera.yaml"  # written by the bench from SMALL
    out = tmp_path / "run"
    assert cli([str(small_real), "-o", str(out), "--camera", str(settings)]) == 0
    camera = metrics_camera(out)
    k = SMALL
    assert (camera["fx"], camera["fy"], camera["cx"], camera["cy"]) == (k.fx, k.fy, k.cx, k.cy)
    assert (camera["width"], camera["height"], camera["depth_factor"]) == (k.width, k.height, 5000.0)
    assert camera["source"] == camera["depth_factor_source"] == "file"
    assert camera["detail"] == str(settings)


ORBSLAM3_V1 = """%YAML:1.0
File.version: "1.0"
Camera.type: "PinHole"
Camera1.fx: 517.3
Camera1.fy: 516.5
Camera1.cx: 318.6
Camera1.cy: 255.3
Camera1.k1: 0.2624
Camera1.k2: -0.9531
Camera1.p1: -0.0054
Camera1.p2: 0.0026
Camera1.k3: 1.1633
Camera.width: 640
Camera.height: 480
Camera.fps: 30
Camera.RGB: 1
Stereo.ThDepth: 40.0
Stereo.b: 0.07732
RGBD.DepthMapFactor: 5000.0
"""
"""ORB-SLAM3's own Examples/RGB-D/TUM1.yaml in its second format, as its users have it."""


def test_an_orbslam3_settings_file_in_its_second_format_gives_tums_fr1_camera(tmp_path):
    path = tmp_path / "TUM1.yaml"
    path.write_text(ORBSLAM3_V1)
    camera = read_camera_file(path)
    fx, fy, cx, cy, distortion = FR1
    assert camera.pinhole == (fx, fy, cx, cy) and camera.distortion == distortion
    assert camera.depth_factor == 5000.0 and camera.size == (640, 480)
    assert camera.source is CameraSource.FILE and camera.origin == str(path)
    first_format = path.with_name("TUM1-first.yaml")  # ORB-SLAM2: no k3 key, read as 0
    first_format.write_text(
        "%YAML:1.0\nCamera.fx: 517.3\nCamera.fy: 516.5\nCamera.cx: 318.6\nCamera.cy: 255.3\n"
        "Camera.k1: 0.2624\nCamera.k2: -0.9531\nCamera.p1: -0.0054\nCamera.p2: 0.0026\n"
        "Camera.width: 640\nCamera.height: 480\nDepthMapFactor: 5000.0\n"
    )
    assert read_camera_file(first_format).distortion == (*distortion[:4], 0.0)


def test_the_depth_factor_scales_every_depth_reading(small_real, tmp_path):
    """depth_m = raw / factor, the raw PNG read by OpenCV's decoder."""
    camera = CameraOverride(pinhole=(50.0, 50.0, 31.5, 23.5), depth_factor=1000.0, origin="test")
    sequence = Sequence.open(small_real, camera=camera)
    for i in range(len(sequence)):
        raw = cv2.imread(str(sequence.frames[i].depth_path), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(sequence.depth_m(i), raw.astype(np.float32) / np.float32(1000.0))
    assert sequence.depth_m(1).max() > 5.0 * 5  # the 0.5-6 m written at 5000 read 5 x farther
    out = tmp_path / "run"
    flags = ["--intrinsics", "50", "50", "31.5", "23.5", "--depth-factor", "1000"]
    assert cli([str(small_real), "-o", str(out), *flags]) == 0
    recorded = metrics_camera(out)
    assert recorded["depth_factor"] == 1000.0 and recorded["depth_factor_source"] == "flags"


def test_a_depth_factor_alone_keeps_the_guessed_calibration_and_its_warning(tmp_path, caplog):
    root = vga_real(tmp_path, "rgbd_dataset_freiburg3_walking_xyz")
    camera = CameraOverride(depth_factor=1000.0, source=CameraSource.FLAGS, origin="--depth-factor")
    sequence = Sequence.open(root, camera=camera)
    assert (sequence.intrinsics.fx, sequence.intrinsics.depth_scale) == (535.4, 1000.0)  # TUM fr3
    assert sequence.camera_source.source is CameraSource.TUM
    assert sequence.camera_source.depth_factor_source is CameraSource.FLAGS
    assert "TUM's freiburg3 calibration" in sequence.camera_warning


def test_the_run_key_is_the_camera_used_not_how_it_was_given(small_real, tmp_path):
    def key(name: str, *flags: str) -> str:
        assert cli([str(small_real), "-o", str(tmp_path / name), *flags]) == 0
        return json.loads((tmp_path / name / "record.json").read_text())["key"]

    settings = tmp_path / "generated" / "camera.yaml"  # SMALL: 50 50 31.5 23.5, 64x48, 5000
    as_file = key("file", "--camera", str(settings))
    assert key("flags", "--intrinsics", "50", "50", "31.5", "23.5") == as_file
    assert key("other", "--intrinsics", "50", "50", "31.5", "23.0") != as_file


# -- distortion: the built-in tracker undistorts keypoints with the camera given ------------------


def test_keypoints_through_the_given_distortion_undistort_to_the_pinhole_closed_form(small_real):
    """Brown-Conrady written out: x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2),
    y_d likewise; the camera the flags give must take the distorted pixels back to fx x + cx."""
    fx, fy, cx, cy, (k1, k2, p1, p2, k3) = FR1
    flags = ["--intrinsics", *map(str, (fx, fy, cx, cy)), "--distortion", *map(str, (k1, k2, p1, p2, k3))]
    assert "-0.9531" in flags  # a negative coefficient is a number, not an option
    args = cli_main.build_parser().parse_args(["run", str(small_real), "-o", "out", *flags])
    given = camera_from_args(args)
    camera = given.applied(TUM_DEFAULT, (640, 480))
    x, y = (a.ravel() for a in np.meshgrid(np.linspace(-0.55, 0.55, 23), np.linspace(-0.45, 0.45, 19)))
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    distorted = np.stack([fx * xd + cx, fy * yd + cy], axis=1)
    pinhole = np.stack([fx * x + cx, fy * y + cy], axis=1)
    assert np.abs(distorted - pinhole).max() > 10  # the lens moves corner points by pixels
    assert np.abs(camera.undistort(distorted) - pinhole).max() < 0.01
    # The same camera is what the built-in tracker projects with (camera_of: the sequence's).
    sequence = Sequence.open(small_real, camera=CameraOverride(given.pinhole, given.distortion))
    assert sequence.intrinsics.distortion == (k1, k2, p1, p2, k3)


# -- the API --------------------------------------------------------------------------------------


def test_the_api_takes_the_camera_as_intrinsics_a_file_or_the_opened_sequence(small_real, tmp_path):
    k = Intrinsics(49.0, 49.5, 31.0, 23.0, 64, 48, (0.01, 0.0, 0.0, 0.0, 0.0), 5000.0)
    record = depotbench.run(small_real, tmp_path / "given", detector="none", cache=False, camera=k)
    camera = metrics_camera(tmp_path / "given")
    assert (camera["fx"], camera["fy"], camera["distortion"]["k1"]) == (49.0, 49.5, 0.01)
    assert camera["source"] == "given"
    assert record.key == json.loads((tmp_path / "given" / "record.json").read_text())["key"]
    settings = tmp_path / "generated" / "camera.yaml"
    depotbench.run(small_real, tmp_path / "file", detector="none", cache=False, camera=settings)
    assert metrics_camera(tmp_path / "file")["source"] == "file"
    opened = Sequence.open(small_real, camera=CameraOverride.of(k))
    # A sequence opened with a camera keeps it: the same run, the same key.
    assert depotbench.run(opened, detector="none", cache=False).key == record.key
    with pytest.raises(InputError, match="camera: give a CameraOverride"):
        depotbench.run(small_real, detector="none", cache=False, camera=(50, 50, 31.5, 23.5))


# -- bad input: one line naming the flag or the file and key, exit 2, nothing written -------------


def _camera_file(tmp_path: Path, replace: tuple[str, str] | None = None, text: str | None = None) -> str:
    path = tmp_path / "cam.yaml"
    body = (tmp_path / "generated" / "camera.yaml").read_text() if text is None else text
    if replace is not None:
        assert replace[0] in body
        body = body.replace(*replace)
    path.write_text(body)
    return str(path)


BAD_FILES = {
    "missing-fx": (("Camera.fx: 50.0\n", ""), "cam.yaml: missing key Camera.fx"),
    "negative-fx": (("Camera.fx: 50.0", "Camera.fx: -50"), "cam.yaml: Camera.fx = -50 is outside"),
    "text-fx": (("Camera.fx: 50.0", "Camera.fx: fifty"), "cam.yaml: Camera.fx must be a number, got 'fifty'"),
    "list-fx": (("Camera.fx: 50.0", "Camera.fx: [50, 50]"), "cam.yaml: Camera.fx must be a number"),
    "nan-k1": (("Camera.k1: 0.0", "Camera.k1: .nan"), "cam.yaml: Camera.k1 must be a finite number"),
    "zero-depth-factor": (
        ("DepthMapFactor: 5000.0", "DepthMapFactor: 0"),
        "cam.yaml: DepthMapFactor = 0 is outside",
    ),
    "no-depth-factor": (("DepthMapFactor: 5000.0\n", ""), "cam.yaml: missing key DepthMapFactor"),
    "fisheye": (
        ('Camera.type: "PinHole"', 'Camera.type: "KannalaBrandt8"'),
        "cam.yaml: Camera.type 'KannalaBrandt8' is not taken",
    ),
    "other-size": (("Camera.width: 64", "Camera.width: 80"), "cam.yaml: the camera is 80x48, but"),
    "resized": (("Camera.width: 64", "Camera.width: 64\nCamera.newWidth: 32"), "cam.yaml: Camera.newWidth"),
    "version": (("%YAML:1.0\n", '%YAML:1.0\nFile.version: "2.0"\n'), "cam.yaml: File.version '2.0'"),
    "not-yaml": (("%YAML:1.0", "{{{{"), "cam.yaml: not"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_a_bad_camera_file_is_one_line_naming_file_and_key(case, small_real, tmp_path, capsys):
    replace, expected = BAD_FILES[case]
    out = tmp_path / "run"
    assert cli([str(small_real), "-o", str(out), "--camera", _camera_file(tmp_path, replace)]) == 2
    assert expected in one_line(capsys.readouterr().err, "error")
    assert not out.exists()


BAD_FLAGS = {
    "three-intrinsics": (["--intrinsics", "50", "50", "31.5"], "--intrinsics: expected 4 arguments"),
    "five-intrinsics": (["--intrinsics", "50", "50", "31.5", "23.5", "1"], "unrecognized arguments: 1"),
    "text-intrinsics": (["--intrinsics", "50", "fifty", "31.5", "23.5"], "must be a number, got 'fifty'"),
    "nan-intrinsics": (["--intrinsics", "nan", "50", "31.5", "23.5"], "must be a finite number"),
    "negative-fx": (["--intrinsics", "-50", "50", "31.5", "23.5"], "--intrinsics: fx must be > 0, got -50"),
    "tiny-fy": (["--intrinsics", "50", "1e-9", "31.5", "23.5"], "--intrinsics: fy = 1e-09 is outside"),
    "zero-depth-factor": (["--depth-factor", "0"], "--depth-factor: must be > 0, got 0"),
    "huge-depth-factor": (["--depth-factor", "1e9"], "--depth-factor: depth factor = 1e+09 is outside"),
    "three-distortion": (
        ["--intrinsics", "50", "50", "31.5", "23.5", "--distortion", "0.1", "0", "0"],
        "--distortion: give K1 K2 P1 P2 [K3] (4 or 5 numbers), got 3",
    ),
    "distortion-alone": (["--distortion", "0.1", "0", "0", "0"], "--distortion belongs with a calibration"),
    "file-and-flags": (["--camera", "cam.yaml", "--intrinsics", "50", "50", "31.5", "23.5"], "not both"),
    "missing-file": (["--camera", "nowhere.yaml"], "nowhere.yaml: no such camera file"),
}


@pytest.mark.parametrize("case", sorted(BAD_FLAGS))
def test_bad_camera_flags_are_one_line_naming_the_flag(case, small_real, tmp_path, capsys, monkeypatch):
    flags, expected = BAD_FLAGS[case]
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "run"
    assert cli([str(small_real), "-o", str(out), *flags]) == 2
    assert expected in one_line(capsys.readouterr().err, "error")
    assert not out.exists()


def test_a_camera_for_a_generated_sequence_is_refused_in_one_line(tmp_path, capsys):
    """Its ground truth (instances, boxes, the static world a map is scored against) was rendered
    through its own camera; another one would make the exact labels disagree with the images."""
    write_sequence(tmp_path / "generated", n=3)
    out = tmp_path / "run"
    assert cli([str(tmp_path / "generated"), "-o", str(out), "--depth-factor", "1000"]) == 2
    line = one_line(capsys.readouterr().err, "error")
    assert "a generated sequence keeps its own camera" in line and "--depth-factor" in line
    assert not out.exists()


def test_the_settings_template_is_given_the_lens_distortion(small_real, tmp_path):
    """A --slam cmd settings template reads the given camera's distortion by name, as
    orbslam_camera carries it (k1..k3 were missing from ``camera``)."""
    from depotbench.eval.trackers.command import SettingsTemplate

    coefficients = (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)
    given = CameraOverride(
        pinhole=(50.0, 50.0, 31.5, 23.5), distortion=coefficients, source=CameraSource.FLAGS
    )
    sequence = Sequence.open(small_real, camera=given)
    template = SettingsTemplate(
        tmp_path / "t.j2",
        "{% for name, value in camera.distortion.items() %}{{ name }}={{ value }} {% endfor %}",
    )
    shown = dict(item.split("=") for item in template.render(sequence, {}).split())
    assert {name: float(value) for name, value in shown.items()} == dict(
        zip(("k1", "k2", "p1", "p2", "k3"), coefficients, strict=True)
    )


@pytest.mark.skipif(not __import__("importlib").util.find_spec("pyorbslam3"), reason="extra [orbslam3]")
def test_orbslam3_opens_a_real_folder_of_another_size_with_the_given_camera(tmp_path, capsys):
    """The worker reopened the folder without the run's camera: a 320x240 folder with no
    camera.yaml failed there (the ROS default it guessed is 640x480) though the run was
    given one. (64x48 frames are too small for ORB-SLAM3's pyramid: it stops on them.)"""
    qvga = Intrinsics(fx=260.0, fy=260.0, cx=159.5, cy=119.5, width=320, height=240)
    root = vga_real(tmp_path, "my_qvga", qvga)
    out = tmp_path / "run"
    flags = ["--slam", "orbslam3", "--intrinsics", "260", "260", "159.5", "119.5"]
    code = cli([str(root), "-o", str(out), *flags])
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == 3 and metrics["camera"]["fx"] == 260.0
    assert (metrics["camera"]["width"], metrics["camera"]["height"]) == (320, 240)
