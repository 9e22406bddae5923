"""The sequence format: round trip, atomic writes, and each breakage refused by name."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from depotbench.core.errors import SequenceFormatError
from depotbench.core.output import OutputError
from depotbench.sim.camera import TUM_FREIBURG, read_orbslam_yaml
from depotbench.sim.sequence import Sequence, SequenceWriter, encode_depth

from tests.sequences import SMALL, random_frame, tree_differences, write_sequence


@pytest.fixture
def seq_dir(tmp_path: Path) -> Path:
    root = tmp_path / "seq"
    write_sequence(root)
    return root


def test_round_trip(tmp_path: Path):
    root = tmp_path / "seq"
    frames = write_sequence(root, n=6)
    seq = Sequence.open(root)
    seq.verify()
    assert seq.is_generated and len(seq) == 6
    assert seq.intrinsics == SMALL
    assert seq.meta["scenario"] == {"name": "test"} and seq.meta["format_version"] == 1
    objects = seq.objects()
    for i, (t, rgb, depth, pose, instances, objs, flow) in enumerate(frames):
        assert seq.frames[i].timestamp_s == pytest.approx(t, abs=1e-6)
        np.testing.assert_array_equal(seq.rgb(i), rgb)
        np.testing.assert_array_equal(seq.depth_raw(i), encode_depth(depth, 5000.0))
        np.testing.assert_allclose(seq.depth_m(i), depth, atol=0.5 / 5000 + 1e-7)
        np.testing.assert_allclose(seq.world_from_camera(i), pose, atol=1e-8)
        np.testing.assert_array_equal(seq.instances(i), instances)
        np.testing.assert_array_equal(seq.flow(i), flow)
        assert objects[i] == objs


def test_layout_is_tum_and_orbslam_compatible(seq_dir: Path):
    for name in (
        "rgb.txt",
        "depth.txt",
        "associations.txt",
        "groundtruth.txt",
        "camera.yaml",
        "meta.json",
        "gt/objects.jsonl",
    ):
        assert (seq_dir / name).is_file(), name
    first = (seq_dir / "associations.txt").read_text().splitlines()[0].split()
    assert first == ["1.000000", "rgb/1.000000.png", "1.000000", "depth/1.000000.png"]
    # ORB-SLAM reads its settings with cv::FileStorage; so do we.
    storage = cv2.FileStorage(str(seq_dir / "camera.yaml"), cv2.FILE_STORAGE_READ)
    assert storage.getNode("Camera.type").string() == "PinHole"
    assert storage.getNode("DepthMapFactor").real() == 5000.0
    assert storage.getNode("ORBextractor.nFeatures").real() == 1000
    intrinsics, fps = read_orbslam_yaml(seq_dir / "camera.yaml")
    assert intrinsics == SMALL and fps == 30.0
    depth = cv2.imread(str(seq_dir / "depth" / "1.000000.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16


def test_writer_is_atomic_on_error(tmp_path: Path):
    root = tmp_path / "seq"
    rng = np.random.default_rng(0)
    with (
        pytest.raises(RuntimeError, match="boom"),
        SequenceWriter(root, SMALL, fps=30, meta={}) as w,
    ):
        rgb, depth, pose, inst, objs, _ = random_frame(rng, 0)
        w.add_frame(1.0, rgb, depth, pose, inst, objs)
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_writer_refuses_bad_frames_and_existing_output(seq_dir: Path, tmp_path: Path):
    with pytest.raises(OutputError, match="already exists"):
        SequenceWriter(seq_dir, SMALL, fps=30, meta={}).__enter__()
    rng = np.random.default_rng(0)
    rgb, depth, pose, inst, objs, _ = random_frame(rng, 0)
    with (
        pytest.raises(ValueError, match="frame 0 rgb"),
        SequenceWriter(tmp_path / "x", SMALL, fps=30, meta={}) as w,
    ):
        w.add_frame(1.0, rgb[:10], depth, pose, inst, objs)
    bad_pose = pose.copy()
    bad_pose[:3, :3] *= 2
    with (
        pytest.raises(ValueError, match="not a proper rotation"),
        SequenceWriter(tmp_path / "x", SMALL, fps=30, meta={}) as w,
    ):
        w.add_frame(1.0, rgb, depth, bad_pose, inst, objs)
    assert not (tmp_path / "x").exists()


def test_overwrite_replaces_whole_folder(seq_dir: Path):
    (seq_dir / "stray.txt").write_text("old")
    rng = np.random.default_rng(1)
    with SequenceWriter(seq_dir, SMALL, fps=30, meta={}, overwrite=True) as w:
        rgb, depth, pose, inst, objs, _ = random_frame(rng, 0)
        w.add_frame(5.0, rgb, depth, pose, inst, objs)
    assert not (seq_dir / "stray.txt").exists()
    assert len(Sequence.open(seq_dir)) == 1


def test_same_input_same_bytes(tmp_path: Path):
    write_sequence(tmp_path / "a", seed=3)
    write_sequence(tmp_path / "b", seed=3)
    assert tree_differences(tmp_path / "a", tmp_path / "b") == []


def test_tree_differences_says_how_two_sequences_differ(tmp_path: Path):
    """The determinism tests' failure message: which files, which pixels, by how much."""
    write_sequence(tmp_path / "a", seed=3)
    write_sequence(tmp_path / "b", seed=3)
    depth_png = sorted((tmp_path / "b" / "depth").glob("*.png"))[1]
    depth = cv2.imread(str(depth_png), cv2.IMREAD_UNCHANGED)
    depth[4, 9] += 3
    cv2.imwrite(str(depth_png), depth)
    flow = sorted((tmp_path / "b" / "gt" / "flow").glob("*.npz"))[0]
    arrays = dict(np.load(flow))
    arrays["flow"][0, 0, 0] += 0.5
    np.savez_compressed(flow, **arrays)
    (tmp_path / "b" / "stray.txt").write_text("x")
    objects = tmp_path / "b" / "gt" / "objects.jsonl"
    lines = objects.read_text().splitlines(keepends=True)
    at = lines[1].rindex("}") - 1  # near the end of a long line, past any shared prefix shown
    lines[1] = lines[1][:at] + ("7" if lines[1][at] != "7" else "8") + lines[1][at + 1 :]
    objects.write_text("".join(lines))
    report = tree_differences(tmp_path / "a", tmp_path / "b")
    rel = depth_png.relative_to(tmp_path / "b")
    original = (tmp_path / "a" / "gt" / "objects.jsonl").read_text().splitlines()[1]
    window = slice(max(0, at - 80), at + 80)
    assert report == [
        f"stray.txt: only in {tmp_path / 'b'}",
        f"{rel}: 1 pixels differ, by up to 3 (first at row 4, column 9: {depth[4, 9] - 3} and {depth[4, 9]})",
        f"{flow.relative_to(tmp_path / 'b')}: flow: 1 values differ, by up to 0.5",
        f"gt/objects.jsonl: line 2 differs at character {at + 1}: "
        f"{original[window]!r} and {lines[1].rstrip(chr(10))[window]!r}",
    ]


def test_encode_depth_marks_invalid_as_no_reading():
    depth = np.array([[0.0, -1.0, np.nan, np.inf, 1.0, 13.2]], dtype=np.float32)
    assert encode_depth(depth, 5000.0).tolist() == [[0, 0, 0, 0, 5000, 0]]


# -- each breakage, its own message ---------------------------------------------


def _rewrite_line(path: Path, line_no: int, new: str) -> None:
    lines = path.read_text().splitlines()
    lines[line_no - 1] = new
    path.write_text("\n".join(lines) + "\n")


def _data_line(path: Path, k: int) -> int:
    """1-based line number of the k-th data row of a TUM file."""
    rows = [i for i, line in enumerate(path.read_text().splitlines(), 1) if line and line[0] != "#"]
    return rows[k]


def test_missing_frame_file(seq_dir: Path):
    (seq_dir / "rgb" / "1.033333.png").unlink()
    with pytest.raises(
        SequenceFormatError, match=r"associations.txt:2: frame file rgb/1.033333.png is missing"
    ):
        Sequence.open(seq_dir)


def test_unsorted_timestamps(seq_dir: Path):
    assoc = seq_dir / "associations.txt"
    lines = assoc.read_text().splitlines()
    lines[1], lines[2] = lines[2], lines[1]
    assoc.write_text("\n".join(lines) + "\n")
    with pytest.raises(SequenceFormatError, match=r"associations.txt:3: timestamp 1.033333 is earlier than"):
        Sequence.open(seq_dir)


def test_duplicate_timestamps(seq_dir: Path):
    gt = seq_dir / "groundtruth.txt"
    line = _data_line(gt, 2)
    fields = gt.read_text().splitlines()[line - 1].split()
    fields[0] = "1.033333"
    _rewrite_line(gt, line, " ".join(fields))
    with pytest.raises(SequenceFormatError, match=rf"groundtruth.txt:{line}: timestamp 1.033333 duplicates"):
        Sequence.open(seq_dir)


def test_depth_not_16_bit(seq_dir: Path):
    path = seq_dir / "depth" / "1.066667.png"
    cv2.imwrite(str(path), np.zeros((48, 64), np.uint8))
    seq = Sequence.open(seq_dir)
    with pytest.raises(
        SequenceFormatError,
        match=r"1.066667.png: depth must be a 16-bit single-channel PNG, got uint8",
    ):
        seq.verify()


def test_wrong_image_size(seq_dir: Path):
    cv2.imwrite(str(seq_dir / "rgb" / "1.100000.png"), np.zeros((24, 32, 3), np.uint8))
    with pytest.raises(SequenceFormatError, match=r"rgb/1.100000.png: image is 32x24, the camera is 64x48"):
        Sequence.open(seq_dir).verify()


def test_corrupt_png(seq_dir: Path):
    path = seq_dir / "rgb" / "1.100000.png"
    intact = path.read_bytes()
    path.write_bytes(b"\x89PNG not really")
    with pytest.raises(SequenceFormatError, match=r"1.100000.png: is not a PNG image"):
        Sequence.open(seq_dir).rgb(3)
    path.write_bytes(intact[:60])  # a valid header, then nothing
    with pytest.raises(SequenceFormatError, match=r"1.100000.png: cannot be decoded as a PNG"):
        Sequence.open(seq_dir).rgb(3)


def test_nan_in_pose(seq_dir: Path):
    gt = seq_dir / "groundtruth.txt"
    line = _data_line(gt, 1)
    _rewrite_line(gt, line, "1.033333 nan 0 0 0 0 0 1")
    with pytest.raises(SequenceFormatError, match=rf"groundtruth.txt:{line}: pose holds NaN"):
        Sequence.open(seq_dir)


def test_non_unit_quaternion(seq_dir: Path):
    gt = seq_dir / "groundtruth.txt"
    line = _data_line(gt, 3)
    _rewrite_line(gt, line, "1.100000 0 0 0 0 0 0.5 0.5")
    with pytest.raises(
        SequenceFormatError, match=rf"groundtruth.txt:{line}: quaternion .* norm 0.707107, not 1"
    ):
        Sequence.open(seq_dir)


def test_unknown_format_version(seq_dir: Path):
    meta_path = seq_dir / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["format_version"] = 99
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(SequenceFormatError, match=r"meta.json: format_version 99 is not supported"):
        Sequence.open(seq_dir)


def test_field_count_and_non_numbers(seq_dir: Path):
    gt = seq_dir / "groundtruth.txt"
    line = _data_line(gt, 0)
    _rewrite_line(gt, line, "1.000000 0 0 0 0 0 1")
    with pytest.raises(SequenceFormatError, match=rf"groundtruth.txt:{line}: expected 8 fields, found 7"):
        Sequence.open(seq_dir)
    _rewrite_line(gt, line, "1.000000 0 zero 0 0 0 0 1")
    with pytest.raises(SequenceFormatError, match=rf"groundtruth.txt:{line}: field 'zero' is not a number"):
        Sequence.open(seq_dir)


def test_generated_sequence_needs_its_ground_truth(seq_dir: Path):
    (seq_dir / "gt" / "instances" / "1.000000.png").unlink()
    with pytest.raises(SequenceFormatError, match="instance image is missing"):
        Sequence.open(seq_dir)
    shutil.rmtree(seq_dir / "gt")
    with pytest.raises(SequenceFormatError, match="objects.jsonl: file is missing"):
        Sequence.open(seq_dir)
    (seq_dir / "camera.yaml").unlink()
    with pytest.raises(SequenceFormatError, match="camera.yaml: file is missing"):
        Sequence.open(seq_dir)


def test_bad_object_record(seq_dir: Path):
    path = seq_dir / "gt" / "objects.jsonl"
    _rewrite_line(path, 2, '{"timestamp": "1.033333", "objects": [{"id": 1}]}')
    with pytest.raises(SequenceFormatError, match=r"objects.jsonl:2: bad record"):
        Sequence.open(seq_dir).objects()


def test_not_a_folder(tmp_path: Path):
    with pytest.raises(SequenceFormatError, match="no such directory"):
        Sequence.open(tmp_path / "nope")


# -- real TUM folders -------------------------------------------------------------


def make_tum_folder(root: Path) -> None:
    """A folder laid out as TUM publishes it: lists at different rates, no associations."""
    rng = np.random.default_rng(0)
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_t = 1305031102.175304 + np.arange(6) / 30.0
    depth_t = rgb_t + rng.uniform(-0.012, 0.012, 6)
    depth_t[5] += 0.2  # the last RGB frame finds no partner within 0.02 s
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps"]
    for t in rgb_t:
        cv2.imwrite(str(root / "rgb" / f"{t:.6f}.png"), rng.integers(0, 255, (480, 640, 3), np.uint8))
        rgb_lines.append(f"{t:.6f}\trgb/{t:.6f}.png")
    for t in depth_t:
        cv2.imwrite(str(root / "depth" / f"{t:.6f}.png"), rng.integers(0, 60000, (480, 640), np.uint16))
        depth_lines.append(f"{t:.6f} depth/{t:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    gt_t = rgb_t[0] - 0.05 + np.arange(40) / 100.0
    (root / "groundtruth.txt").write_text(
        "# ground truth trajectory\n"
        + "".join(f"{t:.4f} 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986\n" for t in gt_t)
    )


def test_reads_real_tum_folder(tmp_path: Path):
    root = tmp_path / "rgbd_dataset_freiburg1_xyz"
    make_tum_folder(root)
    seq = Sequence.open(root)
    assert not seq.is_generated
    assert seq.intrinsics == TUM_FREIBURG["freiburg1"]
    assert len(seq) == 5  # the RGB frame whose depth is 0.2 s off is dropped
    assert all(abs(f.timestamp_s - f.depth_timestamp_s) < 0.02 for f in seq.frames)
    assert seq.rgb(0).shape == (480, 640, 3) and seq.depth_m(0).dtype == np.float32
    assert len(seq.groundtruth.timestamps_s) == 40
    seq.verify()
    with pytest.raises(ValueError, match="not a generated sequence"):
        seq.instances(0)


def test_real_tum_folder_with_given_intrinsics(tmp_path: Path):
    root = tmp_path / "my_recording"
    make_tum_folder(root)
    assert Sequence.open(root).intrinsics.fx == 525.0  # ROS default for unknown sensors
    custom = TUM_FREIBURG["freiburg3"]
    assert Sequence.open(root, intrinsics=custom).intrinsics == custom


def test_objects_written_before_visibility_was_recorded_still_read(tmp_path: Path):
    """Sequences from before unoccluded_pixels / visible_fraction / truncated read as unknown."""
    import json

    root = tmp_path / "seq"
    write_sequence(root, n=3)
    path = root / "gt" / "objects.jsonl"
    records = [json.loads(line) for line in path.read_text().splitlines()]
    assert records[0]["objects"][0]["visible_fraction"] == pytest.approx(100 / 160, abs=1e-4)
    for record in records:
        for obj in record["objects"]:
            for name in ("unoccluded_pixels", "visible_fraction", "truncated"):
                del obj[name]
    path.write_text("".join(json.dumps(r, separators=(",", ":")) + "\n" for r in records))
    person = Sequence.open(root).objects()[0][0]
    assert person.unoccluded_pixels is None and person.truncated is None and person.visible_fraction is None


@pytest.mark.parametrize("stamp", ["nan", "inf", "-inf"])
def test_a_timestamp_that_is_not_finite_is_refused_by_its_line(tmp_path: Path, stamp: str):
    """Probe D4: `nan` passed the order check (every comparison with NaN is false), the frame
    was dropped and the rest tracked out of time order."""
    root = tmp_path / "tum"
    make_tum_folder(root)
    rgb = root / "rgb.txt"
    line = _data_line(rgb, 1)
    _rewrite_line(rgb, line, f"{stamp} {rgb.read_text().splitlines()[line - 1].split()[1]}")
    with pytest.raises(SequenceFormatError, match=rf"rgb.txt:{line}: timestamp '{stamp}' is not a finite"):
        Sequence.open(root)


def test_an_associations_timestamp_that_is_not_finite_is_refused(seq_dir: Path):
    assoc = seq_dir / "associations.txt"
    fields = assoc.read_text().splitlines()[1].split()
    _rewrite_line(assoc, 2, " ".join([fields[0], fields[1], "nan", fields[3]]))
    with pytest.raises(SequenceFormatError, match=r"associations.txt:2: timestamp 'nan' is not a finite"):
        Sequence.open(seq_dir)


@pytest.mark.parametrize("kind", ["file link", "folder link"])
def test_a_frame_reached_through_a_link_out_of_the_folder_is_refused(seq_dir: Path, tmp_path: Path, kind):
    """Probe S1: `x/root -> /` let a listed frame be /etc/passwd (and an export copy it)."""
    secret = tmp_path / "secret.png"
    shutil.copyfile(seq_dir / "rgb" / "1.000000.png", secret)  # a valid PNG: only the link is wrong
    assoc = seq_dir / "associations.txt"
    if kind == "file link":
        (seq_dir / "rgb" / "1.000000.png").unlink()
        (seq_dir / "rgb" / "1.000000.png").symlink_to(secret)
        name = "rgb/1.000000.png"
    else:
        (seq_dir / "x").mkdir()
        (seq_dir / "x" / "root").symlink_to(tmp_path)
        name = "x/root/secret.png"
        fields = assoc.read_text().splitlines()[0].split()
        _rewrite_line(assoc, 1, " ".join([fields[0], name, *fields[2:]]))
    with pytest.raises(SequenceFormatError, match=rf"associations.txt:1: frame file {name} is a link out of"):
        Sequence.open(seq_dir)


def test_a_sequence_folder_that_is_itself_a_link_is_read(seq_dir: Path, tmp_path: Path):
    (tmp_path / "alias").symlink_to(seq_dir)
    assert len(Sequence.open(tmp_path / "alias")) == len(Sequence.open(seq_dir))


@pytest.mark.parametrize("name", ["gt/objects.jsonl", "gt/instances/1.033333.png"])
def test_ground_truth_reached_through_a_link_out_of_the_folder_is_refused(
    seq_dir: Path, tmp_path: Path, name: str
):
    outside = tmp_path / "outside"
    shutil.copyfile(seq_dir / name, outside)
    (seq_dir / name).unlink()
    (seq_dir / name).symlink_to(outside)
    with pytest.raises(SequenceFormatError, match=rf"{name}: is a link out of the sequence folder"):
        Sequence.open(seq_dir)
