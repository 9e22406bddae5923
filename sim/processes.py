"""Child processes that never outlive their parent.

A worker whose parent was killed (SIGKILL gives the parent no chance to stop it)
would go on writing; ``exit_with_parent`` starts a thread that ends the process
as soon as it is reparented.
"""

from __future__ import annotations

import os
import threading
import time

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
