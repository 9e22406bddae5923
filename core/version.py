"""Versions that outputs record: the sequence format's and the generator's."""

from __future__ import annotations

import functools
from importlib import metadata

FORMAT_VERSION = 1
SUPPORTED_FORMAT_VERSIONS = (1,)


@functools.cache
def generator_version() -> str:
    """The installed depotbench's version, read once per process: the code a process runs does
    not change when the installed metadata does, and a read scans the import path (0.4 ms;
    stage and run keys ask for it once per job)."""
    try:
        return metadata.version("depotbench")
    except metadata.PackageNotFoundError:
        return "unknown"
