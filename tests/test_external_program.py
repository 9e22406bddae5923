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
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from depotbench.core.errors import InputError
from depotbench.eval.trackers.command import parse_template

from tests.capped import MAX_RSS_MB, peak_rss_mb
from tests.conftest import REPO
from tests.sequences import write_sequence
from tests.test_output import cli, one_error_line, wait_until_gone

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


# -- S3: no shell ever parses a placeholder's value ---------------------------------------------


def test_a_hostile_folder_name_never_runs_in_a_shell_template(tmp_path: Path, capsys):
    hostile = tmp_path / "seq;echo PWNED_$(id -un)>&2;false;"
    write_sequence(hostile, n=4, with_flow=False)
    code, _, err = run_cmd(capsys, hostile, tmp_path / "r1", "sh -c 'test -d {sequence}'")
    assert code == 2 and "PWNED" not in err
    one_error_line(err, "'test -d {sequence}'", "whole word", "sh {sequence}", '"$DEPOTBENCH_SEQUENCE"')
    code, _, err = run_cmd(capsys, hostile, tmp_path / "r2", "sh -c {sequence}")
    assert code == 2 and "PWNED" not in err
    one_error_line(err, "{sequence}", "shell")
    assert not (tmp_path / "r1").exists() and not (tmp_path / "r2").exists()


def test_a_shell_template_gets_the_values_as_arguments_and_in_the_environment(tmp_path: Path, capsys):
    hostile = tmp_path / "seq;echo PWNED>&2;false;"
    write_sequence(hostile, n=4, with_flow=False)
    code, out, err = run_cmd(capsys, hostile, tmp_path / "r1", COPY_TRUTH)
    assert code == 0, err
    assert "tracked 4/4" in out
    from_env = 'sh -c \'cp "$DEPOTBENCH_SEQUENCE/groundtruth.txt" "$DEPOTBENCH_TRAJECTORY"\''
    code, out, err = run_cmd(capsys, hostile, tmp_path / "r2", from_env)
    assert code == 0, err
    assert "tracked 4/4" in out


@pytest.mark.parametrize(
    "template", ["cp {sequence}/groundtruth.txt {trajectory}", "slam --settings={settings} {sequence}"]
)
def test_a_placeholder_must_be_a_whole_word(template: str):
    with pytest.raises(InputError, match="a placeholder must be a whole word"):
        parse_template(template)


@pytest.mark.parametrize(
    "template", ["bash -ec {sequence}", "env /bin/sh -c {settings}", "sh -xc {trajectory} x"]
)
def test_a_placeholder_is_never_a_shells_script(template: str):
    with pytest.raises(InputError, match="a shell would run its value as commands"):
        parse_template(template)


@pytest.mark.parametrize("template", ["slam -c {settings}", "sh -c 'exec slam \"$1\"' sh {sequence}"])
def test_a_placeholder_after_c_is_fine_when_no_shell_reads_it_as_a_script(template: str):
    assert parse_template(template)


def test_literal_braces_and_whole_word_placeholders_are_accepted():
    words = parse_template("slam '{{not a placeholder}}' {sequence} -- {trajectory}")
    assert words[1] == "{{not a placeholder}}" and words[2] == "{sequence}"


# -- C5: no format spec, no conversion ------------------------------------------------------------


@pytest.mark.parametrize(
    "word",
    [
        "{sequence:d}",
        "{sequence:>99999999999999999999}",
        "{sequence:>1000000000}",  # once built a 1 GB argument (3 GB resident)
        "{sequence!r}",
        "{sequence!s:>5}",
    ],
)
def test_a_format_spec_or_conversion_is_refused_before_anything_is_built(word: str):
    with pytest.raises(InputError, match="format spec") as refused:
        parse_template(f"true {word}")
    assert str(refused.value).count("\n") == 0 and repr(word) in str(refused.value)


def test_a_format_spec_is_one_line_from_the_command_line(seq: Path, tmp_path: Path, capsys):
    for word in ("{sequence:d}", "{sequence:>99999999999999999999}"):
        code, _, err = run_cmd(capsys, seq, tmp_path / "r", f"true {word}")
        assert code == 2
        one_error_line(err, "depotbench run: error: --command", repr(word), "format spec")
        assert not (tmp_path / "r").exists()


# -- C13: stderr is read in bounded pieces ------------------------------------------------------


def test_a_flood_of_stderr_without_newlines_stays_bounded_and_ends_at_once(seq: Path, tmp_path: Path):
    flood = "import os, sys\nchunk = b'x' * (1 << 20)\nfor _ in range(200): os.write(2, chunk)\nsys.exit(3)"
    command = f"{shlex.quote(sys.executable)} -c {shlex.quote(flood)}"
    args = ["run", str(seq), "-o", str(tmp_path / "r"), "--slam", "cmd", "--timeout", "120", "--command"]
    started = time.perf_counter()
    code, err, peak_mb = peak_rss_mb([*args, command])
    elapsed_s = time.perf_counter() - started
    assert code == 2, err[-2000:]
    line = one_error_line(err, "exited with code 3 (xxxx")
    assert len(line) < 1000  # the program's last line, cut short
    assert peak_mb < MAX_RSS_MB, f"{peak_mb:.0f} MB"
    assert elapsed_s < 60, elapsed_s  # not the time limit of 120 s


def test_the_error_shows_the_last_line_of_the_programs_stderr_cut_to_a_bound():
    from depotbench.eval.trackers.external import StderrTail

    tail = StderrTail(lines=3, line_chars=10)
    for piece in (b"12\nfirst li", b"ne\n\xff\xfe broken\n", b"a" * 100, b"\r\nlast\n34\n"):
        tail.feed(piece)
    tail.end()
    assert tail.done_frames == 34
    assert list(tail.lines) == ["\ufffd\ufffd broken", "aaaaaaaaaa\u2026", "last"]


# -- C14: the program, its children and the scratch folder end with depotbench ------------------


SPAWNER = """
import os, subprocess, sys, time
grandchild = subprocess.Popen(["sleep", "600"])
with open(sys.argv[1] + ".part", "w") as f:
    f.write(f"{os.getpid()} {grandchild.pid}")
os.rename(sys.argv[1] + ".part", sys.argv[1])
time.sleep(600)
"""
"""A tracker that starts a child of its own, says their pids, and never finishes."""


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(") ")[-1][:1]
    except FileNotFoundError:
        return False
    return state not in ("Z", "X")


def start_spawner(seq: Path, tmp_path: Path, tmp: Path, token: str) -> tuple[subprocess.Popen, list[int]]:
    (tmp_path / "spawner.py").write_text(SPAWNER)
    pids = tmp_path / "pids"
    command = f"{shlex.quote(sys.executable)} {tmp_path / 'spawner.py'} {pids} {{trajectory}}"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "depotbench.eval.cli.main",
            "run",
            str(seq),
            "-o",
            str(tmp_path / "r"),
            "--slam",
            "cmd",
        ]
        + ["--strategy", "mask", "--command", command],
        cwd=REPO,
        env={**os.environ, "TMPDIR": str(tmp), "DEPOTBENCH_TEST_TOKEN": token, "MUJOCO_GL": "egl"},
        stdout=subprocess.DEVNULL,
        stderr=(tmp_path / "stderr").open("w"),
    )
    deadline = time.time() + 60
    while not pids.exists():
        assert proc.poll() is None and time.time() < deadline, (tmp_path / "stderr").read_text()
        time.sleep(0.05)
    return proc, [int(p) for p in pids.read_text().split()]


def gone_within(seconds: float, check) -> bool:
    deadline = time.time() + seconds
    while not check() and time.time() < deadline:
        time.sleep(0.05)
    return check()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
@pytest.mark.parametrize("how", ["SIGKILL", "SIGTERM"])
def test_the_program_its_children_and_its_scratch_end_with_depotbench(seq: Path, tmp_path: Path, how: str):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    token = f"cmd-{how}-{os.getpid()}-{time.time_ns()}"
    proc, pids = start_spawner(seq, tmp_path, tmp, token)
    assert all(alive(pid) for pid in pids) and len(scratch_folders(tmp)) == 1
    proc.send_signal(getattr(signal, how))
    proc.wait(timeout=30)
    assert proc.returncode == (-signal.SIGKILL if how == "SIGKILL" else 143)
    assert gone_within(5, lambda: not any(alive(pid) for pid in pids)), [p for p in pids if alive(p)]
    assert gone_within(5, lambda: scratch_folders(tmp) == []), scratch_folders(tmp)
    assert wait_until_gone(token, timeout_s=5) == []  # nothing of ours lives on, the watcher included
    assert not (tmp_path / "r").exists()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_what_the_program_leaves_running_is_ended_with_it(
    seq: Path, tmp_path: Path, tmpdir_env: Path, capsys
):
    pids = tmp_path / "pids"
    leave = f'sleep 600 & echo $! > {pids}; cp "$1/groundtruth.txt" "$2"'
    started = time.perf_counter()
    code, _, err = run_cmd(
        capsys, seq, tmp_path / "r", f"sh -c {shlex.quote(leave)} sh {{sequence}} {{trajectory}}"
    )
    assert code == 0, err
    assert time.perf_counter() - started < 5  # the leftover held stderr open: no wait for it
    assert gone_within(5, lambda: not alive(int(pids.read_text())))
    assert scratch_folders(tmpdir_env) == []


def test_a_killed_caller_leaves_no_scratch_before_the_program_starts(tmp_path: Path):
    """The watcher guards the scratch folder from its creation (the masked copy takes time)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    caller = (
        "import sys, time\n"
        "from depotbench.eval.trackers.reaper import Scratch\n"
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


def test_an_interrupted_cleanup_is_finished_by_the_watcher(tmp_path: Path, tmpdir_env: Path, monkeypatch):
    from depotbench.eval.trackers import reaper

    scratch = reaper.Scratch("depotbench-cmd-")
    (scratch.path / "masked").mkdir()

    def interrupted(path) -> None:
        raise KeyboardInterrupt  # Ctrl-C while depotbench removes the folder itself

    monkeypatch.setattr(reaper.shutil, "rmtree", interrupted)
    with pytest.raises(KeyboardInterrupt), scratch:
        pass
    assert scratch._watcher.wait(timeout=5) == 0
    assert scratch_folders(tmpdir_env) == []


# -- M7: a relative program is found where depotbench was started ------------------------------


def test_a_relative_program_is_found_in_the_starting_folder(seq: Path, tmp_path: Path, monkeypatch, capsys):
    script = tmp_path / "my_slam.sh"
    script.write_text('#!/bin/sh\ncp "$1/groundtruth.txt" "$2"\n')
    script.chmod(0o755)
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cmd(capsys, seq, tmp_path / "r", "./my_slam.sh {sequence} {trajectory}")
    assert code == 0, err
    assert "tracked 4/4" in out
    code, _, err = run_cmd(capsys, seq, tmp_path / "r2", "./no_slam.sh {sequence}")
    assert code == 2
    one_error_line(
        err, "the program './no_slam.sh'", f"looked for {tmp_path / 'no_slam.sh'}", "does not exist"
    )


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
    depotbench = [
        sys.executable,
        "-m",
        "depotbench.eval.cli.main",
        "run",
        str(seq),
        "-o",
        str(tmp_path / "r"),
    ]
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
