"""Where depotbench keeps what it can make again, read in one place for every cache.

One root, ``$XDG_CACHE_HOME/depotbench`` (``~/.cache/depotbench``), holds one folder per
cache: ``stages`` (detections, features and flow), ``sequences`` (rendered sequences) and
``vocabulary`` (ORB vocabularies). One variable moves or switches off the whole root, and
each cache has one of the same form for itself; every reader asks ``cache_folder``, so
the variables mean the same everywhere:

- ``DEPOTBENCH_CACHE``: unset or ``on`` (``1``, ``yes``, ``true``) for the XDG root,
  ``off`` (``0``, ``no``, ``false``) for no cache at all, an absolute folder (``~``
  allowed) for the root moved there.
- ``DEPOTBENCH_CACHE_STAGES``, ``..._SEQUENCES``, ``..._VOCABULARY``: unset (or ``on``)
  for the cache's folder under the root, ``off``, or an absolute folder of its own. They
  act while the root is on: ``DEPOTBENCH_CACHE=off`` is a master switch, so that a
  one-off ``DEPOTBENCH_CACHE=off depotbench ...`` writes no cache whatever a profile
  sets for one.
- ``DEPOTBENCH_CACHE_STAGES_MAX_BYTES`` and ``DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES``
  bound those two (``500M``, ``2GiB`` or bytes); least recently used entries go first.

A relative folder is refused rather than taken from the working directory: an ``off``
mistyped once became a ``./off`` cache (reliability probe D7), and XDG's own rule is that
relative paths in its variables are invalid. A variable this bench no longer reads is
refused by name, so that a setting never silently stops working.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import re
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

from depotbench.core.errors import InputError

ROOT_VARIABLE = "DEPOTBENCH_CACHE"
OFF = ("off", "0", "no", "false")
ON = ("on", "1", "yes", "true")
_UNITS = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}
MAX_BOUND = (1 << 63) - 1
"""The largest bound read: a file size is a signed 64-bit number, so no cache holds more."""


@dataclass(frozen=True)
class Cache:
    """One cache under the root: its folder's name, what it holds, and its default bound."""

    name: str
    holds: str
    default_bound: int | None
    """Bytes; None: unbounded (the vocabulary cache holds one file per builder setting)."""

    @property
    def variable(self) -> str:
        return f"{ROOT_VARIABLE}_{self.name.upper()}"

    @property
    def bound_variable(self) -> str | None:
        return None if self.default_bound is None else f"{self.variable}_MAX_BYTES"


CACHES: dict[str, Cache] = {
    cache.name: cache
    for cache in (
        # 2 GiB: the stages of ~150 sequences; walking_xyz's 150 frames at 640x480 take 13.6 MB
        # (features 12.2 MB, flow 1.4 MB, detections 0.07 MB).
        Cache("stages", "detections, features and flow of sequences", 2 << 30),
        # 20 GiB: ~250 sequences; walking_xyz's 150 frames take 82 MB.
        Cache("sequences", "rendered sequences, by content key", 20 << 30),
        Cache("vocabulary", "ORB vocabularies for ORB-SLAM3 and external trackers", None),
    )
}


@dataclass(frozen=True)
class Contents:
    """Entries and bytes: what a cache holds, or what clearing it freed."""

    entries: int
    bytes: int


RETIRED = {
    "DEPOTBENCH_CACHE_DIR": "DEPOTBENCH_CACHE_STAGES",
    "DEPOTBENCH_CACHE_MAX_BYTES": "DEPOTBENCH_CACHE_STAGES_MAX_BYTES",
    "DEPOTBENCH_SEQUENCE_STORE": "DEPOTBENCH_CACHE_SEQUENCES",
    "DEPOTBENCH_SEQUENCE_STORE_MAX_BYTES": "DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES",
}
"""Variables of earlier versions, and what replaced each."""


def _refuse_retired() -> None:
    for old, new in RETIRED.items():
        if old in os.environ:
            raise InputError(
                f"{old}={os.environ[old]!r}: this variable is no longer read; set {new} "
                f"(or {ROOT_VARIABLE} to move or switch off every cache)"
            )


def _raw(variable: str) -> str:
    return os.environ.get(variable, "")


def _setting(variable: str) -> bool | Path | None:
    """A switch-or-folder variable: None when unset (or empty), True for on, False for off,
    or the absolute folder it names."""
    raw = _raw(variable)
    text = raw.strip()
    if not text:
        return None
    if text.lower() in OFF:
        return False
    if text.lower() in ON:
        return True
    try:
        path = Path(text).expanduser()
    except RuntimeError:  # ~name of no user here
        raise InputError(f"{variable}={raw!r}: {text.split('/')[0]} is no user's home folder here") from None
    if not path.is_absolute():
        raise InputError(f"{variable}={raw!r}: give on, off or an absolute folder (~ allowed)")
    return path


def default_root() -> Path:
    """``$XDG_CACHE_HOME/depotbench``, or ``~/.cache/depotbench`` when that is unset or
    relative (invalid, as the XDG Base Directory specification says)."""
    base = os.environ.get("XDG_CACHE_HOME", "")
    if not os.path.isabs(base):
        base = os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "depotbench"


@dataclass(frozen=True)
class Settings:
    """Every cache variable, read at once."""

    root: Path | None
    """None: ``DEPOTBENCH_CACHE`` switches it off."""
    folders: dict[str, Path | None]
    """Each cache's folder; None: switched off."""
    bounds: dict[str, int | None]
    off_by: dict[str, str | None]
    """The setting that switches each cache off (``DEPOTBENCH_CACHE='off'``), for messages."""


def settings() -> Settings:
    """Every cache variable, read as the module's docstring says; the first bad one is
    refused, whichever cache is asked for, so a mistake is caught by any command that uses
    a cache (not only by the rare one that uses the cache it names), and a command acting
    on several caches reads them all before it changes anything."""
    _refuse_retired()
    switch = _setting(ROOT_VARIABLE)
    root = None if switch is False else switch if isinstance(switch, Path) else default_root()
    folders: dict[str, Path | None] = {}
    bounds: dict[str, int | None] = {}
    off_by: dict[str, str | None] = {}
    for name, cache in CACHES.items():
        own = _setting(cache.variable)  # read (and checked) even when the root is off
        if root is None or own is False:
            folders[name] = None
            variable = ROOT_VARIABLE if root is None else cache.variable
            off_by[name] = f"{variable}={_raw(variable)!r}"
        else:
            folders[name] = own if isinstance(own, Path) else root / name
            off_by[name] = None
        bounds[name] = _bound(cache)
    return Settings(root, folders, bounds, off_by)


def _bound(cache: Cache) -> int | None:
    if cache.bound_variable is None:
        return None
    text = _raw(cache.bound_variable)
    return parse_bytes(text, cache.bound_variable) if text.strip() else cache.default_bound


def _cache(name: str) -> Cache:
    try:
        return CACHES[name]
    except KeyError:
        raise ValueError(f"no cache named {name!r}; the caches are {', '.join(CACHES)}") from None


def warning_level() -> int:
    """The level a cache that cannot be used is reported at: a warning in the command's own
    process, debug in a worker it spawned. The command probes its caches before its
    workers start and warns once, with its prefix; 2 workers used to print 11 to 14
    copies, without it (reliability probe M1)."""
    return logging.WARNING if multiprocessing.parent_process() is None else logging.DEBUG


def cache_root() -> Path | None:
    """The folder of every cache, as ``DEPOTBENCH_CACHE`` says; None when it is off."""
    return settings().root


def cache_folder(name: str) -> Path | None:
    """The folder of the cache ``name`` (``stages``, ``sequences``, ``vocabulary``); None
    when it is off."""
    return settings().folders[_cache(name).name]


def switched_off_by(name: str) -> str | None:
    """The setting that switches the cache ``name`` off (``DEPOTBENCH_CACHE='off'``), for
    messages; None when it is on."""
    return settings().off_by[_cache(name).name]


def cache_bound(name: str) -> int | None:
    """The bound in bytes of the cache ``name``, as its ``_MAX_BYTES`` variable says (its
    default when unset); None for a cache without one."""
    return settings().bounds[_cache(name).name]


def parse_bytes(text: str, name: str) -> int:
    """A size such as ``2147483648``, ``500M``, ``2GiB`` or ``1.5 GB`` (units of 1024), read
    exactly (a float of 400 digits is infinite) and at most ``MAX_BOUND``."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([kmgt]?)(?:i?b)?\s*", text, re.IGNORECASE)
    if match is None:
        raise InputError(f"{name}={text!r}: give a size in bytes, e.g. 2147483648, 500M or 2GiB")
    if len(match.group(1)) > 40:  # Python refuses to read an int of over 4300 digits (ValueError)
        raise InputError(f"{name}={text[:40]!r}...: more than the largest size, {MAX_BOUND} bytes")
    size = int(Fraction(match.group(1)) * _UNITS[match.group(2).lower()])
    if size > MAX_BOUND:
        raise InputError(f"{name}={text!r}: more than the largest size, {MAX_BOUND} bytes")
    return size
