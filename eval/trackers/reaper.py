"""A scratch folder and a process group that end with depotbench, SIGKILL included.

An external program runs in a process group of its own (so that one signal ends it
with all its children), which makes it nobody's to end when depotbench is killed:
SIGKILL gives depotbench no chance to clean up, the program went on for up to the
time limit (an hour by default), and its scratch folder (under ``--strategy mask``
a full copy of the sequence) stayed in ``$TMPDIR``. PR_SET_PDEATHSIG would reach
only the direct child, and fires when the thread that forked it ends, not the process.

So ``Scratch`` starts a watcher (``eval/trackers/watcher.py``, ~40 ms) that makes the
folder and anchors the group, and holds the read end of a pipe whose write end only
depotbench holds. Whenever depotbench ends, the kernel closes that end: the watcher
reads end of file, kills the group and removes the folder. On a normal end depotbench
does both itself and tells the watcher to exit quietly.

A program that leaves its process group (``setsid``, a daemon) is beyond its reach.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from depotbench.eval.trackers import watcher

WATCHER = Path(watcher.__file__)


class Scratch:
    """``with Scratch(prefix) as scratch``: ``scratch.path``, a new folder in the temporary
    directory, and ``scratch.group``, the process group to start the program in.

    Made at once (the watcher guards the folder from then on); raises OSError, naming the
    temporary directory, when the folder cannot be made.
    """

    def __init__(self, prefix: str) -> None:
        self.parent = tempfile.gettempdir()
        read_end, self._control = os.pipe()  # not inheritable: the program never holds it
        try:
            self._watcher = subprocess.Popen(
                [sys.executable, "-I", "-S", str(WATCHER), prefix, self.parent],
                stdin=read_end,
                stdout=subprocess.PIPE,
                process_group=0,  # not in depotbench's group: a signal to that group spares it
            )
        except BaseException:
            os.close(self._control)
            raise
        finally:
            os.close(read_end)
        try:
            reply = self._reply()
        except BaseException:  # Ctrl-C, say: closing our end makes the watcher clean up
            os.close(self._control)
            raise
        if "errno" in reply:
            self._quit()
            raise OSError(reply["errno"] or None, reply["error"], self.parent)
        self.path, self.group = Path(reply["path"]), int(reply["group"])

    def _reply(self) -> dict:
        assert self._watcher.stdout is not None
        with self._watcher.stdout as answer:
            line = answer.readline()
        return json.loads(line) if line else {"errno": 0, "error": "the scratch watcher died"}

    def __enter__(self) -> Scratch:
        return self

    def __exit__(self, *exc: object) -> None:
        watcher.kill_group(self.group)  # what the program left running
        try:
            if os.path.lexists(self.path):  # else the program removed it: its run says so
                shutil.rmtree(self.path)
        except OSError:
            self._quit()  # it could do no better: the error (naming the file) is ours to show
            raise
        except BaseException:  # Ctrl-C in the middle: the watcher, told nothing, removes the rest
            os.close(self._control)
            raise
        self._quit()

    def _quit(self) -> None:
        """The watcher exits without touching anything (it did its work if we died first)."""
        assert self._watcher is not None
        try:
            os.write(self._control, watcher.QUIT)
        except BrokenPipeError:
            pass  # it has exited already: its exit code says how, below
        finally:
            os.close(self._control)
        code = self._watcher.wait()
        if code not in (0, 1):
            raise RuntimeError(f"the scratch watcher {WATCHER} ended with code {code}")
