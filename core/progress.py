"""Progress of long steps, as a terminal shows it and as a CI log can keep it.

``progress_bar`` is the one factory every loop of the bench uses. It returns a ``tqdm``
(iterate over it, ``update``, ``close``, use it as a context manager):

- **On a terminal** (stderr is a TTY) it is tqdm's bar, redrawn in place.
- **Elsewhere** (CI, a pipe, a file) a bar redrawn with ``\\r`` would be one unreadable
  line, and tqdm's own answer there is to print nothing at all (``disable=None``), so a
  10-minute sweep said nothing between its first and last line. Here it prints a whole
  line instead, ``depotbench: sweep 120/400 run (30%), 2.10run/s, ETA 02:13``, at most
  every ``DEPOTBENCH_PROGRESS_INTERVAL`` seconds (30 by default: 2 lines a minute keep an
  hour-long sweep's log at 120 lines and never leave a reader waiting more than half a
  minute; ``0`` prints every step), and a last line with the time taken when a bar that
  stays (``leave=True``) closes. Work shorter than the interval prints nothing, as on a
  terminal a transient bar leaves nothing.
- **Silent** when the caller asks (``disable=True``, a library's ``progress=False``) or
  when the ``depotbench`` logger's level is above WARNING (the command line's ``-q``).

The lines use tqdm's own counting, rate smoothing and formatting: tqdm's ``display`` is
the documented place to send a bar somewhere else. tqdm has no line mode of its own
(tqdm/tqdm#750 is open), and tqdm-loggable logs through its own logger, at a rate set
once per process and in a format of its own, so it would need the same subclass.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import threading
from collections.abc import Iterable
from typing import Any

from depotbench.core.errors import InputError
from tqdm import tqdm

INTERVAL_VARIABLE = "DEPOTBENCH_PROGRESS_INTERVAL"
DEFAULT_INTERVAL_S = 30.0
PREFIX = "depotbench: "
_LINE = "{desc} {n_fmt}/{total_fmt} {unit} ({percentage:.0f}%), {rate_fmt}, ETA {remaining}"
_LINE_NO_TOTAL = "{desc} {n_fmt} {unit}, {rate_fmt}"
_DONE = "{desc} {n_fmt}/{total_fmt} {unit}, {rate_fmt}"


def interval_s() -> float:
    """``DEPOTBENCH_PROGRESS_INTERVAL``: seconds between two lines off a terminal."""
    raw = os.environ.get(INTERVAL_VARIABLE, "")
    if not raw.strip():
        return DEFAULT_INTERVAL_S
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise InputError(f"{INTERVAL_VARIABLE}={raw!r}: give seconds between progress lines, 0 or more")
    return value


def quiet() -> bool:
    """Whether the ``depotbench`` logger is set above WARNING (``-q``)."""
    return logging.getLogger("depotbench").getEffectiveLevel() > logging.WARNING


class _Nowhere:
    """Where tqdm's own writes (``\\r``, cursor moves, the newline of ``close``) go off a
    terminal: ``_Lines.display`` writes each whole line itself."""

    def write(self, text: str) -> None:
        pass

    def flush(self) -> None:
        pass


class _Lines(tqdm):
    """tqdm that prints each display as one line to the current ``sys.stderr``."""

    def display(self, msg: str | None = None, pos: int | None = None) -> bool:
        if msg == "":  # tqdm clears a transient (leave=False) bar as it closes: nothing to say
            return True
        fields = self.format_dict
        closing = self.disable  # tqdm sets it before the last display of a bar that stays
        fields["bar_format"] = (_DONE if closing else _LINE) if self.total else _LINE_NO_TOTAL
        line = self.format_meter(**fields)
        if closing:  # the rate is the whole run's here: tqdm drops its smoothing to close
            took = tqdm.format_interval(fields["elapsed"])
            stopped = self.total is not None and self.n < self.total
            line += f", stopped after {took}" if stopped else f", took {took}"
        stream = sys.stderr
        if stream is not None:
            stream.write(f"{PREFIX}{line}\n")
            stream.flush()
        return True


def progress_bar(
    iterable: Iterable | None = None,
    *,
    total: float | None = None,
    desc: str = "",
    unit: str = "it",
    disable: bool = False,
    leave: bool = True,
    **options: Any,
) -> tqdm:
    """A progress bar (see the module's docstring); ``options`` go to tqdm (``initial``,
    ``smoothing``)."""
    stream = sys.stderr
    if disable or stream is None or quiet():
        return tqdm(iterable, total=total, desc=desc, unit=unit, disable=True, leave=leave, **options)
    every = interval_s()  # read on a terminal too: a bad value is refused wherever it is set
    if stream.isatty():
        return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, file=stream, **options)
    return _Lines(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        leave=leave,
        file=_Nowhere(),
        mininterval=every,
        maxinterval=math.inf,
        miniters=1,  # tqdm's dynamic miniters would skip lines once a loop slows down
        delay=every,
        **options,
    )


def use_thread_lock() -> None:
    """Give tqdm a thread lock in a worker process: its default multiprocessing lock holds a
    semaphore that a killed worker never unregisters, and Python then warns of a "leaked
    semaphore" after the error. A worker's bars are off, so a thread lock serves."""
    tqdm.set_lock(threading.RLock())
