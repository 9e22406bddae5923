"""The watcher of one scratch folder and process group: a script, standard library only.

``depotbench.eval.trackers.reaper`` starts it (``python -I -S watcher.py PREFIX DIR``, ~40 ms) with
its stdin on the read end of a pipe whose write end only depotbench holds. It:

1. makes the scratch folder (``mkdtemp(prefix=PREFIX, dir=DIR)``), so that no moment
   exists where the folder is there and nobody would remove it;
2. forks the *anchor*, a process that only sleeps, as the leader of a new process
   group in which depotbench then starts the external program: the group is known
   here before the program exists, and its number cannot be reused while the anchor
   is this process's unreaped child;
3. replies one JSON line on stdout: ``{"path": ..., "group": ...}`` (or ``{"errno":
   ..., "error": ...}`` when the folder cannot be made);
4. waits on stdin. ``q`` means depotbench ended the group and removed the folder
   itself: exit quietly. End of file means depotbench died (SIGKILL included, the
   kernel closes its pipes): kill the whole group with SIGKILL (the program and
   every child it left in its group), then remove the folder.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import sys
import tempfile
import time

QUIT = b"q"
REMOVE_TRIES = 20
"""The folder is removed again this many times, 0.05 s apart, while killed processes
that were inside a write still finish it (SIGKILL takes effect as a call returns)."""


def main(argv: list[str]) -> int:
    # Ctrl-C at the terminal or a hang-up is for depotbench to handle; this process
    # must outlive it to clean up (it is in a process group of its own anyway).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    prefix, parent = argv[1], argv[2]
    try:
        path = tempfile.mkdtemp(prefix=prefix, dir=parent)
    except OSError as exc:
        _reply({"errno": exc.errno, "error": exc.strerror or str(exc)})
        return 1
    anchor = _fork_anchor()
    try:
        _reply({"path": path, "group": anchor})
        told = os.read(0, 1)
    except OSError:  # depotbench is gone already (a broken reply pipe): clean up as at EOF
        told = b""
    if told == QUIT:
        _reap(anchor)
        return 0
    _end(anchor, path)
    return 0


def _reply(message: dict) -> None:
    sys.stdout.write(json.dumps(message) + "\n")
    sys.stdout.flush()
    sys.stdout.close()


def _fork_anchor() -> int:
    anchor = os.fork()
    if anchor == 0:
        os.setpgid(0, 0)
        devnull = os.open(os.devnull, os.O_RDWR)
        for fd in (0, 1, 2):  # hold none of depotbench's pipes open
            os.dup2(devnull, fd)
        while True:
            signal.pause()
    os.setpgid(anchor, anchor)  # also here: the group exists before the reply, whoever runs first
    return anchor


def kill_group(group: int) -> None:
    """SIGKILL to a whole process group; one already gone is no error (nor, as macOS says
    for a group of zombies, EPERM)."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(group, signal.SIGKILL)


def _reap(anchor: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.kill(anchor, signal.SIGKILL)
    os.waitpid(anchor, 0)


def _end(anchor: int, path: str) -> None:
    kill_group(anchor)
    _reap(anchor)
    for _ in range(REMOVE_TRIES - 1):
        try:
            shutil.rmtree(path)
            return
        except FileNotFoundError:
            return
        except OSError:
            time.sleep(0.05)
    shutil.rmtree(path)  # the last try lets its error show (on depotbench's stderr)


if __name__ == "__main__":
    sys.exit(main(sys.argv))
