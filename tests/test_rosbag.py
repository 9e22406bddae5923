"""``depotbench export-rosbag``: the bag read back by three readers that share no code with the
writer's message building (rosbags' AnyReader decoding with the definitions stored in the bag,
the ``mcap`` reader with ``mcap_ros2``'s own CDR decoder, and SQLite read by hand and decoded by
``mcap_ros2``), checked against the sequence's files parsed here independently: PNGs decoded
by Pillow, timestamps and poses parsed from the text files, boxes from ``gt/objects.jsonl``."""

from __future__ import annotations

import json
import re
import shutil
import sqlite3
from decimal import Decimal
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from depotbench.core.camera import Intrinsics
from depotbench.core.errors import InputError
from depotbench.eval.cli import rosbag as cli_rosbag
from depotbench.eval.cli.main import EXIT_INPUT_ERROR, main
from depotbench.eval.export import rosbag
from depotbench.eval.export.rosbag import DEPTH_FORMS, BagStorage, DepthUnit, write_bag
from depotbench.sim.camera import orbslam_yaml
from PIL import Image
from scipy.spatial.transform import Rotation

from tests.sequences import SMALL, write_sequence

FRAMES = 30
IMAGE_TOPICS = ("/camera/color/image_raw", "/camera/color/camera_info", "/camera/depth/camera_info")


# -- the sequence's files, parsed here --------------------------------------------------------


def ns_of(text: str) -> int:
    """A TUM timestamp's nanoseconds, from its decimal text (no float on the way)."""
    return int(Decimal(text) * 1_000_000_000)


def frame_list(path: Path) -> list[tuple[int, str]]:
    rows = [
        line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")
    ]
    return [(ns_of(t), name) for t, name in rows]


def groundtruth(path: Path) -> tuple[list[int], np.ndarray]:
    lines = [line for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    return [ns_of(line.split()[0]) for line in lines], np.loadtxt(lines, ndmin=2)[:, 1:]


def png(path: Path) -> np.ndarray:
    with Image.open(path) as image:
        return np.array(image)


# -- three readers ------------------------------------------------------------------------------

Messages = dict[str, list[tuple[int, Any]]]
"""Per topic, (log time in ns, decoded message) in the order stored."""


def read_rosbags(bag: Path) -> tuple[Messages, dict[str, str]]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    messages: Messages = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for connection, t, raw in reader.messages():
            messages.setdefault(connection.topic, []).append((t, reader.deserialize(raw, connection.msgtype)))
    return messages, types


def read_mcap(bag: Path) -> tuple[Messages, dict[str, str]]:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    messages: Messages = {}
    types = {}
    (data,) = bag.glob("*.mcap")
    with data.open("rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            assert message.publish_time == message.log_time
            types[channel.topic] = schema.name
            messages.setdefault(channel.topic, []).append((message.log_time, decoded))
    return messages, types


def read_sqlite(bag: Path) -> tuple[Messages, dict[str, str]]:
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    (data,) = bag.glob("*.db3")
    factory = DecoderFactory()
    with sqlite3.connect(f"file:{data}?mode=ro", uri=True) as db:
        definitions = dict(
            db.execute("SELECT topic_type, encoded_message_definition FROM message_definitions")
        )
        topics = {i: (name, kind) for i, name, kind in db.execute("SELECT id, name, type FROM topics")}
        rows = db.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id").fetchall()
    decoders = {
        i: factory.decoder_for(
            "cdr", Schema(id=i, name=kind, encoding="ros2msg", data=definitions[kind].encode())
        )
        for i, (_, kind) in topics.items()
    }
    messages: Messages = {}
    for topic_id, t, raw in rows:
        messages.setdefault(topics[topic_id][0], []).append((t, decoders[topic_id](raw)))
    return messages, {name: kind for name, kind in topics.values()}


READERS = {"mcap": (read_rosbags, read_mcap), "sqlite3": (read_rosbags, read_sqlite)}


def raw_bytes(value: Any) -> bytes:
    return bytes(value) if isinstance(value, bytes | bytearray) else np.asarray(value).tobytes()


def stamp(message: Any) -> int:
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


def same_rotation(q: np.ndarray, reference: np.ndarray) -> bool:
    return bool(np.allclose(q, reference, atol=1e-9) or np.allclose(q, -reference, atol=1e-9))


# -- fixtures -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("rosbag") / "seq"
    write_sequence(root, n=FRAMES, seed=3)
    return root


@pytest.fixture(scope="module")
def bags(sequence: Path) -> dict[tuple[str, str], Path]:
    """One bag per storage and depth form, each with the detections."""
    out = {}
    for storage in BagStorage:
        for depth in DepthUnit:
            path = sequence.parent / f"bag-{storage.value}-{depth.value}"
            write_bag(sequence, path, storage=storage, depth=depth, detections=True, progress=False)
            out[(storage.value, depth.value)] = path
    return out


def tum_like(sequence: Path, root: Path, *, with_groundtruth: bool) -> Path:
    """The sequence as a real TUM folder has it: no meta.json, no gt/, no associations.txt,
    depth 4 ms after each colour frame, a distorted camera, ground truth at 100 Hz (4 decimals)."""
    root.mkdir()
    (root / "rgb").mkdir()
    (root / "depth").mkdir()
    rgb_lines, depth_lines = ["# timestamp filename"], ["# timestamp filename"]
    for t, name in frame_list(sequence / "rgb.txt"):
        shutil.copy(sequence / name, root / name)
        depth_t = f"{Decimal(t) / 10**9 + Decimal('0.004'):.6f}"
        shutil.copy(sequence / name.replace("rgb", "depth"), root / "depth" / f"{depth_t}.png")
        rgb_lines.append(f"{Decimal(t) / 10**9:.6f} {name}")
        depth_lines.append(f"{depth_t} depth/{depth_t}.png")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    distorted = Intrinsics(**{**SMALL.__dict__, "distortion": (0.26, -0.95, -0.005, 0.003, 1.16)})
    (root / "camera.yaml").write_text(orbslam_yaml(distorted))
    if with_groundtruth:
        rng = np.random.default_rng(5)
        rows = [
            f"{0.98 + j / 100:.4f} "
            + " ".join(f"{v:.4f}" for v in rng.normal(0, 1, 3))
            + " "
            + " ".join(f"{v:.7f}" for v in Rotation.random(random_state=rng.integers(1 << 31)).as_quat())
            for j in range(110)
        ]
        (root / "groundtruth.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(rows) + "\n")
    return root


def run_cli(capsys, *argv: str | Path) -> tuple[int, str, str]:
    """The command through the real entry point, ``depotbench export-rosbag ...``."""
    try:
        code = main(["export-rosbag", *map(str, argv)])
    except SystemExit as exc:  # argparse's refusals
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_error_line(err: str, *needles: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# -- the bag's content --------------------------------------------------------------------------


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_every_reader_sees_each_frame_pose_and_box_of_the_sequence(sequence: Path, bags, storage: str):
    colour = frame_list(sequence / "rgb.txt")
    depth = frame_list(sequence / "depth.txt")
    gt_ns, gt = groundtruth(sequence / "groundtruth.txt")
    objects = [json.loads(line) for line in (sequence / "gt" / "objects.jsonl").read_text().splitlines()]
    for reader in READERS[storage]:
        messages, types = reader(bags[(storage, "m")])
        counts = {topic: len(found) for topic, found in messages.items()}
        assert counts == {
            **dict.fromkeys(IMAGE_TOPICS, FRAMES),
            "/camera/depth/image": FRAMES,
            "/camera/detections": FRAMES,
            "/tf": FRAMES,
            "/ground_truth/pose": FRAMES,
            "/ground_truth/path": 1,
            "/tf_static": 1,
        }, reader.__name__
        assert types["/camera/detections"] == "vision_msgs/msg/Detection2DArray"
        assert types["/camera/depth/camera_info"] == "sensor_msgs/msg/CameraInfo"
        assert types["/tf"] == "tf2_msgs/msg/TFMessage"
        assert types["/ground_truth/path"] == "nav_msgs/msg/Path"
        times = [t for found in messages.values() for t, _ in found]
        assert min(times) == colour[0][0]

        for k, (t, message) in enumerate(messages["/camera/color/image_raw"]):
            assert t == stamp(message) == colour[k][0]
            assert message.header.frame_id == "camera_color_optical_frame"
            assert (message.encoding, message.height, message.width, message.step) == ("rgb8", 48, 64, 192)
            assert raw_bytes(message.data) == png(sequence / colour[k][1]).tobytes()
        for k, (t, message) in enumerate(messages["/camera/depth/image"]):
            assert t == stamp(message) == depth[k][0]
            assert message.header.frame_id == "camera_color_optical_frame"  # registered to colour
            assert (message.encoding, message.is_bigendian, message.step) == ("32FC1", 0, 64 * 4)
            metres = np.frombuffer(raw_bytes(message.data), "<f4").reshape(48, 64)
            stored = png(sequence / depth[k][1])
            assert stored.dtype == np.uint16 and (stored == 0).any()
            np.testing.assert_array_equal(np.isnan(metres), stored == 0)
            np.testing.assert_array_equal(np.nan_to_num(np.rint(metres * 5000.0)).astype(np.uint16), stored)
        for topic in ("/camera/color/camera_info", "/camera/depth/camera_info"):
            for t, info in messages[topic]:
                assert t == stamp(info)
                assert (info.width, info.height, info.distortion_model) == (64, 48, "plumb_bob")
                np.testing.assert_array_equal(info.k, [50, 0, 31.5, 0, 50, 23.5, 0, 0, 1])
                np.testing.assert_array_equal(info.p, [50, 0, 31.5, 0, 0, 50, 23.5, 0, 0, 0, 1, 0])
                np.testing.assert_array_equal(info.r, np.eye(3).ravel())
                np.testing.assert_array_equal(info.d, np.zeros(5))

        for k, ((t_tf, tf), (t_pose, pose)) in enumerate(
            zip(messages["/tf"], messages["/ground_truth/pose"], strict=True)
        ):
            (transform,) = tf.transforms
            assert t_tf == t_pose == stamp(transform) == stamp(pose) == gt_ns[k]
            assert (transform.header.frame_id, transform.child_frame_id) == (
                "world",
                "camera_color_optical_frame",
            )
            v, q = transform.transform.translation, transform.transform.rotation
            np.testing.assert_allclose([v.x, v.y, v.z], gt[k, :3], rtol=0, atol=1e-9)
            assert same_rotation(np.array([q.x, q.y, q.z, q.w]), gt[k, 3:])
            p, q = pose.pose.position, pose.pose.orientation
            np.testing.assert_allclose([p.x, p.y, p.z], gt[k, :3], rtol=0, atol=1e-9)
            assert same_rotation(np.array([q.x, q.y, q.z, q.w]), gt[k, 3:])
        ((t_path, path),) = messages["/ground_truth/path"]
        assert t_path == stamp(path) == colour[0][0] and len(path.poses) == FRAMES
        for k, pose in enumerate(path.poses):
            assert stamp(pose) == gt_ns[k] and pose.header.frame_id == "world"
            np.testing.assert_allclose([pose.pose.position.x, pose.pose.position.y], gt[k, :2], atol=1e-9)

        ((_, static),) = messages["/tf_static"]
        (link,) = static.transforms
        assert (link.header.frame_id, link.child_frame_id) == ("camera_color_optical_frame", "camera_link")
        r = link.transform.rotation
        optical_from_link = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
        np.testing.assert_allclose(optical_from_link @ [1, 0, 0], [0, 0, 1], atol=1e-12)  # forward = z
        np.testing.assert_allclose(optical_from_link @ [0, 0, 1], [0, -1, 0], atol=1e-12)  # up = -y
        np.testing.assert_allclose(optical_from_link @ [0, 1, 0], [-1, 0, 0], atol=1e-12)  # left = -x

        boxes_seen = 0
        for k, (t, array) in enumerate(messages["/camera/detections"]):
            assert t == stamp(array) == colour[k][0]
            visible = [o for o in objects[k]["objects"] if o["box_xyxy"] is not None]
            assert len(array.detections) == len(visible) > 0
            world_from_camera = np.eye(4)
            world_from_camera[:3, :3] = Rotation.from_quat(gt[k, 3:]).as_matrix()
            world_from_camera[:3, 3] = gt[k, :3]
            for detection, truth in zip(array.detections, visible, strict=True):
                x0, y0, x1, y1 = truth["box_xyxy"]
                (hypothesis,) = detection.results
                assert (hypothesis.hypothesis.class_id, detection.id) == (truth["class"], str(truth["id"]))
                assert hypothesis.hypothesis.score == 1.0
                box = detection.bbox
                assert (box.center.position.x, box.center.position.y) == ((x0 + x1) / 2, (y0 + y1) / 2)
                assert (box.size_x, box.size_y) == (x1 - x0, y1 - y0)
                p, q = hypothesis.pose.pose.position, hypothesis.pose.pose.orientation
                camera_from_object = np.eye(4)
                camera_from_object[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
                camera_from_object[:3, 3] = [p.x, p.y, p.z]
                world_from_object = world_from_camera @ camera_from_object
                np.testing.assert_allclose(world_from_object[:3, 3], truth["position_m"], atol=1e-9)
                truth_rotation = Rotation.from_quat(truth["quat_xyzw"]).as_matrix()
                np.testing.assert_allclose(world_from_object[:3, :3], truth_rotation, atol=1e-9)
                boxes_seen += 1
        assert boxes_seen == FRAMES  # the person; the chair is out of sight


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_the_16_bit_forms_hold_the_png_values_or_their_millimetres(sequence: Path, bags, storage: str):
    depth = frame_list(sequence / "depth.txt")
    for reader in READERS[storage]:
        for form, expected in (
            ("raw", lambda stored: stored),
            ("mm", lambda stored: np.where(stored > 0, np.maximum(np.rint(stored / 5.0), 1), 0)),
        ):
            messages, _ = reader(bags[(storage, form)])
            assert "/camera/depth/image" not in messages  # REP 118: 16-bit depth is image_raw
            found = messages["/camera/depth/image_raw"]
            assert len(found) == FRAMES
            for k, (_, message) in enumerate(found):
                assert (message.encoding, message.is_bigendian, message.step) == ("16UC1", 0, 128)
                values = np.frombuffer(raw_bytes(message.data), "<u2").reshape(48, 64)
                np.testing.assert_array_equal(values, expected(png(sequence / depth[k][1])))


def test_metadata_names_the_depth_form_and_plays_on_humble(bags):
    import yaml

    for (storage, depth), bag in bags.items():
        info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        assert info["version"] == 8 and info["storage_identifier"] == storage
        assert info["custom_data"]["depotbench.depth"] == DEPTH_FORMS[DepthUnit(depth)].meaning
        assert info["custom_data"]["depotbench.depth_scale"] == "5000"
        for topic in info["topics_with_message_count"]:
            qos = topic["topic_metadata"]["offered_qos_profiles"]
            assert isinstance(qos, str)  # Humble parses a string; v9's list would fail it
            profile = yaml.safe_load(qos)[0]
            latched = topic["topic_metadata"]["name"] in ("/tf_static", "/ground_truth/path")
            assert profile["reliability"] == 1 and profile["durability"] == (1 if latched else 2)
        assert sorted(p.name for p in bag.iterdir()) == sorted(
            [".depotbench.json", "metadata.yaml", f"{bag.name}.{'mcap' if storage == 'mcap' else 'db3'}"]
        )


def test_evo_reads_the_pose_topic_as_groundtruth(bags, sequence: Path):
    """The bag as evo's users read it (``evo_ape bag2 BAG /ground_truth/pose ...``)."""
    from evo.tools.file_interface import read_bag_trajectory, read_tum_trajectory_file
    from rosbags.rosbag2 import Reader

    reference = read_tum_trajectory_file(str(sequence / "groundtruth.txt"))
    for storage in ("mcap", "sqlite3"):
        with Reader(bags[(storage, "m")]) as reader:
            trajectory = read_bag_trajectory(reader, "/ground_truth/pose")
        np.testing.assert_allclose(trajectory.timestamps, reference.timestamps, rtol=0, atol=1e-9)
        np.testing.assert_allclose(trajectory.positions_xyz, reference.positions_xyz, atol=1e-9)
        np.testing.assert_allclose(
            trajectory.orientations_quat_wxyz, reference.orientations_quat_wxyz, atol=1e-9
        )


def test_same_sequence_same_bytes_and_compression_changes_only_the_size(sequence: Path, tmp_path: Path):
    a = write_bag(sequence, tmp_path / "a" / "bag", progress=False)
    b = write_bag(sequence, tmp_path / "b" / "bag", progress=False)
    for name in ("bag.mcap", "metadata.yaml"):  # the file's name is in both: the same name, then
        assert (tmp_path / "a" / "bag" / name).read_bytes() == (tmp_path / "b" / "bag" / name).read_bytes()
    z = write_bag(sequence, tmp_path / "z" / "bag", compress=True, progress=False)
    assert z.size_bytes < a.size_bytes == b.size_bytes
    plain, _ = read_mcap(tmp_path / "a" / "bag")
    packed, _ = read_mcap(tmp_path / "z" / "bag")
    for topic in ("/camera/color/image_raw", "/camera/depth/image"):
        assert [raw_bytes(m.data) for _, m in plain[topic]] == [raw_bytes(m.data) for _, m in packed[topic]]


def test_a_real_tum_folder_exports_its_100hz_groundtruth_and_distortion(sequence: Path, tmp_path: Path):
    root = tum_like(sequence, tmp_path / "rgbd_dataset_freiburg1_xyz", with_groundtruth=True)
    summary = write_bag(root, tmp_path / "bag", progress=False)
    assert summary.notes == ()
    gt_ns, gt = groundtruth(root / "groundtruth.txt")
    depth = frame_list(root / "depth.txt")
    messages, _ = read_mcap(tmp_path / "bag")
    assert "/camera/detections" not in messages
    assert [t for t, _ in messages["/tf"]] == gt_ns and len(gt_ns) == 110
    for k, (_, pose) in enumerate(messages["/ground_truth/pose"]):
        q = pose.pose.orientation
        assert same_rotation(np.array([q.x, q.y, q.z, q.w]), gt[k, 3:])
    assert [stamp(m) for _, m in messages["/camera/depth/image"]] == [t for t, _ in depth]
    assert [stamp(m) for _, m in messages["/camera/depth/camera_info"]] == [t for t, _ in depth]
    np.testing.assert_array_equal(
        messages["/camera/color/camera_info"][0][1].d, [0.26, -0.95, -0.005, 0.003, 1.16]
    )
    times = [t for found in messages.values() for t, _ in found]
    assert min(times) == gt_ns[0]  # the static TF and the path open the bag


def test_a_tum_folder_without_groundtruth_exports_images_and_says_so(sequence: Path, tmp_path: Path, capsys):
    root = tum_like(sequence, tmp_path / "rgbd_dataset_freiburg3_secret", with_groundtruth=False)
    code, out, err = run_cli(capsys, root, "-o", tmp_path / "bag")
    assert code == 0, err
    assert "note: no groundtruth.txt: no /tf, /ground_truth/pose or /ground_truth/path" in out
    messages, _ = read_rosbags(tmp_path / "bag")
    assert sorted(messages) == sorted([*IMAGE_TOPICS, "/camera/depth/image", "/tf_static"])


def test_the_command_prints_each_topic_and_a_namespace_renames_topics_and_frames(
    sequence: Path, tmp_path: Path, capsys
):
    bag = tmp_path / "bag"
    code, out, err = run_cli(
        capsys, sequence, "-o", bag, "--storage", "sqlite3", "--namespace", "/robot1/rgbd", "--detections"
    )
    assert code == 0, err
    assert f"wrote {bag} (sqlite3, {FRAMES} frames," in out
    assert re.search(rf"\n  /robot1/rgbd/detections +vision_msgs/msg/Detection2DArray +{FRAMES}\n", out)
    messages, _ = read_sqlite(bag)
    assert "/robot1/rgbd/color/image_raw" in messages
    assert messages["/tf"][0][1].transforms[0].child_frame_id == "robot1_rgbd_color_optical_frame"


def test_the_command_line_choices_are_the_library_s():
    assert tuple(s.value for s in BagStorage) == cli_rosbag.STORAGES
    assert tuple(d.value for d in DepthUnit) == cli_rosbag.DEPTHS
    assert cli_rosbag.DEFAULT_NAMESPACE == rosbag.DEFAULT_NAMESPACE


# -- bad input: one line, exit 2, nothing left behind -----------------------------------------


def test_not_a_sequence_folder(tmp_path: Path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    for source in (tmp_path / "missing", empty, plain):
        code, _, err = run_cli(capsys, source, "-o", tmp_path / "bag")
        assert code == EXIT_INPUT_ERROR
        one_error_line(err, str(source))
    assert listing(tmp_path) == ["empty", "plain.txt"]


def test_an_existing_output_is_replaced_only_with_overwrite_and_only_if_a_bag(
    sequence: Path, tmp_path: Path, capsys
):
    bag = tmp_path / "bag"
    assert run_cli(capsys, sequence, "-o", bag)[0] == 0
    before = {p.name: p.read_bytes() for p in bag.iterdir()}
    code, _, err = run_cli(capsys, sequence, "-o", bag)
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, str(bag), "already exists", "--overwrite")
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == before
    code, _, err = run_cli(capsys, sequence, "-o", bag, "--overwrite", "--storage", "sqlite3")
    assert code == 0, err
    assert sorted(p.name for p in bag.iterdir()) == [".depotbench.json", "bag.db3", "metadata.yaml"]

    foreign = tmp_path / "recorded"
    foreign.mkdir()
    (foreign / "metadata.yaml").write_text("a bag ros2 bag record wrote")
    code, _, err = run_cli(capsys, sequence, "-o", foreign, "--overwrite")
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, "not written by depotbench")
    assert listing(foreign) == ["metadata.yaml"]

    other = tmp_path / "other-seq"
    write_sequence(other, n=2)
    code, _, err = run_cli(capsys, sequence, "-o", other, "--overwrite")
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, "sequence output, not a rosbag output")
    assert listing(tmp_path) == ["bag", "other-seq", "recorded"]


def test_bad_storage_depth_namespace_and_options(sequence: Path, tmp_path: Path, capsys):
    code, _, err = run_cli(capsys, sequence, "-o", tmp_path / "bag", "--storage", "zip")
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, "--storage", "'zip'")
    for option, value in (("storage", "zip"), ("depth", "cm")):
        with pytest.raises(InputError, match=rf"^{option} '{value}' is not one of "):
            write_bag(sequence, tmp_path / "bag", **{option: value})
    for namespace in ("camera", "/1cam", "/cam//rgb", "/cam/", "/ground_truth", "/cäm"):
        code, _, err = run_cli(capsys, sequence, "-o", tmp_path / "bag", "--namespace", namespace)
        assert code == EXIT_INPUT_ERROR
        one_error_line(err, repr(namespace), "not a ROS 2 namespace")
    code, _, err = run_cli(capsys, sequence, "-o", tmp_path / "bag", "--storage", "sqlite3", "--compress")
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, "compression applies to MCAP bags")
    root = tum_like(sequence, tmp_path / "rgbd_dataset_freiburg1_desk", with_groundtruth=True)
    code, _, err = run_cli(capsys, root, "-o", tmp_path / "bag", "--detections")
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, str(root), "detections need a generated sequence")
    assert listing(tmp_path) == ["rgbd_dataset_freiburg1_desk"]


def test_unwritable_places_and_the_input_itself_are_refused(sequence: Path, tmp_path: Path, capsys):
    plain = tmp_path / "plain-file"
    plain.write_text("")
    for target in (plain / "bag", Path("/proc/depotbench-cannot-write/bag"), sequence / "bag", sequence):
        code, _, err = run_cli(capsys, sequence, "-o", target)
        assert code == EXIT_INPUT_ERROR
        one_error_line(err, str(target))
    assert listing(tmp_path) == ["plain-file"]
    assert "bag" not in listing(sequence) and not list(sequence.parent.glob(".seq*"))


def test_a_corrupt_frame_names_its_file_and_leaves_no_bag(sequence: Path, tmp_path: Path, capsys):
    copy = tmp_path / "seq"
    shutil.copytree(sequence, copy)
    _, name = frame_list(copy / "depth.txt")[17]
    (copy / name).write_bytes((copy / name).read_bytes()[:60])  # truncated
    code, _, err = run_cli(capsys, copy, "-o", tmp_path / "bag")
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, str(copy / name))
    assert listing(tmp_path) == ["seq"]  # no bag, no staging folder, no lock


def test_depth_beyond_16_bit_millimetres_is_refused_naming_the_file():
    raw = np.array([[0, 10, 40000]], dtype=np.uint16)  # 80 m at 500 units per metre
    with pytest.raises(InputError, match=r"^depth/1.000000.png: depth 80.000 m exceeds 16UC1"):
        DEPTH_FORMS[DepthUnit.MILLIMETRES].convert(raw, 500.0, Path("depth/1.000000.png"))
    np.testing.assert_array_equal(
        DEPTH_FORMS[DepthUnit.MILLIMETRES].convert(raw[:, :2], 500.0, Path()), [[0, 20]]
    )
