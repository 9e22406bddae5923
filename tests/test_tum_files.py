"""TUM text files are read as TUM's own tools read them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from depotbench.core.errors import SequenceFormatError
from depotbench.eval.metrics.trajectory import Trajectory, read_tum, write_tum
from depotbench.sim.tum_files import read_frame_list, read_pose_file


def test_separators_and_comments(tmp_path: Path):
    path = tmp_path / "traj.txt"
    path.write_text(
        "# timestamp tx ty tz qx qy qz qw\n\n"
        "1.0 1 2 3 0 0 0 1\n"
        "2.0\t1,2,3\t0 0  0   1\n"
        "  # indented comment\n"
        "3.0 1 2 3 0 0 0 2\n"  # non-unit: an estimate is normalised, as evo does
    )
    traj = read_tum(path)
    assert len(traj) == 3
    np.testing.assert_allclose(traj.positions_m, [[1, 2, 3]] * 3)
    np.testing.assert_allclose(traj.rotations[2], np.eye(3), atol=1e-12)
    with pytest.raises(SequenceFormatError, match=r"traj.txt:6: quaternion .* norm 2, not 1"):
        read_pose_file(path, strict=True)


def test_zero_quaternion_is_refused_even_for_estimates(tmp_path: Path):
    path = tmp_path / "traj.txt"
    path.write_text("1.0 0 0 0 0 0 0 0\n")
    with pytest.raises(SequenceFormatError, match=r"traj.txt:1: quaternion"):
        read_tum(path)


def test_write_read_round_trip(tmp_path: Path):
    rng = np.random.default_rng(0)
    from scipy.spatial.transform import Rotation

    traj = Trajectory(
        np.arange(10) + 0.5,
        rng.normal(0, 1, (10, 3)),
        Rotation.random(10, random_state=1).as_matrix(),
    )
    write_tum(tmp_path / "t.txt", traj)
    back = read_tum(tmp_path / "t.txt")
    np.testing.assert_allclose(back.positions_m, traj.positions_m, atol=1e-9)
    np.testing.assert_allclose(back.rotations, traj.rotations, atol=1e-8)


def test_empty_and_binary_files(tmp_path: Path):
    empty = tmp_path / "rgb.txt"
    empty.write_text("# nothing\n")
    with pytest.raises(SequenceFormatError, match="rgb.txt: lists no frames"):
        read_frame_list(empty)
    binary = tmp_path / "bin.txt"
    binary.write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(SequenceFormatError, match="not a text file"):
        read_tum(binary)
