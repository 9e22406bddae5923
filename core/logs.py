"""The ``depotbench`` logger's levels, as the command line's ``-v`` and ``-vv`` show them.

Kept free of imports beyond ``logging``: the command line's conventions import it to build
every parser, and ``depotbench --help`` must stay a fraction of a second.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator

DETAIL = 15
"""A step's details that ``-v`` shows (workers started, a stage's time, a program's command
line, a kernel loaded): between DEBUG (``-vv``: every cache lookup with its key) and INFO
(status lines, which the command line shows by default). A library user who sets the
``depotbench`` logger to DEBUG sees both."""
logging.addLevelName(DETAIL, "DETAIL")


@contextlib.contextmanager
def timed(logger: logging.Logger, what: str) -> Iterator[None]:
    """Log at ``DETAIL`` how long the block took (``-v``: where a run's time went). Nothing
    is said for a block that raised: its error says enough."""
    started = time.perf_counter()
    yield
    logger.log(DETAIL, "%s took %.2f s", what, time.perf_counter() - started)


class _WorkerLines(logging.Handler):
    """A spawned worker's records on its stderr, which it shares with the command: ``-v`` and
    ``-vv`` lines named by the worker's process id (``depotbench worker 4711: debug: [cache]
    ...``), warnings and errors as Python's last-resort handler printed them before this one
    took its place; status lines (INFO) are the command's own to say, so a worker's are
    dropped."""

    def emit(self, record: logging.LogRecord) -> None:
        import os
        import sys

        if logging.INFO <= record.levelno < logging.WARNING:
            return
        message = record.getMessage()
        if record.levelno < logging.INFO:
            kind = "detail" if record.levelno >= DETAIL else "debug"
            where = record.name.removeprefix("depotbench.")
            message = f"depotbench worker {os.getpid()}: {kind}: [{where}] {message}"
        if sys.stderr is not None:
            print(message, file=sys.stderr, flush=True)


def follow_in_worker(level: int) -> None:
    """Give a spawned worker the command's ``-v``/``-vv`` (``level``: the ``depotbench``
    logger's level in the parent). Without it a worker's logger stays at Python's default,
    WARNING, and a sweep's cache lookups, which happen in its workers, said nothing at
    ``-vv``."""
    if level >= logging.INFO:
        return
    logger = logging.getLogger("depotbench")
    logger.setLevel(level)
    logger.addHandler(_WorkerLines())
