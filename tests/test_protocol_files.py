"""The files an external program writes are read as docs/external-trackers.md says: every
trajectory and keypoint line checked, a bad one a failed run naming the file and line, and
a large file read in bounded memory."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from depotbench.eval.metrics.trajectory import read_tum
from depotbench.eval.trackers import columns
from depotbench.eval.trackers.protocol import (
    KEYPOINTS_HEADER,
    ProtocolError,
    read_keypoints,
    read_trajectory,
    write_keypoints,
)
from depotbench.sim.sequence import Sequence

from tests.sequences import write_sequence
from tests.test_output import cli, one_error_line


@pytest.fixture
def seq(tmp_path: Path) -> Path:
    write_sequence(tmp_path / "seq", n=4, with_flow=False)
    return tmp_path / "seq"


def pose_lines(seq: Path) -> list[str]:
    """The ground truth's pose lines: one a frame, at the frames' times."""
    text = (seq / "groundtruth.txt").read_text()
    return [line for line in text.splitlines() if line.strip() and not line.startswith("#")]


def shifted(line: str, seconds: float) -> str:
    stamp, *rest = line.split()
    return " ".join([f"{float(stamp) + seconds:.6f}", *rest])


# -- O5, O6, O7: the trajectory ------------------------------------------------------------


@pytest.fixture(params=[columns.BLOCK_BYTES, 97], ids=["one-block", "97-byte-blocks"])
def block_bytes(request, monkeypatch) -> int:
    """Every reader runs whole and cut into blocks that split lines anywhere."""
    monkeypatch.setattr(columns, "BLOCK_BYTES", request.param)
    return request.param


def test_a_good_trajectory_gives_each_frame_the_pose_evo_reads(seq: Path, tmp_path: Path, block_bytes):
    lines = pose_lines(seq)
    # Frame 2 untracked; commas, tabs, CRLF and comments as TUM's tools take them.
    text = "# t tx ty tz qx qy qz qw\r\n" + lines[3].replace(" ", ",") + "\r\n\n" + lines[0] + "\n"
    path = tmp_path / "trajectory.txt"
    path.write_text(text + lines[1].replace(" ", "\t"))  # the last line without a newline
    poses = read_trajectory(path, Sequence.open(seq))
    reference = read_tum(seq / "groundtruth.txt").poses  # the evo-compatible reader
    assert poses[2] is None
    for i in (0, 1, 3):
        np.testing.assert_allclose(poses[i], reference[i], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("edit", "line", "needle"),
    [
        # O5: every pose 100 s late was "tracked 0/4", rc 0.
        (lambda ls: [shifted(x, 100.0) for x in ls], 1, "timestamp 101.000000 is no frame's"),
        (lambda ls: [*ls, shifted(ls[0], 98.0)], 5, "timestamp 99.000000 is no frame's"),
        # O6: a second pose for frame 1, 5 m off, was dropped without a word.
        (
            lambda ls: [*ls, ls[1].split()[0] + " 5 0 0 0 0 0 1"],
            5,
            "frame 1's again, whose pose is on line 2",
        ),
        (lambda ls: [ls[0], ls[1], shifted(ls[1], 0.0004)], 3, "frame 1's again, whose pose is on line 2"),
        # O7: a quaternion of norm 2 was normalised and used.
        (lambda ls: [ls[0], ls[1].split()[0] + " 0 0 0 0 0 0 2"], 2, "has norm 2, not 1 (within 0.001)"),
        (lambda ls: [ls[0], ls[1].split()[0] + " 0 0 0 0 0 0 1.0011"], 2, "has norm 1.0011"),
        (lambda ls: [ls[0], ls[1].split()[0] + " 0 0 0 nan 0 0 1"], 2, "NaN or infinity"),
        (lambda ls: [ls[0], ls[1].split()[0] + " 0 0 0 0 0 1"], 2, "expected 8 fields"),
        (lambda ls: [ls[0], ls[1].split()[0] + " 0 x 0 0 0 0 1"], 2, "field 'x' is not a number"),
    ],
)
def test_a_bad_trajectory_line_is_named(seq: Path, tmp_path: Path, block_bytes, edit, line, needle):
    path = tmp_path / "trajectory.txt"
    path.write_text("\n".join(edit(pose_lines(seq))) + "\n")
    with pytest.raises(ProtocolError) as caught:
        read_trajectory(path, Sequence.open(seq))
    assert str(caught.value).startswith(f"{path}:{line}: "), caught.value
    assert needle in str(caught.value)


@pytest.mark.parametrize("text", ["", "\n\n  \n", "# only a comment\n\n"])
def test_a_trajectory_without_a_pose_line_tracked_nothing(seq: Path, tmp_path: Path, text: str):
    (tmp_path / "trajectory.txt").write_text(text)
    assert read_trajectory(tmp_path / "trajectory.txt", Sequence.open(seq)) == (None,) * 4


def test_a_quaternion_within_the_tolerance_is_taken(seq: Path, tmp_path: Path):
    lines = pose_lines(seq)
    path = tmp_path / "trajectory.txt"
    path.write_text(lines[0] + "\n" + lines[1].split()[0] + " 0 0 0 0 0 0 1.0009\n")
    assert np.array_equal(read_trajectory(path, Sequence.open(seq))[1], np.eye(4))


def test_ground_truth_keeps_tums_leniency(tum_trajectories: Path):
    """read_tum stays evo's reader: TUM's fr2/desk ground truth repeats a timestamp, and
    stored quaternions are normalised there."""
    assert len(read_tum(tum_trajectories / "fr2_desk_groundtruth.txt")) == 20957


# -- O8: the keypoint file's header and kind ----------------------------------------------


def keypoint_text(seq: Path) -> str:
    stamps = [line.split()[0] for line in pose_lines(seq)]
    return "".join(f"{s} 10.5 20.25 1\n{s} 30.0 5.0 0 box\n" for s in stamps)


@pytest.mark.parametrize(
    ("head", "needle"),
    [
        ("# depotbench keypoints 2\n", "keypoint file version 2 is unknown"),
        ("# timestamp x y kept [reason]\n", "the first line must be '# depotbench keypoints 1'"),
        ("", "the first line must be '# depotbench keypoints 1'"),
    ],
)
def test_a_keypoint_file_without_its_header_is_refused(seq: Path, tmp_path: Path, head: str, needle: str):
    path = tmp_path / "keypoints.txt"
    path.write_text(head + keypoint_text(seq))
    with pytest.raises(ProtocolError, match=needle):
        read_keypoints(path, Sequence.open(seq))


def test_an_empty_keypoint_file_is_refused(seq: Path, tmp_path: Path):
    (tmp_path / "keypoints.txt").write_bytes(b"")
    with pytest.raises(ProtocolError, match="is empty: a keypoint file begins with"):
        read_keypoints(tmp_path / "keypoints.txt", Sequence.open(seq))


def reference_keypoints(path: Path, n_frames: int, stamps: list[str]):
    """The file read line by line in plain Python, as the reader was before it streamed."""
    points = [[] for _ in range(n_frames)]
    kept = [[] for _ in range(n_frames)]
    reasons = [[] for _ in range(n_frames)]
    for line in path.read_text().splitlines()[1:]:
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        frame = stamps.index(fields[0])
        points[frame].append((float(fields[1]), float(fields[2])))
        kept[frame].append(fields[3] == "1")
        reasons[frame].append(fields[4] if len(fields) == 5 else "")
    return points, kept, reasons


def test_keypoints_read_in_blocks_are_every_line_of_the_file(seq: Path, tmp_path: Path, block_bytes):
    """Frames interleaved, reasons, comments and blank lines, read whole and in blocks that
    cut lines anywhere, against a plain line-by-line reading."""
    sequence = Sequence.open(seq)
    stamps = [line.split()[0] for line in pose_lines(seq)]
    rng = np.random.default_rng(5)
    lines = [KEYPOINTS_HEADER]
    for _ in range(300):
        frame = int(rng.integers(0, 3))  # frame 3 gets none
        x, y = rng.uniform(-0.5, 63.49), rng.uniform(-0.5, 47.49)
        reason = ["", " box", " epipolar", " flow\u00e9"][int(rng.integers(0, 4))]
        lines.append(f"{stamps[frame]}  {x!r}\t{y!r} {0 if reason else 1}{reason}\r\n")
        if rng.random() < 0.05:
            lines.append("# a comment\n\n")
    path = tmp_path / "keypoints.txt"
    path.write_text("".join(lines))
    decisions = read_keypoints(path, sequence)
    points, kept, reasons = reference_keypoints(path, len(sequence), stamps)
    for i in range(len(sequence)):
        # stored as float32 (half the memory of a 330 MB file's 12.7M keypoints)
        assert np.array_equal(decisions.keypoints_px[i], np.array(points[i], np.float32).reshape(-1, 2))
        assert np.array_equal(decisions.kept[i], np.array(kept[i], bool))
        assert decisions.reasons[i] == tuple(reasons[i])
    assert len(decisions.keypoints_px[3]) == 0


def test_what_write_keypoints_writes_comes_back(seq: Path, tmp_path: Path, block_bytes):
    sequence = Sequence.open(seq)
    rng = np.random.default_rng(2)
    points = [rng.uniform(0, 40, (n, 2)) for n in (3, 0, 5, 1)]
    kept = [rng.random(len(p)) < 0.5 for p in points]
    reasons = [["" if k else "box" for k in flags] for flags in kept]
    write_keypoints(tmp_path / "kp.txt", list(sequence.timestamps_s), points, kept, reasons)
    back = read_keypoints(tmp_path / "kp.txt", sequence)
    for i in range(4):
        assert np.array_equal(back.keypoints_px[i], points[i].astype(np.float32).reshape(-1, 2))
        assert np.array_equal(back.kept[i], kept[i])
    assert back.reasons == tuple(tuple(r) for r in reasons)


@pytest.mark.parametrize(
    ("line", "needle"),
    [
        ("{t} 10 20 2", "kept must be 1 or 0, got '2'"),
        ("{t} 64 20 1", "keypoint (64, 20) is not inside the 64x48 image"),
        ("{t} nan 20 1", "is not inside"),
        ("{t} 10 20", "expected timestamp x y kept [reason], found 3 fields"),
        ("{t} 10 20 1 a b", "found 6 fields"),
        ("{t} 1e1x 20 1", "x '1e1x' is not a number"),
        ("99.0 10 20 1", "timestamp 99.0 is no frame's"),
        ("inf 10 20 1", "timestamp 'inf' is not a finite number"),
        ("{t} 10 20 1 " + "w" * 65, "field 5 is longer than 64 characters"),
    ],
)
def test_a_bad_keypoint_line_is_named(seq: Path, tmp_path: Path, block_bytes, line: str, needle: str):
    stamp = pose_lines(seq)[1].split()[0]
    path = tmp_path / "keypoints.txt"
    path.write_text(KEYPOINTS_HEADER + keypoint_text(seq) + line.format(t=stamp) + "\n")
    with pytest.raises(ProtocolError) as caught:
        read_keypoints(path, Sequence.open(seq))
    assert str(caught.value).startswith(f"{path}:11: "), caught.value
    assert needle in str(caught.value)


def test_a_line_without_end_is_refused_at_its_bound(seq: Path, tmp_path: Path, monkeypatch):
    monkeypatch.setattr(columns, "BLOCK_BYTES", 1024)
    path = tmp_path / "keypoints.txt"
    path.write_bytes(KEYPOINTS_HEADER.encode() + b"1" * (columns.MAX_LINE_BYTES + 5000))
    with pytest.raises(ProtocolError, match=r"keypoints.txt:3: is longer than 65536 bytes"):
        read_keypoints(path, Sequence.open(seq))


# -- O5 and O8 through a run: a failed run naming the file and line -------------------------

WRITE = 'sh -c \'cp "$1" "$2" && {keypoints}\' sh {answer} {{trajectory}} {{keypoints}}'
"""A program that answers with a prepared trajectory and does ``keypoints`` to ``$3``."""


@pytest.mark.parametrize(
    ("late_s", "keypoints", "needle"),
    [
        # O5: "tracked 0/4", exit 0, before.
        (100.0, "true", "trajectory.txt:1: timestamp 101.000000 is no frame's"),
        # O8: each of these meant "no keypoints", exit 0, before.
        (0.0, 'mkdir "$3"', "keypoints.txt: is a directory"),
        (0.0, 'mkfifo "$3"', "keypoints.txt: is not a regular file"),
        (0.0, 'ln -s /dev/zero "$3"', "keypoints.txt: is not a regular file"),
        (0.0, 'echo "# depotbench keypoints 2" > "$3"', "keypoints.txt:1: keypoint file version 2"),
    ],
)
def test_a_program_that_writes_a_bad_file_fails_its_run(
    seq: Path, tmp_path: Path, capsys, late_s: float, keypoints: str, needle: str
):
    answer = tmp_path / "answer.txt"
    answer.write_text("".join(shifted(line, late_s) + "\n" for line in pose_lines(seq)))
    command = WRITE.format(keypoints=keypoints, answer=shlex.quote(str(answer)))
    code, _, err = cli(capsys, "run", seq, "-o", tmp_path / "out", "--slam", "cmd", "--command", command)
    assert code != 0, err
    one_error_line(err, needle)


# -- N11: a large keypoint file in bounded memory ------------------------------------------


def big_keypoint_file(path: Path, seq: Path, megabytes: int) -> int:
    """A keypoint file of about ``megabytes`` MB, lines as a C++ program prints them; the
    number of keypoints in it."""
    stamps = [line.split()[0] for line in pose_lines(seq)]
    rng = np.random.default_rng(0)
    block = "".join(
        f"{{t}} {x:.3f} {y:.3f} {'1' if k else '0 box'}\n"
        for x, y, k in zip(
            rng.uniform(0, 63, 4000), rng.uniform(0, 47, 4000), rng.random(4000) < 0.7, strict=True
        )
    )
    count = 0
    with path.open("w") as out:
        out.write(KEYPOINTS_HEADER)
        while out.tell() < megabytes * 1_000_000:
            out.write(block.replace("{t}", stamps[count // 4000 % len(stamps)]))
            count += 4000
    return count


@pytest.mark.parametrize("megabytes", [10, pytest.param(330, marks=pytest.mark.slow)])
def test_a_large_keypoint_file_is_read_in_bounded_memory(seq: Path, tmp_path: Path, megabytes: int):
    """Read whole and split into strings, 330 MB cost 3.2 GB (10 MB: 100 MB at the peak);
    now its arrays (19 bytes a keypoint) and a few blocks' worth of work."""
    import tracemalloc

    count = big_keypoint_file(tmp_path / "kp.txt", seq, megabytes)
    tracemalloc.start()
    try:
        decisions = read_keypoints(tmp_path / "kp.txt", Sequence.open(seq))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert sum(len(p) for p in decisions.keypoints_px) == count
    result = count * 19  # points, flag and reason code of each keypoint
    assert peak < result + 40 * 2**20, (peak / 2**20, result / 2**20)


# -- N6: lens distortion is bounded as the focal length is ---------------------------------


@pytest.mark.parametrize(
    ("flags", "needle"),
    [
        # 1e30 gave "tracked 6/6, ATE 4.4e12 m", rc 0; 1e6 a plausible-looking 0.031 m.
        (["--distortion", "1e30", "0", "0", "0"], "--distortion: distortion k1 = 1e+30 is outside"),
        (["--distortion", "0", "1e6", "0", "0"], "distortion k2 = 1e+06 is outside the plausible -10..10"),
        (["--distortion", "0", "0", "1.5", "0"], "distortion p1 = 1.5 is outside the plausible -1..1"),
        (["--distortion", "0", "0", "0", "0", "-11"], "distortion k3 = -11 is outside"),
        (["--camera", "CAMERA"], "cam.yaml: Camera.k1 = 1e+30 is outside the plausible -10..10"),
    ],
)
def test_an_implausible_lens_distortion_is_one_line_naming_it(tmp_path: Path, capsys, flags, needle):
    from tests.test_camera_input import as_real

    write_sequence(tmp_path / "generated", n=4, with_flow=False)
    real = as_real(tmp_path / "generated", tmp_path / "my_recording")
    camera = (tmp_path / "generated" / "camera.yaml").read_text()
    assert "Camera.k1: 0.0" in camera
    (tmp_path / "cam.yaml").write_text(camera.replace("Camera.k1: 0.0", "Camera.k1: 1e30"))
    if flags[0] == "--distortion":
        flags = ["--intrinsics", "50", "50", "31.5", "23.5", *flags]
    flags = [str(tmp_path / "cam.yaml") if f == "CAMERA" else f for f in flags]
    out = tmp_path / "out"
    code, _, err = cli(capsys, "run", real, "-o", out, "--detector", "none", *flags)
    assert code == 2
    one_error_line(err, needle)
    assert not out.exists()


def test_a_real_lens_distortion_is_taken(tmp_path: Path):
    """TUM fr1's calibration (k3 1.16) and values at the bounds pass."""
    from depotbench.core.camera import CameraOverride

    for distortion in ((0.2624, -0.9531, -0.0054, 0.0026, 1.1633), (10.0, -10.0, 1.0, -1.0, 10.0)):
        assert CameraOverride((517.3, 516.5, 318.6, 255.3), distortion).distortion == distortion


# -- N16: a program's map of coincident points ---------------------------------------------


def test_coincident_map_points_score_as_brute_force_and_fast():
    """A program that writes a point once per keyframe that saw it: the distances are the
    brute-force ones, and 30,000 copies against 30,000 reference points take well under a
    second (a k-d tree cannot split equal points: this took 6 s, 500,000 of them 65 s)."""
    import time

    from depotbench.eval.metrics.map import InstanceCloud, ReferenceClouds, map_distances, map_metrics

    rng = np.random.default_rng(3)
    static = rng.uniform(-1, 1, (400, 3))
    person = rng.uniform(-0.2, 0.2, (50, 3)) + 0.5
    reference = ReferenceClouds(static, (InstanceCloud(6, "person", person),))
    points = np.concatenate([np.repeat(rng.uniform(-1, 1, (5, 3)), 60, axis=0), person[:3], static[:7]])
    points[0] = -0.0  # -0.0 and 0.0 are one place
    points[1] = 0.0
    rng.shuffle(points)
    distances = map_distances(points, reference)

    def brute(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=2)).min(axis=1)

    np.testing.assert_allclose(distances.to_static_m, brute(points, static), rtol=0, atol=1e-12)
    np.testing.assert_allclose(distances.static_to_map_m, brute(static, points), rtol=0, atol=1e-12)
    np.testing.assert_allclose(distances.to_moving_m[:, 0], brute(points, person), rtol=0, atol=1e-12)

    big_static = rng.uniform(-5, 5, (30_000, 3))
    big = ReferenceClouds(big_static)
    assert big.static_tree is not None  # built before the clock starts, as a reference is once
    copies = np.repeat(big_static[:1], 30_000, axis=0)
    started = time.perf_counter()
    scores = map_metrics(copies, big, thresholds=(0.02,)).at(0.02)
    assert time.perf_counter() - started < 1.0
    assert scores.accuracy == 1.0 and scores.completeness == 1 / 30_000


# -- a program's map: the PLY read in chunks -------------------------------------------------


def ply_bytes(points: np.ndarray, colours: np.ndarray | None, form: str, faces: bool = False) -> bytes:
    """A PLY written here, by the format's definition (not by the reader under test)."""
    props = [("x", "f4"), ("y", "f4"), ("z", "f8")] + (
        [("red", "u1"), ("green", "u1"), ("blue", "u1")] if colours is not None else []
    )
    names = {"f4": "float", "f8": "double", "u1": "uchar"}
    head = [f"ply\nformat {form} 1.0\ncomment by a test\nelement vertex {len(points)}\n"]
    head += [f"property {names[kind]} {name}\n" for name, kind in props]
    if faces:
        head.append("element face 1\nproperty list uchar int vertex_indices\n")
    head.append("end_header\n")
    if form == "ascii":
        rows = [
            " ".join([*(repr(float(np.float32(v))) for v in p[:2]), repr(float(p[2]))])
            + ("" if colours is None else " " + " ".join(str(int(c)) for c in colours[i]))
            for i, p in enumerate(points)
        ]
        body = ("\n".join(rows) + "\n" + ("3 0 1 2\n" if faces else "")).encode()
    else:
        order = "<" if form == "binary_little_endian" else ">"
        table = np.zeros(len(points), [(n, order + k) for n, k in props])
        for axis, name in enumerate("xyz"):
            table[name] = points[:, axis]
        if colours is not None:
            for channel, name in enumerate(("red", "green", "blue")):
                table[name] = colours[:, channel]
        body = table.tobytes() + (
            np.array([3], "u1").tobytes() + np.array([0, 1, 2], order + "i4").tobytes() if faces else b""
        )
    return "".join(head).encode() + body


@pytest.mark.parametrize("form", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("coloured", [True, False])
@pytest.mark.parametrize("faces", [False, True])
def test_a_map_read_in_chunks_is_what_trimesh_reads(tmp_path: Path, monkeypatch, form, coloured, faces):
    import trimesh
    from depotbench.eval.trackers import ply
    from depotbench.eval.trackers.protocol import read_map

    monkeypatch.setattr(ply, "CHUNK_VERTICES", 7)
    monkeypatch.setattr(columns, "BLOCK_BYTES", 61)
    rng = np.random.default_rng(4)
    points = rng.normal(0, 3, (50, 3))
    colours = rng.integers(0, 256, (50, 3)).astype(np.uint8)
    path = tmp_path / "map.ply"
    path.write_bytes(ply_bytes(points, colours if coloured else None, form, faces))
    got_points, got_colours = read_map(path)
    reference = trimesh.load(path, file_type="ply", process=False)  # the general reader
    np.testing.assert_array_equal(got_points, np.asarray(reference.vertices, np.float64))
    expected = colours if coloured else np.full((50, 3), 160, np.uint8)
    np.testing.assert_array_equal(got_colours, expected)


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        (b"ply\nformat binary_little_endian 1.0\nelement vertex 9\n", "no PLY header ending in end_header"),
        (b"ply\n", "no PLY header"),
        (
            b"ply\nformat binary_little_endian 1.0\nelement vertex 9\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n" + bytes(12 * 8),
            "is cut short: 9 vertices of 12 bytes",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n1 2 3\n4 5 6\n",
            "is cut short: 3 vertices declared, 2 found",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n1 2 3\n4 5\n",
            "map.ply:9: a vertex has 3 properties, this line 2",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n1 nan 3\n",
            "holds a point that is not finite",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n",
            "holds no points",
        ),
    ],
)
def test_a_damaged_map_is_named(tmp_path: Path, data: bytes, needle: str):
    from depotbench.eval.trackers.protocol import read_map

    (tmp_path / "map.ply").write_bytes(data)
    with pytest.raises(ProtocolError, match=re.escape(needle)):
        read_map(tmp_path / "map.ply")


def test_a_large_binary_map_is_read_in_bounded_memory(tmp_path: Path):
    """2M points (30 MB of binary PLY): read whole by trimesh they took 3.5 times their
    arrays at their peak; now their arrays (27 bytes a point) and a chunk."""
    import tracemalloc

    from depotbench.eval.trackers.protocol import read_map

    n = 2_000_000
    kinds = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    table = np.zeros(n, kinds)
    table["x"] = np.arange(n)
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n" + "".join(
        f"property {'float' if kind.endswith('f4') else 'uchar'} {name}\n" for name, kind in kinds
    )
    (tmp_path / "map.ply").write_bytes((header + "end_header\n").encode() + table.tobytes())
    del table
    tracemalloc.start()
    try:
        points, _ = read_map(tmp_path / "map.ply")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.array_equal(points[:, 0], np.arange(n))
    result = n * 27
    assert peak < result + 40 * 2**20, (peak / 2**20, result / 2**20)
