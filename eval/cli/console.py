"""The ``depotbench`` console script: its first module takes Ctrl-C before anything heavy loads.

Python raises ``KeyboardInterrupt`` from its own handler until a program sets another, and
the command line's modules (argparse, then NumPy, SciPy and OpenCV: ~0.1 s) were imported
before ``main`` set it: a Ctrl-C in that window was a 7-34-line traceback and exit -2
(probe C15). This module imports only ``signal`` and ``depotbench.core.processes`` (10 ms),
sets the handler, and only then loads the command line; an interruption before the command
line can report it is one line and exit 130.
"""

from __future__ import annotations

import signal

_taken: list[int] = []
_ours = signal.getsignal(signal.SIGINT) is signal.default_int_handler  # not ignored (nohup, &)
if _ours:
    # Held, not raised, while this module loads: raised here, it would be a traceback of
    # the console script's import line.
    signal.signal(signal.SIGINT, lambda signum, frame: _taken.append(signum))

import os  # noqa: E402
import sys  # noqa: E402

from depotbench.core.processes import OutsideImports  # noqa: E402

EXIT_INTERRUPTED = 128 + signal.SIGINT


def _interrupted() -> None:
    """Nothing has started that needs cleaning up: say so and leave (``os._exit``: an
    interrupted extension import leaves CPython set to end itself by SIGINT, not 130)."""
    sys.stderr.write("depotbench: interrupted\n")
    sys.stderr.flush()
    os._exit(EXIT_INTERRUPTED)


def entry() -> None:
    """The program: ``main.entry`` behind a Ctrl-C handler set first (``OutsideImports``:
    a Ctrl-C inside an import is held until the import is done, then raised)."""
    if _ours:
        signal.signal(signal.SIGINT, OutsideImports(KeyboardInterrupt))
    if _taken:  # checked after the switch, so that none falls between the two handlers
        _interrupted()
    try:
        from depotbench.eval.cli import main
    except KeyboardInterrupt:
        _interrupted()
    try:
        main.entry()
    except KeyboardInterrupt:  # before main's own handling starts, or after it ends
        _interrupted()
