"""``export-rosbag`` on input other commands take: timestamps outside ROS 2's Time, a bag name
of up to 255 bytes, a namespace whose topics ROS 2 cannot create. Each is refused in one line
naming the file and line (or the option), or written; nothing half-written is left.

Limits are ROS 2's, written here: ``builtin_interfaces/msg/Time`` holds ``int32 sec``, and
rmw's ``RMW_TOPIC_MAX_NAME_LENGTH`` is 255 - 8 = 247 characters for a fully qualified topic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from depotbench.eval.cli.main import EXIT_INPUT_ERROR
from depotbench.eval.export.rosbag import WORLD_FRAME, path_cdr, typestore

from tests.capped import peak_rss_mb
from tests.test_rosbag import listing, one_error_line, read_rosbags, run_cli
from tests.test_rosbag_camera import tum_folder

INTRINSICS = ("--intrinsics", "50", "50", "31.5", "23.5")
TOPIC_MAX = 255 - 8
INT32_SECONDS = 2**31


def replaced(path: Path, line: int, timestamp: str) -> Path:
    """``path`` with the timestamp on ``line`` (1-based) replaced."""
    lines = path.read_text().splitlines()
    lines[line - 1] = " ".join([timestamp, *lines[line - 1].split()[1:]])
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    ("timestamp", "line"),
    [("-1.000000", 2), (f"{INT32_SECONDS}.000000", 4), (f"{INT32_SECONDS + 5}.250000", 4), ("1e300", 4)],
)
def test_a_ground_truth_time_outside_ros_time_names_its_file_and_line(
    tmp_path: Path, capsys, timestamp: str, line: int
):
    """Rows stay in increasing order (line 2 is the first, line 4 the last), as the reader
    requires: only the range is wrong."""
    root = tum_folder(tmp_path / "office", 64, 48)
    path = replaced(root / "groundtruth.txt", line, timestamp)
    code, _, err = run_cli(capsys, root, "-o", tmp_path / "bag", *INTRINSICS)
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, f"{path}:{line}:", "int32")
    assert len(err) < 400  # 1e300 is not written out in 300 digits
    assert listing(tmp_path) == ["office"]


def test_negative_frame_times_name_the_frame_list_and_line(tmp_path: Path, capsys):
    """``run`` takes a folder recorded before 1970; ROS 2's Time cannot hold it."""
    root = tum_folder(tmp_path / "office", 64, 48, start_s=-5.0)
    code, _, err = run_cli(capsys, root, "-o", tmp_path / "bag", *INTRINSICS)
    assert code == EXIT_INPUT_ERROR
    one_error_line(err, f"{root / 'rgb.txt'}:2:", "-5.000000", "int32")
    assert listing(tmp_path) == ["office"]


def test_the_last_second_ros_time_holds_is_written(tmp_path: Path, capsys):
    root = tum_folder(tmp_path / "office", 64, 48)
    replaced(root / "groundtruth.txt", 4, f"{INT32_SECONDS - 1}.999999")
    assert run_cli(capsys, root, "-o", tmp_path / "bag", *INTRINSICS)[0] == 0
    messages, _ = read_rosbags(tmp_path / "bag")
    stamp = messages["/ground_truth/pose"][-1][1].header.stamp
    assert (stamp.sec, stamp.nanosec) == (INT32_SECONDS - 1, 999_999_000)


@pytest.mark.parametrize("length", [250, 251, 255])
def test_a_bag_name_other_commands_take_is_written(tmp_path: Path, capsys, length: int):
    root = tum_folder(tmp_path / "office", 64, 48, frames=1)
    bag = tmp_path / ("b" * length)
    code, _, err = run_cli(capsys, root, "-o", bag, *INTRINSICS)
    assert code == 0, err
    messages, _ = read_rosbags(bag)
    assert len(messages["/camera/color/image_raw"]) == 1
    assert sorted(listing(tmp_path)) == sorted(["office", bag.name])


def test_a_namespace_whose_topics_ros_2_cannot_create_is_refused(tmp_path: Path, capsys):
    root = tum_folder(tmp_path / "office", 64, 48, frames=1)
    longest = "/" + "n" * (TOPIC_MAX - len("/" + "/color/camera_info"))
    assert len(f"{longest}/color/camera_info") == TOPIC_MAX
    for namespace in ("/" + "n" * 5000, longest + "x"):
        code, _, err = run_cli(capsys, root, "-o", tmp_path / "bag", *INTRINSICS, "--namespace", namespace)
        assert code == EXIT_INPUT_ERROR
        one_error_line(err, "--namespace", f"{len(namespace)} characters", str(TOPIC_MAX))
        assert len(err) < 400  # the namespace is not repeated 5000 characters long
    assert listing(tmp_path) == ["office"]
    code, _, err = run_cli(capsys, root, "-o", tmp_path / "bag", *INTRINSICS, "--namespace", longest)
    assert code == 0, err
    messages, _ = read_rosbags(tmp_path / "bag")
    assert max(len(topic) for topic in messages) == TOPIC_MAX


@pytest.mark.parametrize("n", [0, 1, 5])
def test_the_path_s_bytes_are_rosbags_own_serialization(n: int):
    """``path_cdr`` builds the Path from arrays; rosbags' serializer, given the same poses as
    message objects, is the reference, stamps at both ends of ROS 2's Time included."""
    rng = np.random.default_rng(n)
    pose_ns = np.sort(rng.integers(0, INT32_SECONDS * 10**9, n))
    if n:
        pose_ns[0], pose_ns[-1] = 0, INT32_SECONDS * 10**9 - 1
    positions, quats = rng.normal(size=(n, 3)), rng.normal(size=(n, 4))
    store = typestore()
    t = store.types

    def header(ns: int):
        sec, nanosec = divmod(int(ns), 10**9)
        return t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=WORLD_FRAME
        )

    poses = [
        t["geometry_msgs/msg/PoseStamped"](
            header=header(ns),
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            ),
        )
        for ns, p, q in zip(pose_ns, positions, quats, strict=True)
    ]
    start = 1_500_000_000_123_456_789
    reference = store.serialize_cdr(
        t["nav_msgs/msg/Path"](header=header(start), poses=poses), "nav_msgs/msg/Path"
    )
    assert bytes(path_cdr(start, WORLD_FRAME, pose_ns, positions, quats)) == bytes(reference)


@pytest.mark.slow
def test_a_400000_row_ground_truth_exports_in_under_300_mb(tmp_path: Path):
    """100 Hz motion capture for 67 minutes, the reader's and the Path's arrays kept as
    numbers: the peak was 719 MB (400,000 rows as objects, then 400,000 PoseStamped)."""
    root = tum_folder(tmp_path / "office", 64, 48, frames=2)
    n = 400_000
    rng = np.random.default_rng(0)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rows = np.column_stack([1.0 + np.arange(n) / 100, rng.normal(size=(n, 3)), q])
    np.savetxt(root / "groundtruth.txt", rows, fmt="%.4f %.4f %.4f %.4f %.6f %.6f %.6f %.6f")
    args = ["export-rosbag", str(root), "-o", str(tmp_path / "bag"), *INTRINSICS]
    # Measured from a small fresh process (tests/capped.py): a child's peak as Linux reports it
    # starts at its parent's, and pytest had grown to 610-1133 MB by this test.
    code, err, peak_mb = peak_rss_mb(args)
    assert code == 0, err
    assert peak_mb < 300, f"peak {peak_mb:.0f} MB"
