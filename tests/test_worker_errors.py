"""A job's error crosses from a worker (a process or a Ray task) as itself (probe U5).

Workers send errors back pickled. ``FileError`` takes (path, line, problem), and the default
rebuild calls ``__init__`` with its message alone: unpickling raised TypeError, so a bad
file in a Ray job reached the user as a 30-line ``UnserializableException``; and Ray wraps
what a task raised in ``RayTaskError`` with the worker's traceback in its message.
"""

from __future__ import annotations

import importlib.util
import pickle
from pathlib import Path

import pytest
from depotbench.core.errors import EnvironmentProblem, FileError, InputError, SequenceFormatError
from depotbench.core.output import OutputError
from depotbench.eval.trackers.base import TrackerError
from depotbench.eval.trackers.protocol import ProtocolError

from tests.sequences import write_sequence

ERRORS = [
    InputError("--set k: not a number"),
    FileError("/data/seq/rgb.txt", 4, "not a timestamp"),
    FileError("/data/seq", None, "no rgb.txt"),
    SequenceFormatError("/data/seq/depth.txt", 2, "two columns expected"),
    ProtocolError("/tmp/run/trajectory.txt", 7, "a pose at no frame's time"),
    OutputError("/out: is not a depotbench folder"),
    TrackerError("my_slam exited with 3", log="segfault"),
    EnvironmentProblem("no OpenGL: install libegl1"),
]


@pytest.mark.parametrize("error", ERRORS, ids=lambda e: type(e).__name__)
def test_the_projects_errors_cross_a_process_boundary_with_their_message_and_fields(error):
    back = pickle.loads(pickle.dumps(error))
    assert type(back) is type(error) and str(back) == str(error)
    assert back.__dict__.keys() == error.__dict__.keys()
    assert all(str(getattr(back, k)) == str(v) for k, v in vars(error).items())


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is the [ray] extra")
def test_a_bad_file_in_a_ray_job_reaches_the_caller_as_its_one_line_error(tmp_path: Path):
    """A real Ray task (starting Ray takes ~10 s) opens a sequence whose associations.txt has
    a bad line: the caller gets the reader's own FileError, its message one line naming file and
    line; a bug of ours (here a TypeError) keeps Ray's error and the worker's traceback."""
    import ray
    from depotbench.core.executors import RayPool
    from depotbench.sim.sequence import Sequence

    write_sequence(tmp_path / "seq", n=2)
    pairs = tmp_path / "seq" / "associations.txt"
    pairs.write_text(pairs.read_text() + "not-a-time rgb/x.png 1.0 depth/x.png\n")
    with pytest.raises(FileError) as local:
        Sequence.open(tmp_path / "seq")
    pool = RayPool(1, None)
    try:
        with pytest.raises(FileError) as remote:
            list(pool.map_unordered(Sequence.open, [(tmp_path / "seq",)]))
        with pytest.raises(ray.exceptions.RayTaskError):
            list(pool.map_unordered(Sequence.open, [(None, "not a camera")]))
    finally:
        pool.close(True)
    assert type(remote.value) is type(local.value)
    assert str(remote.value) == str(local.value) and "\n" not in str(remote.value)
    assert remote.value.line == local.value.line


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is the [ray] extra")
def test_a_local_ray_pool_starts_a_ray_of_its_own_whatever_ray_finds_on_the_machine(tmp_path, monkeypatch):
    """Without --address, ``--backend ray`` runs on a Ray of its own with --workers CPUs. Ray's
    default attaches to RAY_ADDRESS or to the last cluster ``ray start`` left on the machine
    and then refused ``num_cpus`` ("When connecting to an existing cluster, num_cpus and
    num_gpus must not be provided"), as a local sweep did beside the cluster test's nodes."""
    from depotbench.core.executors import RayPool
    from depotbench.sim.sequence import Sequence

    write_sequence(tmp_path / "seq", n=2)
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:9")  # a cluster that is not there
    pool = RayPool(1, None)
    try:
        opened = list(pool.map_unordered(Sequence.open, [(tmp_path / "seq",)]))
    finally:
        pool.close(False)
    assert len(opened) == 1 and len(opened[0]) == 2
