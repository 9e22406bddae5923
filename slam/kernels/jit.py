"""The one way kernels are compiled: ``numba.njit`` with fixed options, cached where it can be."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TypeVar

OPTIONS = {"fastmath": False, "parallel": False, "error_model": "numpy", "nogil": False}
"""Numba options of every kernel: IEEE arithmetic in NumPy's order, NumPy's division by zero
(inf or NaN, no exception), one thread."""

_log = logging.getLogger(__name__)
F = TypeVar("F", bound=Callable)


def jit(function: F) -> F:
    """``numba.njit`` with ``OPTIONS``, cached on disk where Numba finds a writable folder.

    Numba looks for one when the kernel is defined (``NUMBA_CACHE_DIR``, the package's
    ``__pycache__``, the user's cache) and raises if there is none, as in a read-only install
    run by a user without a home; the kernels then compile in memory in every process
    (14 s for all of them on a busy 2-core machine, against 0.5 s to load them from the cache;
    ``benchmarks/tracking.py --kernels both`` prints both)."""
    import numba

    try:
        return numba.njit(cache=True, **OPTIONS)(function)
    except RuntimeError as error:
        if "no locator available" not in str(error):
            raise
        _log.warning("numba: no writable cache folder for %s; compiling in memory", function.__name__)
        return numba.njit(cache=False, **OPTIONS)(function)
