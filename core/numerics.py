"""numpy's and OpenBLAS's code for the CPU, set as on the reference machine kind.

Both pick their vector code when they load, by the CPU, and on an AVX-512 machine round
otherwise than their AVX2 code does: numpy's X86_V4 loops (SVML's sin, cos, exp, power, ...)
and OpenBLAS's SkylakeX kernels. That, and not the renderer, is what made an AVX-512 EPYC
generate other bytes than CI's AVX2 EPYC (smoke-1's first sequence fe4db6a5... against the
lock's 9c44a437...): with numpy's AVX-512 targets disabled (``NPY_DISABLE_CPU_FEATURES``)
and OpenBLAS on its Haswell kernels (``OPENBLAS_CORETYPE``) it generated the lock's bytes,
for smoke-1 and for the tum-dyn-short-1 and depot-1 sequences tried (docs/determinism.md).

They read those variables when they load, so importing ``depotbench`` sets them where numpy
is not loaded yet (the command, the pytest plugin, the benchmarks' scripts, a program that
imports the bench first), and spawned workers inherit them; a variable the user set is left
as it is. Where numpy was loaded before, the process keeps its own code and ``generate``
warns in it, but the bench's worker pools set them before they spawn (``core.executors``):
workers load numpy afresh, so a suite or benchmark rendered in them has the reference bytes
whatever the program imported first. This module imports nothing heavy: it runs before
numpy does.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

NUMPY_AVX512 = (
    "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR X86_V4"
)
"""numpy's AVX-512 dispatch targets under both their names (numpy 1.x: AVX512_SKX...; 2.4:
X86_V4, AVX512_ICL, AVX512_SPR); numpy passes over a name it does not know."""
OPENBLAS_CORE = "Haswell"
"""OpenBLAS's AVX2 kernels, which its Zen targets (CI's EPYC) use too."""
OPENBLAS_AVX512 = {"skylakex", "cooperlake", "sapphirerapids"}
"""OpenBLAS's cores that run AVX-512 kernels (threadpoolctl's ``architecture``)."""


def cpuinfo() -> tuple[str | None, set[str]] | None:
    """The first CPU's model name (None where none is given) and flags from ``/proc/cpuinfo``;
    None where it cannot be read (not Linux). ``sim.machine`` names the machine from it too."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None
    fields: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():  # the first processor's block ends: every CPU is the same model
            break
        name, _, value = line.partition(":")
        fields.setdefault(name.strip(), value.strip())
    return fields.get("model name"), set(fields.get("flags", "").split())


@functools.cache
def reference_environment() -> dict[str, str]:
    """The variables that make this machine's numpy and OpenBLAS compute as an AVX2 one's:
    none where the CPU has no AVX-512."""
    found = cpuinfo()
    if found is None or "avx512f" not in found[1]:
        return {}
    return {"NPY_DISABLE_CPU_FEATURES": NUMPY_AVX512, "OPENBLAS_CORETYPE": OPENBLAS_CORE}


def apply_reference_environment() -> None:
    """Set each reference variable the user has not set (``depotbench/__init__.py`` calls it
    while numpy is not loaded yet)."""
    for name, value in reference_environment().items():
        os.environ.setdefault(name, value)


def workers_on_reference() -> bool:
    """Whether the workers the bench's pools spawn compute as the reference: they load numpy
    afresh with this environment, each reference variable set where the user has not
    (``apply_reference_environment``), so False only where the user set one otherwise."""
    return all(os.environ.get(name, value) == value for name, value in reference_environment().items())


def off_reference() -> list[str]:
    """What in this process computes otherwise than the reference (empty where all is as
    there): numpy's AVX-512 loops, OpenBLAS's AVX-512 kernels."""
    if not reference_environment():
        return []
    import numpy as np

    try:
        from numpy._core import _multiarray_umath as umath
    except ImportError:  # numpy 1.x
        from numpy.core import _multiarray_umath as umath  # type: ignore[no-redef]
    from threadpoolctl import threadpool_info

    off = []
    targets = set(NUMPY_AVX512.split()) & set(getattr(umath, "__cpu_dispatch__", ()))
    features = getattr(umath, "__cpu_features__", {})
    if any(features.get(name) for name in targets):
        off.append(f"numpy {np.__version__}'s AVX-512 loops")
    for library in threadpool_info():
        core = str(library.get("architecture"))
        said = f"OpenBLAS's {core} kernels"  # numpy's and SciPy's OpenBLAS: said once
        if library.get("internal_api") == "openblas" and core.lower() in OPENBLAS_AVX512 and said not in off:
            off.append(said)
    return off
