"""What the trackers that run as other programs share: settings files and child processes
with a time limit and a progress bar (their output files are read by ``protocol``)."""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from depotbench.core.logs import DETAIL
from depotbench.core.progress import progress_bar
from depotbench.eval.trackers.base import TrackerError
from depotbench.eval.trackers.watcher import kill_group
from depotbench.sim.camera import OrbSlamSettings, orbslam_yaml
from depotbench.sim.sequence import Sequence

LOG = logging.getLogger(__name__)

STDERR_TAIL_LINES = 20
STDERR_LINE_CHARS = 500
"""A line of the program's stderr is kept to this many characters (the error shows the last)."""
READ_BYTES = 1 << 16
"""Stderr is read in pieces of 64 KiB: a program that writes without newlines once grew
one string to 2.4 GB."""
POLL_S = 0.1
READER_JOIN_S = 1.0
"""Once the program has exited and its group is killed, its pipes close within
milliseconds; one still open after this is held by a process that left the group
(``setsid``), which stalled each run 10 s without a word."""


def write_settings(sequence: Sequence, path: Path) -> Path:
    """ORB-SLAM2/3 RGB-D settings for the sequence's camera (also for TUM folders without one)."""
    path.write_text(orbslam_yaml(sequence.intrinsics, OrbSlamSettings(fps=sequence.fps)), encoding="utf-8")
    return path


@dataclass(frozen=True)
class ChildResult:
    """How a program ran: its wall time, peak memory, CPU time and the end of what it printed."""

    wall_s: float
    peak_memory_mb: float | None
    log: str
    cpu_s: float | None = None
    """User plus system CPU time of the program and of the processes it waited for (what
    ``wait4`` reports), None where the system has no ``wait4``."""


def run_child(
    argv: list[str],
    *,
    what: str,
    cwd: Path,
    timeout_s: float,
    frames: int,
    progress: bool,
    env: dict[str, str] | None = None,
    group: int | None = None,
    program: str | None = None,
) -> ChildResult:
    """Run a program without a shell.

    Lines of plain integers on its stderr advance a progress bar (frames done); the
    last other lines are kept for the error message, and the last ``LOG_BYTES`` of its
    stdout and of its stderr for the run folder. It runs in process group ``group``
    (``depotbench.eval.trackers.reaper``), or in a new one: past ``timeout_s``, on any exception
    and once it has exited, that group is killed, with whatever the program left in it.
    ``program`` names it in a "cannot start" error (default: ``argv[0]``). A failure
    raises ``TrackerError`` carrying the log.
    """
    started = time.perf_counter()
    LOG.log(DETAIL, "%s: running %s in %s (timeout %g s)", what, shlex.join(argv), cwd, timeout_s)
    shown = program or repr(argv[0])
    report, reports = os.pipe() if MEASURED else (-1, -1)
    try:
        child = subprocess.Popen(
            [sys.executable, "-I", "-S", "-c", LAUNCHER, str(reports), *argv] if MEASURED else argv,
            cwd=cwd,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            pass_fds=(reports,) if MEASURED else (),
            **({"start_new_session": True} if group is None else {"process_group": group}),
        )
    except OSError as exc:
        if MEASURED:
            os.close(report)
        raise TrackerError(f"{what}: cannot start {shown}: {exc.strerror or exc}") from None
    finally:
        if MEASURED:
            os.close(reports)
    launcher = _Launcher(report) if MEASURED else None
    if launcher is not None and launcher.exec_error is not None:
        _kill(child, child.pid if group is None else group)
        for stream in (launcher, child.stdout, child.stderr):
            if stream is not None:
                stream.close()
        raise TrackerError(f"{what}: cannot start {shown}: {os.strerror(launcher.exec_error)}")
    group = child.pid if group is None else group
    assert child.stderr is not None and child.stdout is not None
    tail, out = StderrTail(), ByteTail()
    readers = [
        threading.Thread(target=tail.pump, args=(child.stderr.fileno(),), daemon=True),
        threading.Thread(target=out.pump, args=(child.stdout.fileno(),), daemon=True),
    ]
    for reader in readers:
        reader.start()

    notes: list[str] = []  # the bench's own lines about the run, kept with its output

    def log() -> str:
        return _log(out.text(), tail.raw.text()) + "".join(f"== depotbench ==\n{n}\n" for n in notes)

    try:
        _watch(child, tail, what=what, started=started, timeout_s=timeout_s, frames=frames, progress=progress)
    except TrackerError as exc:
        _kill(child, group)
        raise TrackerError(str(exc), log()) from None
    except BaseException:
        _kill(child, group)
        raise
    finally:
        peak = None if launcher is None else launcher.peak_mb_and_close()
    # It has exited: this ends what it left running, which may hold a pipe open.
    peak_mb, cpu_s = _kill(child, group)
    if launcher is not None:
        peak_mb = peak
    streams = (child.stderr, child.stdout)
    escaped = _outlived(readers, streams, what)
    for reader, stream in zip(readers, streams, strict=True):
        if not reader.is_alive():
            stream.close()
    if escaped:
        notes.append(escaped)
    if child.returncode != 0:
        how = (
            f"was killed by signal {-child.returncode}"
            if child.returncode < 0
            else f"exited with code {child.returncode}"
        )
        raise TrackerError(f"{what}: {how} ({tail.last() or 'no message'})", log())
    took = time.perf_counter() - started
    peak = "unknown" if peak_mb is None else f"{peak_mb:.0f} MB"
    LOG.log(DETAIL, "%s: exited 0 after %.2f s (peak memory %s)", what, took, peak)
    return ChildResult(took, peak_mb, log(), cpu_s)


def _outlived(readers: list[threading.Thread], streams: tuple, what: str) -> str | None:
    """Wait up to ``READER_JOIN_S`` for the program's pipes to close. Where a process it
    started left its group and holds one, end that process (found in /proc, where there
    is one) and say so in one warning line, which is returned."""
    deadline = time.monotonic() + READER_JOIN_S
    for reader in readers:
        reader.join(timeout=max(0.0, deadline - time.monotonic()))
    open_pipes = [s.fileno() for r, s in zip(readers, streams, strict=True) if r.is_alive()]
    if not open_pipes:
        return None
    holders = sorted({pid for fd in open_pipes for pid in _pipe_holders(fd)})
    for pid in holders:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGKILL)
    for reader in readers:
        reader.join(timeout=READER_JOIN_S)
    shown = ", ".join(map(str, holders))
    warning = (
        f"{what}: process {shown}, started by the program outside its process group (setsid?), "
        "outlived it holding its output open, and was killed"
        if holders
        else f"{what}: a process started by the program outside its process group (setsid?) "
        "outlived it holding its output open; it is left running"
    )
    LOG.warning(warning)
    return warning


def _pipe_holders(fd: int) -> list[int]:
    """The other processes that hold the pipe ``fd`` reads, from /proc (none where there is
    no /proc): only the program's descendants inherited it."""
    try:
        target = f"pipe:[{os.fstat(fd).st_ino}]"
        pids = [int(name) for name in os.listdir("/proc") if name.isdigit()]
    except OSError:
        return []
    holders = []
    for pid in pids:
        if pid == os.getpid():
            continue
        try:
            links = [os.readlink(f"/proc/{pid}/fd/{n}") for n in os.listdir(f"/proc/{pid}/fd")]
        except OSError:  # gone, or not ours to look at
            continue
        if target in links:
            holders.append(pid)
    return holders


def _log(stdout: str, stderr: str) -> str:
    return f"== standard output (its end) ==\n{stdout}\n== standard error (its end) ==\n{stderr}\n"


def _watch(
    child: subprocess.Popen,
    tail: StderrTail,
    *,
    what: str,
    started: float,
    timeout_s: float,
    frames: int,
    progress: bool,
) -> None:
    """Until the program exits (left unreaped, so its group's number stays its own)."""
    bar = progress_bar(total=frames, desc=what, unit="frame", disable=not progress, leave=False)
    with bar:
        while True:
            finished = _exited(child, POLL_S)
            bar.update(min(tail.done_frames, frames) - bar.n)
            if tail.failure is not None:
                raise TrackerError(f"{what}: cannot read its stderr: {tail.failure}")
            if finished:
                return
            if time.perf_counter() - started > timeout_s:
                raise TrackerError(f"{what}: stopped after the time limit of {timeout_s:g} s")


def _exited(child: subprocess.Popen, seconds: float) -> bool:
    """Whether the program has exited, waiting up to ``seconds``; it is not reaped."""
    deadline = time.monotonic() + seconds
    while True:
        if hasattr(os, "waitid"):
            if os.waitid(os.P_PID, child.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None:
                return True
        elif child.poll() is not None:
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)


MEASURED = hasattr(os, "posix_spawnp") and hasattr(os, "wait4") and sys.platform == "linux"
"""Programs start through ``LAUNCHER``, so that their peak memory is their own (Linux)."""

LAUNCHER = """
import os, signal, sys
report = int(sys.argv[1])
os.set_inheritable(report, False)
try:  # SIGPIPE and SIGXFSZ back to their defaults, as subprocess does (Python ignores them)
    pid = os.posix_spawnp(sys.argv[2], sys.argv[2:], os.environ, setsigdef=(signal.SIGPIPE, signal.SIGXFSZ))
except OSError as exc:
    os.write(report, b"E %d\\n" % exc.errno)
    os._exit(127)
os.write(report, b"S\\n")
_, status, usage = os.wait4(pid, 0)
os.write(report, b"R %d\\n" % usage.ru_maxrss)
code = os.waitstatus_to_exitcode(status)
if code < 0:  # end by the same signal (Python ignores SIGPIPE and catches SIGINT)
    signal.signal(-code, signal.SIG_DFL)
    os.kill(os.getpid(), -code)
os._exit(code)
"""
"""A program's peak resident memory as wait4 reports it starts at its parent's peak when the
parent forks and execs it (Linux folds the old address space's high-water mark into the new
one's): started straight from a sweep worker of 600 MB, ``/bin/true`` peaked at 600 MB. This
small fresh interpreter (about 10 MB) starts the program instead and reports on a pipe that
the program started ("S") or could not ("E errno"), then its peak with whatever it waited
for, in KiB ("R maxrss"); it ends as the program did, by its code or its signal. A program
killed with its group (a time limit) leaves no peak."""


class _Launcher:
    """The bench's end of ``LAUNCHER``'s report pipe."""

    def __init__(self, fd: int) -> None:
        self._file = os.fdopen(fd, "rb")
        first = self._file.readline().split()
        self.exec_error = int(first[1]) if first[:1] == [b"E"] and len(first) == 2 else None

    def peak_mb_and_close(self) -> float | None:
        """The program's peak resident memory (MB), once it has exited (``LAUNCHER`` writes it
        before it ends, so this never waits on a running program); None if it was killed
        with its group first."""
        with self._file:
            line = self._file.readline().split()
        return int(line[1]) / 1024.0 if line[:1] == [b"R"] and len(line) == 2 else None

    def close(self) -> None:
        self._file.close()


def _kill(child: subprocess.Popen, group: int) -> tuple[float | None, float | None]:
    """End the group and reap the program; its peak resident memory in MB and its user plus
    system CPU seconds (each with what it waited for), from ``wait4``, where the system has it
    (with ``LAUNCHER``, the peak is its report's: this one starts at the bench's size)."""
    kill_group(group)
    if not hasattr(os, "wait4"):
        child.wait()
        return None, None
    try:
        _, status, usage = os.wait4(child.pid, 0)
    except ChildProcessError:  # reaped already
        child.wait()
        return None, None
    child.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_maxrss / 1024.0, usage.ru_utime + usage.ru_stime  # maxrss: KiB on Linux


LOG_BYTES = 1 << 20
"""The end of a program's standard output, and of its standard error, kept for the run
folder: 1 MiB each, whatever it prints (a program once printed 1 GB)."""


class ByteTail:
    """The last ``limit`` bytes of a stream, in bounded memory."""

    def __init__(self, limit: int = LOG_BYTES) -> None:
        self.limit = limit
        self._buffer = bytearray()
        self.cut = False

    def feed(self, chunk: bytes) -> None:
        self._buffer += chunk
        if len(self._buffer) > 2 * self.limit:
            del self._buffer[: len(self._buffer) - self.limit]
            self.cut = True

    def pump(self, fd: int) -> None:
        """Read ``fd`` to its end (in a thread: the program never blocks on a full pipe)."""
        try:
            while chunk := os.read(fd, READ_BYTES):
                self.feed(chunk)
        except OSError:
            pass  # the pipe broke: what was read is kept, the exit code tells the rest

    def text(self) -> str:
        data = bytes(self._buffer[-self.limit :])
        cut = self.cut or len(self._buffer) > self.limit
        return ("[\u2026]" if cut else "") + data.decode("utf-8", "replace")


class StderrTail:
    """What a program's stderr tells, in bounded memory and time: the last integer line
    (frames done) and the last ``lines`` other lines, each cut to ``line_chars`` characters.

    ``pump`` reads a file descriptor to its end in 64 KiB pieces. Of each piece only the
    last ``SCAN_LINES`` lines are looked at, from the end, so that a flood of short lines
    costs no Python step per line (splitting every line of a piece took 8 ms a piece: a
    program that printed 200 MB of them waited 18 s on its pipe).
    """

    SCAN_LINES = 1000

    def __init__(self, lines: int = STDERR_TAIL_LINES, line_chars: int = STDERR_LINE_CHARS) -> None:
        self.raw = ByteTail()
        self.lines: collections.deque[str] = collections.deque(maxlen=lines)
        self.line_chars = line_chars
        self.done_frames = 0
        self.failure: OSError | None = None
        self._partial = b""
        self._partial_cut = False
        self._keep_bytes = 4 * line_chars + 4  # UTF-8 takes up to 4 bytes a character

    def pump(self, fd: int) -> None:
        """Read ``fd`` to its end (in a thread: the program never blocks on a full pipe)."""
        try:
            while chunk := os.read(fd, READ_BYTES):
                self.feed(chunk)
        except OSError as exc:
            self.failure = exc  # the watching loop reports it and ends the program
            return
        self.end()

    def feed(self, chunk: bytes) -> None:
        self.raw.feed(chunk)
        data = (self._partial + chunk).replace(b"\r", b"\n")  # \r ends a line too: progress bars
        cut = data.rfind(b"\n")
        if cut >= 0:
            self._complete(data[:cut])
            data = data[cut + 1 :]
        if len(data) > self._keep_bytes:
            data, self._partial_cut = data[: self._keep_bytes], True
        self._partial = data

    def end(self) -> None:
        """The last line may have had no newline."""
        if self._partial.strip():
            self._complete(self._partial)
        self._partial, self._partial_cut = b"", False

    def last(self) -> str | None:
        return self.lines[-1] if self.lines else None

    def _complete(self, block: bytes) -> None:
        """The lines this piece ended, the first of which began in earlier pieces."""
        first_cut, self._partial_cut = self._partial_cut, False
        pieces = block.rsplit(b"\n", self.SCAN_LINES)
        whole = len(pieces) <= self.SCAN_LINES  # pieces[0] is a line, not the rest of the block
        texts: list[tuple[bytes, bool]] = []
        counted = False
        for i in range(len(pieces) - 1, -1 if whole else 0, -1):
            line = pieces[i].strip()
            if line.isdigit() and len(line) <= 12:
                if not counted:
                    self.done_frames, counted = int(line), True
            elif line and len(texts) < (self.lines.maxlen or 0):
                texts.append((line, first_cut and whole and i == 0))
            elif counted and line:
                break  # the count and enough lines: the rest would be pushed out anyway
        for line, cut in reversed(texts):
            self._add(line, cut)

    def _add(self, line: bytes, cut: bool) -> None:
        text = line.decode("utf-8", "replace").strip()
        if cut or len(text) > self.line_chars:
            text = text[: self.line_chars] + "\u2026"
        self.lines.append(text)
