"""Compiled kernels: the one way they are compiled, the one switch between them and NumPy, and
how a process warms them up before anything is timed.

The tracker's (``slam.kernels``) and the generator's (``sim.kernels``) hot loops are Numba
kernels beside NumPy references. One environment variable, read here and nowhere else, picks
the path:

- ``DEPOTBENCH_KERNELS=numba``: the compiled kernels (the default where numba imports);
- ``DEPOTBENCH_KERNELS=numpy``: the NumPy reference throughout.
"""

from __future__ import annotations

import contextlib
import enum
import functools
import importlib.util
import logging
import os
import threading
import time
from collections.abc import Callable, Iterator
from typing import TypeVar

from depotbench.core.errors import InputError
from depotbench.core.logs import DETAIL

OPTIONS = {"fastmath": False, "parallel": False, "error_model": "numpy", "nogil": False}
"""Numba options of every kernel: IEEE arithmetic in NumPy's order, NumPy's division by zero
(inf or NaN, no exception), one thread."""
ANNOUNCE_AFTER_S = 3.0
"""A warm-up still running after this long is compiling, not loading (0.5 s from the cache,
1.5 s on a busy machine, 24-50 s compiling): only then does it say so, so a user knows what
the wait is."""
LOG = logging.getLogger("depotbench.kernels")
F = TypeVar("F", bound=Callable)

VARIABLE = "DEPOTBENCH_KERNELS"


class Kernels(enum.Enum):
    NUMPY = "numpy"
    NUMBA = "numba"


@functools.cache
def kernels() -> Kernels:
    """The path this process runs, from ``DEPOTBENCH_KERNELS`` (read once; tests that set it
    call ``kernels.cache_clear()``). A value other than numpy or numba is refused, and so is
    numba where it is not installed: a comparison that asked for it must not get NumPy."""
    value = os.environ.get(VARIABLE, "").strip().lower()
    installed = importlib.util.find_spec("numba") is not None
    if not value:
        return Kernels.NUMBA if installed else Kernels.NUMPY
    try:
        chosen = Kernels(value)
    except ValueError:
        choices = " or ".join(k.value for k in Kernels)
        raise InputError(f"{VARIABLE}={os.environ[VARIABLE]!r}: choose {choices}") from None
    if chosen is Kernels.NUMBA and not installed:
        raise InputError(f"{VARIABLE}=numba, but numba is not installed (pip install numba)")
    return chosen


def compiled() -> bool:
    """Whether the hot paths run compiled (the callers' one question)."""
    return kernels() is Kernels.NUMBA


@contextlib.contextmanager
def using(path: Kernels) -> Iterator[None]:
    """Run a block on one path, as ``DEPOTBENCH_KERNELS`` set for it would (benchmarks and tests
    compare both in one process); the variable is restored after."""
    before = os.environ.get(VARIABLE)
    os.environ[VARIABLE] = path.value
    kernels.cache_clear()
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(VARIABLE, None)
        else:
            os.environ[VARIABLE] = before
        kernels.cache_clear()


def warmed(what: str, warm_up: Callable[[], object], compile_s: tuple[float, float]) -> float:
    """Run ``warm_up`` (which compiles or loads ``what``'s kernels) and return its seconds. One
    that runs past ``ANNOUNCE_AFTER_S`` is compiling: it is announced with ``compile_s``, the
    range a compile has taken on 2 cores, so the wait reads as a step of its own; a load shows
    under -v."""
    announce = threading.Timer(
        ANNOUNCE_AFTER_S,
        LOG.info,
        (
            f"compiling {what} (the first run after an install: {compile_s[0]:.0f}-{compile_s[1]:.0f} s "
            "on 2 cores; later runs load it)",
        ),
    )
    announce.daemon = True
    announce.start()
    started = time.perf_counter()
    try:
        warm_up()
    finally:
        announce.cancel()
    seconds = time.perf_counter() - started
    said = logging.INFO if seconds > ANNOUNCE_AFTER_S else DETAIL
    LOG.log(said, f"{what} ready in {seconds:.1f} s (kept in Numba's cache for later runs)")
    return seconds


def jit(function: F) -> F:
    """``numba.njit`` with ``OPTIONS``, cached on disk where Numba finds a writable folder.

    Numba looks for one when the kernel is defined (``NUMBA_CACHE_DIR``, the package's
    ``__pycache__``, the user's cache) and raises if there is none, as in a read-only install
    run by a user without a home; the kernels then compile in memory in every process
    (40-50 s for all of them on a 2-core machine, against 0.5 s to load them from the cache;
    ``benchmarks/tracking.py --kernels both`` prints both)."""
    import numba

    try:
        return numba.njit(cache=True, **OPTIONS)(function)
    except RuntimeError as error:
        if "no locator available" not in str(error):
            raise
        LOG.warning("numba: no writable cache folder for %s; compiling in memory", function.__name__)
        return numba.njit(cache=False, **OPTIONS)(function)
