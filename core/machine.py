"""The machine and libraries a generated sequence's bytes depend on, in one line.

OpenCV's version changes the textures' bytes, and a machine of another CPU made other bytes
with the same libraries (docs/determinism.md): a benchmark's lock records this line for each
sequence it freezes, so that a sequence refused on another machine names both."""

from __future__ import annotations

import platform
from importlib import metadata
from pathlib import Path

LIBRARIES = (("opencv", "opencv-python-headless"), ("mujoco", "mujoco"), ("numpy", "numpy"))


def _cpuinfo() -> tuple[str, set[str]]:
    """The CPU's model name and flags (Linux); the platform's word elsewhere."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor() or platform.machine(), set()
    fields = dict(line.split(":", 1) for line in text.splitlines() if ":" in line)
    fields = {k.strip(): v.strip() for k, v in fields.items()}
    return fields.get("model name", platform.machine()), set(fields.get("flags", "").split())


def _version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "absent"


def machine_summary() -> str:
    """``AMD EPYC (avx2, no avx512); opencv 5.1.0.95, mujoco 4.0.0, numpy 2.4.6``."""
    model, flags = _cpuinfo()
    if "avx512f" in flags:
        simd = "avx512"
    elif "avx2" in flags:
        simd = "avx2, no avx512"
    else:
        simd = "no avx2" if flags else "flags unknown"
    libraries = ", ".join(f"{name} {_version(dist)}" for name, dist in LIBRARIES)
    return f"{model} ({simd}); {libraries}"
