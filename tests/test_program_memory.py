"""A program's peak memory and how it ends, as ``run_child`` reports them (eval/trackers/external.py).

Linux folds a parent's high-water mark into a child's at fork and exec, so a peak taken from
``wait4`` on a program started straight from the bench is at least the bench's own peak:
``/bin/true`` started from a 790 MB process reported 790 MB. Programs now start through a small
launcher; these tests hold the reported peak to what the program itself allocated, from a
test process made large on purpose."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
from depotbench.eval.trackers.base import TrackerError
from depotbench.eval.trackers.external import MEASURED, run_child

pytestmark = pytest.mark.skipif(not MEASURED, reason="the launcher needs Linux's posix_spawnp and wait4")

BENCH_MB = 600
"""The test process is made at least this large before it starts each program."""


@pytest.fixture(scope="module")
def large_bench():
    """Hold BENCH_MB of touched memory in this process while the programs run."""
    held = np.ones(BENCH_MB << 17)  # float64: BENCH_MB MiB, every page written
    yield held
    del held


def _run(tmp_path: Path, code: str, program: tuple[str, ...] = (sys.executable, "-c")):
    return run_child([*program, code], what="probe", cwd=tmp_path, timeout_s=60, frames=1, progress=False)


def test_a_small_program_started_from_a_large_bench_reports_its_own_peak(large_bench, tmp_path):
    """Before the launcher: about BENCH_MB for a program that holds 80 MB."""
    small = _run(tmp_path, "import sys; b = bytearray(80 << 20); b[::4096] = b'x' * len(b[::4096])")
    assert small.peak_memory_mb is not None
    assert 80 <= small.peak_memory_mb < 0.5 * BENCH_MB, small.peak_memory_mb


def test_what_a_program_waits_for_counts_in_its_peak(large_bench, tmp_path):
    """A wrapper whose child holds 200 MB peaks at 200 MB or more, as wait4 counts the
    processes a program waited for (a shell script starting the real tracker)."""
    child = "b = bytearray(200 << 20); b[::4096] = b'x' * len(b[::4096])"
    wrapper = f"import subprocess, sys; subprocess.run([sys.executable, '-c', {child!r}], check=True)"
    result = _run(tmp_path, wrapper)
    assert 200 <= result.peak_memory_mb < BENCH_MB, result.peak_memory_mb


@pytest.mark.parametrize(
    ("code", "message"),
    [
        ("exit 3", "probe: exited with code 3"),
        ("kill -TERM $$", "probe: was killed by signal 15"),
        ("kill -PIPE $$", "probe: was killed by signal 13"),
    ],
)
def test_a_program_ends_through_the_launcher_as_it_ended(tmp_path, code, message):
    """Its code, or the signal that killed it; SIGPIPE is at its default in the program (the
    launcher, a Python process, ignores it, and an ignored signal stays ignored across exec)."""
    with pytest.raises(TrackerError, match=message):
        _run(tmp_path, code, ("sh", "-c"))


def test_a_program_that_cannot_start_is_named_with_the_systems_reason(tmp_path):
    """Refused by the launcher (no such program, not executable) or before it (no such
    folder), each in the same line, and no file descriptor left open."""
    open_before = len(os.listdir("/proc/self/fd"))
    for argv, cwd, reason in (
        (["./no-such-tracker"], tmp_path, "No such file or directory"),
        ([str(tmp_path)], tmp_path, "Permission denied"),
        (["/bin/true"], tmp_path / "gone", "No such file or directory"),
    ):
        with pytest.raises(TrackerError, match=f"probe: cannot start '{argv[0]}': {reason}"):
            run_child(argv, what="probe", cwd=cwd, timeout_s=60, frames=1, progress=False)
    assert len(os.listdir("/proc/self/fd")) == open_before


def test_a_program_past_its_time_limit_is_stopped_and_leaves_no_peak(tmp_path):
    with pytest.raises(TrackerError, match="stopped after the time limit of 1 s"):
        run_child(
            [sys.executable, "-c", "import time; time.sleep(60)"],
            what="probe",
            cwd=tmp_path,
            timeout_s=1,
            frames=1,
            progress=False,
        )
