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
def children_block_sigint() -> Iterator[None]:
    """Start worker processes with SIGINT blocked from their first instruction.

    Ctrl-C reaches the whole process group, and a spawned worker still starting
    Python (importing ``site``) died of it with a traceback of its own before its
    initializer could ignore the signal. A child inherits the signal mask of the
    thread that forks it, across exec, so the spawning thread blocks SIGINT while it
    spawns: a Ctrl-C then waits in the starting worker until its initializer ignores
    it (``release_sigint``, which drops it). The parent keeps its own handler: a
    Ctrl-C in the window reaches it through another thread or once the block is
    lifted. (It used to ignore SIGINT in the window instead, and a Ctrl-C that came
    then was lost: the suite ran to the end and exited 0.) Off the main thread
    (where Python cannot handle signals) this does nothing.

    A Ctrl-C taken by another thread (a progress bar's monitor, the pool's own threads)
    still runs Python's handler in this thread at once, which raised KeyboardInterrupt
    between starting a worker and sending it its start-up data; the worker then died
    reading a closed pipe, with a traceback ("Ran out of input"). So the handler is
    deferred too: a SIGINT in the window is recorded and handed to the previous handler
    as the window closes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    taken: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: taken.append(signum))
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        signal.signal(signal.SIGINT, previous)
        if taken:
            _deliver_sigint(previous)


def _deliver_sigint(handler: object) -> None:
    """Hand a deferred SIGINT to ``handler`` as the signal itself would have."""
    if callable(handler):
        handler(signal.SIGINT, None)
    elif handler == signal.SIG_DFL:
        signal.raise_signal(signal.SIGINT)


def release_sigint() -> None:
    """In a worker started under ``children_block_sigint``: ignore SIGINT (dropping one
    already pending), then unblock it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


IMPORT_POLL_S = 0.02
"""How often a signal deferred during an import checks whether the import has ended."""


def _importing(frame: object) -> bool:
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):  # type: ignore[attr-defined]
            return True
        frame = frame.f_back  # type: ignore[attr-defined]
    return False


_HOLDING: list[OutsideImports] = []
"""Handlers holding a signal that came during an import, until it is delivered."""
_HOLDING_LOCK = threading.Lock()


class OutsideImports:
    """A signal handler that raises ``exception`` at once, except inside an import.

    An exception raised while an extension module initialises is turned into "ImportError:
    initialization failed" (MuJoCo's, SciPy's pybind11 modules), or swallowed by a library's
    optional import, so a Ctrl-C then gave a traceback or was lost and the command ran on.
    Inside an import the signal is held and delivered again (``_thread.interrupt_main``) as
    soon as the main thread is out of every import, or earlier, where the program is about
    to write (``deliver_held``).
    """

    def __init__(self, exception: type[BaseException]) -> None:
        self.exception = exception

    def __call__(self, signum: int, frame: object) -> None:
        if frame is not None and _importing(frame):
            with _HOLDING_LOCK:
                if self in _HOLDING:
                    return
                _HOLDING.append(self)
            threading.Thread(target=self._redeliver, args=(signum,), daemon=True).start()
            return
        self._release()
        raise self.exception

    def _release(self) -> bool:
        """Take the held signal for delivery; False where it was delivered already."""
        with _HOLDING_LOCK:
            if self not in _HOLDING:
                return False
            _HOLDING.remove(self)
            return True

    def _redeliver(self, signum: int) -> None:
        import _thread
        import sys

        main = threading.main_thread().ident
        while self in _HOLDING and _importing(sys._current_frames().get(main)):
            time.sleep(IMPORT_POLL_S)
        if self._release():
            _thread.interrupt_main(signum)


def deliver_held() -> None:
    """Raise a signal held during an import now, in the main thread.

    The thread that delivers it polls every ``IMPORT_POLL_S``; on a loaded machine the
    command ran on past its imports in that gap and made its output folder before the
    Ctrl-C arrived (CI, one run in several). Every writer calls this first, so a Ctrl-C
    from the imports ends the command before anything is written.
    """
    if threading.current_thread() is threading.main_thread() and _HOLDING:
        held = _HOLDING[0]
        if held._release():
            raise held.exception
