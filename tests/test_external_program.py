"""The external tracker (``run --slam cmd``) against a hostile user, folder or program.

Placeholders reach the program as whole arguments, never through a shell (S3) and
never with a format spec (C5); its stderr is read in bounded pieces (C13); it dies
with depotbench, SIGKILL included, and so do its children and its scratch folder
(C14); a relative program is found where depotbench was started (M7); a full
scratch disk is one line (C6). The findings are those of the reliability probe.
"""

from __future__ import annotations

import errno
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import REPO
from tests.sequences import write_sequence
from tests.test_output import cli, one_error_line

COPY_TRUTH = 'sh -c \'cp "$1/groundtruth.txt" "$2"\' sh {sequence} {trajectory}'
"""A tracker that answers with the ground truth: the values go to the shell as arguments."""


@pytest.fixture
def seq(tmp_path: Path) -> Path:
    write_sequence(tmp_path / "seq", n=4, with_flow=False)
    return tmp_path / "seq"


def scratch_folders(tmp: Path) -> list[str]:
    return sorted(p.name for p in tmp.iterdir() if p.name.startswith("depotbench-cmd-"))


@pytest.fixture
def tmpdir_env(tmp_path: Path, monkeypatch) -> Path:
    """TMPDIR for this test only, so that scratch folders left behind can be seen."""
    import tempfile

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr(tempfile, "tempdir", None)  # gettempdir() caches the first answer
    return tmp


def run_cmd(capsys, seq: Path, out: Path, command: str, *extra: str) -> tuple[int, str, str]:
    return cli(capsys, "run", seq, "-o", out, "--slam", "cmd", "--command", command, *extra)


# -- C13: stderr is read in bounded pieces ------------------------------------------------------

MEASURE = """
import resource, subprocess, sys
cap = int(sys.argv[1])
def limit():
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
proc = subprocess.run(sys.argv[2:], preexec_fn=limit, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
sys.stderr.buffer.write(proc.stderr[-100000:])
print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
sys.exit(proc.returncode if proc.returncode >= 0 else 128 - proc.returncode)
"""
"""As in tests/test_fuzz.py: a small fresh process forks the capped command and measures
its peak RSS (KiB), so that pytest's own size is not counted."""
MEMORY_CAP_BYTES = 2 << 30
MAX_RSS_MB = 300
"""The project's bound for any input (tests/test_fuzz.py)."""


def test_a_flood_of_stderr_without_newlines_stays_bounded_and_ends_at_once(seq: Path, tmp_path: Path):
    flood = "import os, sys\nchunk = b'x' * (1 << 20)\nfor _ in range(200): os.write(2, chunk)\nsys.exit(3)"
    command = f"{shlex.quote(sys.executable)} -c {shlex.quote(flood)}"
    args = ["run", str(seq), "-o", str(tmp_path / "r"), "--slam", "cmd", "--timeout", "120", "--command"]
    started = time.perf_counter()
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            MEASURE,
            str(MEMORY_CAP_BYTES),
            sys.executable,
            "-m",
            "eval.cli",
            *args,
            command,
        ],
        cwd=REPO,
        capture_output=True,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
    )
    elapsed_s = time.perf_counter() - started
    err = proc.stderr.decode("utf-8", "replace")
    peak_mb = int(proc.stdout.decode().split()[-1]) / 1024
    assert proc.returncode == 2, err[-2000:]
    line = one_error_line(err, "exited with code 3 (xxxx")
    assert len(line) < 1000  # the program's last line, cut short
    assert peak_mb < MAX_RSS_MB, f"{peak_mb:.0f} MB"
    assert elapsed_s < 60, elapsed_s  # not the time limit of 120 s


def test_the_error_shows_the_last_line_of_the_programs_stderr_cut_to_a_bound():
    from eval.trackers.external import StderrTail

    tail = StderrTail(lines=3, line_chars=10)
    for piece in (b"12\nfirst li", b"ne\n\xff\xfe broken\n", b"a" * 100, b"\r\nlast\n34\n"):
        tail.feed(piece)
    tail.end()
    assert tail.done_frames == 34
    assert list(tail.lines) == ["\ufffd\ufffd broken", "aaaaaaaaaa\u2026", "last"]


# -- C14: the scratch folder and the program's group end with depotbench --------------------------


def gone_within(seconds: float, check) -> bool:
    deadline = time.time() + seconds
    while not check() and time.time() < deadline:
        time.sleep(0.05)
    return check()


def test_a_killed_caller_leaves_no_scratch_before_the_program_starts(tmp_path: Path):
    """The watcher guards the scratch folder from its creation (the masked copy takes time)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    caller = (
        "import sys, time\n"
        "from eval.trackers.reaper import Scratch\n"
        "scratch = Scratch('depotbench-cmd-')\n"
        "(scratch.path / 'half-written.png').write_bytes(b'x')\n"
        "print(scratch.path, flush=True)\n"
        "time.sleep(600)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", caller],
        cwd=REPO,
        env={**os.environ, "TMPDIR": str(tmp)},
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    folder = Path(proc.stdout.readline().strip())
    assert folder.parent == tmp and folder.is_dir()
    proc.kill()
    proc.wait()
    assert gone_within(5, lambda: not folder.exists())


# -- C6: a full scratch disk under --strategy mask -------------------------------------------


def test_a_full_scratch_disk_is_one_line_and_leaves_nothing(
    seq: Path, tmp_path: Path, tmpdir_env: Path, monkeypatch, capsys
):
    """What ``write()`` raises on a full disk (ENOSPC, no file name), in the masked copy's writes."""
    real = Path.write_bytes

    def full(self: Path, data) -> int:
        if tmpdir_env in self.parents:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", full)
    code, _, err = run_cmd(capsys, seq, tmp_path / "r", COPY_TRUTH, "--strategy", "mask")
    assert code == 2
    one_error_line(err, str(tmpdir_env / "depotbench-cmd-"), "No space left on device")
    assert scratch_folders(tmpdir_env) == [] and not (tmp_path / "r").exists()


def _can_mount_a_tmpfs() -> bool:
    probe = subprocess.run(
        ["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=32k tmpfs /mnt"], capture_output=True
    )
    return probe.returncode == 0


@pytest.mark.skipif(
    sys.platform != "linux" or not _can_mount_a_tmpfs(), reason="needs unprivileged user namespaces"
)
def test_a_really_full_tmpfs_as_tmpdir_is_one_line(seq: Path, tmp_path: Path):
    """The probe's own case: TMPDIR on a 32 KB tmpfs, mounted in a user namespace."""
    small = tmp_path / "small"
    small.mkdir()
    depotbench = [sys.executable, "-m", "eval.cli", "run", str(seq), "-o", str(tmp_path / "r")]
    depotbench += ["--slam", "cmd", "--strategy", "mask", "--command", COPY_TRUTH]
    script = (
        f"mount -t tmpfs -o size=32k tmpfs {shlex.quote(str(small))} && "
        f"TMPDIR={shlex.quote(str(small))} {shlex.join(depotbench)}; code=$?; "
        f'ls -A {shlex.quote(str(small))}; exit "$code"'
    )
    proc = subprocess.run(
        ["unshare", "-rm", "sh", "-c", script], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2, proc.stderr
    one_error_line(proc.stderr, f"{small}/depotbench-cmd-", "No space left on device")
    assert proc.stdout == ""  # the tmpfs was left empty
    assert not (tmp_path / "r").exists()
