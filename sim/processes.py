"""Child processes that never outlive their parent.

A worker whose parent was killed (SIGKILL gives the parent no chance to stop it)
would go on writing; ``exit_with_parent`` starts a thread that ends the process
as soon as it is reparented.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Iterator

PARENT_POLL_S = 0.2
"""How often a child checks that its parent is alive."""


def _watch(parent_pid: int) -> None:
    while True:
        time.sleep(PARENT_POLL_S)
        if os.getppid() != parent_pid:
            os._exit(1)  # orphaned: the parent is gone, and with it whoever wanted our output


def exit_with_parent(parent_pid: int) -> None:
    """End this process within ``PARENT_POLL_S`` of its parent's death."""
    threading.Thread(target=_watch, args=(parent_pid,), daemon=True, name="exit-with-parent").start()


@contextlib.contextmanager
def children_ignore_sigint() -> Iterator[None]:
    """Start worker processes with SIGINT ignored from their first instruction.

    Ctrl-C reaches the whole process group, and a spawned worker still starting
    Python (importing ``site``) died of it with a traceback of its own before its
    initializer could ignore the signal. An ignored signal stays ignored across
    exec, and Python installs its KeyboardInterrupt handler only over the default
    one. The parent ignores SIGINT only while it spawns; off the main thread
    (where signals cannot be set) this does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
