"""The machine, renderer and libraries a generated sequence's bytes depend on, in one line.

OpenCV's version changes the textures' bytes, llvmpipe's vector code changes the pixels
(``GALLIUM_NOSSE=1`` drew other bytes on one machine), and a machine of another CPU made
other bytes with the same libraries (docs/determinism.md): a benchmark's lock records this
line for each sequence it freezes, so that a sequence refused on another machine names both."""

from __future__ import annotations

import functools
import platform
from importlib import metadata

from depotbench.core.numerics import cpuinfo

LIBRARIES = (("opencv", "opencv-python-headless"), ("mujoco", "mujoco"), ("numpy", "numpy"))


def _cpuinfo() -> tuple[str, set[str]]:
    """The CPU's model name and flags (Linux); the platform's word elsewhere."""
    found = cpuinfo()
    if found is None:
        return platform.processor() or platform.machine(), set()
    model, flags = found
    return model or platform.machine(), flags


def _version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "absent"


@functools.cache
def renderer() -> str:
    """The OpenGL renderer frames are drawn with, ``llvmpipe (LLVM 15.0.6, 256 bits), Mesa
    22.3.6``, read from a 1x1 context (0.1 s); the reason where no context can be made."""
    from depotbench.sim.mujoco_env import mujoco
    from OpenGL import GL

    try:
        context = mujoco.GLContext(1, 1)
    except (RuntimeError, OSError, ImportError, mujoco.FatalError) as exc:  # generation says why, itself
        return f"no OpenGL context ({type(exc).__name__})"
    try:
        context.make_current()
        name, version = (GL.glGetString(k).decode(errors="replace") for k in (GL.GL_RENDERER, GL.GL_VERSION))
    finally:
        context.free()
    return f"{name}, Mesa {version.split('Mesa ', 1)[1]}" if "Mesa " in version else f"{name}, {version}"


def machine_summary() -> str:
    """``AMD EPYC (avx2, no avx512); llvmpipe (LLVM 15.0.6, 256 bits), Mesa 22.3.6; opencv
    5.1.0.95, mujoco 4.0.0, numpy 2.4.6``."""
    model, flags = _cpuinfo()
    if "avx512f" in flags:
        simd = "avx512"
    elif "avx2" in flags:
        simd = "avx2, no avx512"
    else:
        simd = "no avx2" if flags else "flags unknown"
    libraries = ", ".join(f"{name} {_version(dist)}" for name, dist in LIBRARIES)
    return f"{model} ({simd}); {renderer()}; {libraries}"


def machine_kind(summary: str) -> str:
    """The CPU and renderer of a ``machine_summary`` line, without the libraries: what decides
    whether two machines draw the same bytes (OpenCV is pinned to one minor version, and
    mujoco 4.0.0 and 4.0.1 drew the same bytes). AVX-512 and AVX2 are one class: the bench
    runs numpy's and OpenBLAS's AVX2 code on an AVX-512 CPU (core/numerics.py), and an
    AVX-512 EPYC then generated an AVX2 EPYC's bytes."""
    cpu, *rest = summary.split("; ")[:2]
    cpu = cpu.replace("(avx512)", "(avx2)").replace("(avx2, no avx512)", "(avx2)")
    return "; ".join([cpu, *rest])
