"""Versions that outputs record: the sequence format's and the generator's."""

from __future__ import annotations

from importlib import metadata

FORMAT_VERSION = 1
SUPPORTED_FORMAT_VERSIONS = (1,)


def generator_version() -> str:
    try:
        return metadata.version("depotbench")
    except metadata.PackageNotFoundError:
        return "unknown"
