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
