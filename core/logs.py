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
