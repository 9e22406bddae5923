"""What the trackers that run as other programs share: settings files, child processes
with a time limit and a progress bar, and reading their trajectories back."""

from __future__ import annotations

import collections
import contextlib
import os
import queue
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eval.trackers.base import TrackerError
from sim.camera import OrbSlamSettings, orbslam_yaml
from sim.sequence import Sequence

STDERR_TAIL_LINES = 20


def write_settings(sequence: Sequence, path: Path) -> Path:
    """ORB-SLAM2/3 RGB-D settings for the sequence's camera (also for TUM folders without one)."""
    path.write_text(orbslam_yaml(sequence.intrinsics, OrbSlamSettings(fps=sequence.fps)), encoding="utf-8")
    return path


def run_child(
    argv: list[str],
    *,
    what: str,
    cwd: Path,
    timeout_s: float,
    frames: int,
    progress: bool,
    env: dict[str, str] | None = None,
) -> float:
    """Run a program without a shell; return its wall time.

    Lines of plain integers on its stderr advance a progress bar (frames done); the
    rest is kept for the error message. Past ``timeout_s`` its process group is killed,
    whether or not it still prints.
    """
    started = time.perf_counter()
    try:
        child = subprocess.Popen(
            argv,
            cwd=cwd,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            errors="replace",
            start_new_session=True,
        )
    except OSError as exc:
        raise TrackerError(f"{what}: cannot start {argv[0]!r}: {exc.strerror or exc}") from None
    lines: queue.SimpleQueue[str] = queue.SimpleQueue()
    reader = threading.Thread(target=_read_lines, args=(child, lines), daemon=True)
    reader.start()
    tail: collections.deque[str] = collections.deque(maxlen=STDERR_TAIL_LINES)
    bar = tqdm(total=frames, desc=what, unit="frame", disable=None if progress else True, leave=False)
    try:
        with bar:
            while True:
                finished = _wait(child, POLL_S)
                while not lines.empty():
                    text = lines.get().strip()
                    if text.isdigit():
                        bar.update(int(text) - bar.n)
                    elif text:
                        tail.append(text)
                if finished:
                    break
                if time.perf_counter() - started > timeout_s:
                    raise TrackerError(f"{what}: stopped after the time limit of {timeout_s:g} s")
    except BaseException:
        _kill(child)
        raise
    reader.join(timeout=5)
    if child.returncode != 0:
        detail = tail[-1] if tail else "no message"
        raise TrackerError(f"{what}: exited with code {child.returncode} ({detail})")
    return time.perf_counter() - started


POLL_S = 0.2


def _read_lines(child: subprocess.Popen, lines: queue.SimpleQueue) -> None:
    assert child.stderr is not None
    for line in child.stderr:
        lines.put(line)


def _wait(child: subprocess.Popen, seconds: float) -> bool:
    try:
        child.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        return False
    return True


def _kill(child: subprocess.Popen) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(child.pid, signal.SIGKILL)
    child.wait()


def poses_by_frame(
    sequence: Sequence, timestamps_s: np.ndarray, poses: np.ndarray, tolerance_s: float = 1e-3
) -> list[np.ndarray | None]:
    """Each frame's pose from a trajectory keyed by timestamp (None where it has none)."""
    by_frame: list[np.ndarray | None] = [None] * len(sequence)
    if len(timestamps_s) == 0:
        return by_frame
    order = np.argsort(timestamps_s)
    stamps = timestamps_s[order]
    for i, frame in enumerate(sequence.frames):
        k = int(np.searchsorted(stamps, frame.timestamp_s))
        for j in (k - 1, k):
            if 0 <= j < len(stamps) and abs(stamps[j] - frame.timestamp_s) <= tolerance_s:
                by_frame[i] = poses[order[j]]
                break
    return by_frame
