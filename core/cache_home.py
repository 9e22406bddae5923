"""Where depotbench keeps what it can make again (stages, sequences, vocabularies), and
how its size and switch variables are read: one reading for every cache."""

from __future__ import annotations

import os
import re
from pathlib import Path

from depotbench.core.errors import InputError

OFF = ("off", "0", "no", "false")
ON = ("on", "1", "yes", "true", "")
_UNITS = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}


def cache_home() -> Path:
    """The folder of all of depotbench's caches, as XDG says (``~/.cache/depotbench``)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "depotbench"


def parse_bytes(text: str, name: str) -> int:
    """A size such as ``2147483648``, ``500M``, ``2GiB`` or ``1.5 GB`` (units of 1024)."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([kmgt]?)(?:i?b)?\s*", text, re.IGNORECASE)
    if match is None:
        raise InputError(f"{name}={text!r}: give a size in bytes, e.g. 2147483648, 500M or 2GiB")
    return int(float(match.group(1)) * _UNITS[match.group(2).lower()])
