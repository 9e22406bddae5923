"""A disk cache for stages that do not depend on the swept thresholds.

Entries are files named by a content hash of everything their value depends on
(the caller makes the key), written atomically, so readers see a whole entry or
none and concurrent writers of one key write the same bytes. Reading an entry
marks it used (its mtime); when the cache grows past its bound the least
recently used entries go. ``DEPOTBENCH_CACHE_DIR`` moves it (default
``$XDG_CACHE_HOME/depotbench/stages``, or ``~/.cache/depotbench/stages``),
``DEPOTBENCH_CACHE_MAX_BYTES`` bounds it (default 2 GiB; ``500M``, ``2GiB`` and plain
bytes are read), and ``DEPOTBENCH_CACHE=off`` turns it off.

The cache only saves time, so a cache that cannot be written (read-only, full, a file
where its folder should be) is read where it can be and otherwise left alone, with one
warning: the run's results are the same without it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
from pathlib import Path

from depotbench.core.cache_home import OFF as _OFF
from depotbench.core.cache_home import ON as _ON
from depotbench.core.cache_home import cache_home, parse_bytes
from depotbench.core.errors import InputError
from depotbench.core.output import OutputError, write_bytes_atomic

DEFAULT_MAX_BYTES = 2 << 30
SWITCH = "DEPOTBENCH_CACHE"
log = logging.getLogger("depotbench.cache")


def default_root() -> Path:
    env = os.environ.get("DEPOTBENCH_CACHE_DIR")
    return Path(env) if env else cache_home() / "stages"


def cache_enabled() -> bool:
    """``DEPOTBENCH_CACHE``: on (the default) or off; anything else is refused by name,
    since a folder given here (as some once did) would silently mean "on"."""
    value = os.environ.get(SWITCH, "").strip().lower()
    if value in _OFF:
        return False
    if value in _ON:
        return True
    raise InputError(
        f"{SWITCH}={os.environ[SWITCH]!r}: give on or off (the cache's folder is DEPOTBENCH_CACHE_DIR)"
    )


def content_hash(*parts: object) -> str:
    """A stable key of JSON-able parts."""
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:32]


class StageCache:
    def __init__(self, root: Path | None = None, max_bytes: int | None = None) -> None:
        self.root = root or default_root()
        env = os.environ.get("DEPOTBENCH_CACHE_MAX_BYTES")
        if max_bytes is None:
            max_bytes = parse_bytes(env, "DEPOTBENCH_CACHE_MAX_BYTES") if env else DEFAULT_MAX_BYTES
        self.max_bytes = max_bytes
        self.hits = 0
        self.misses = 0
        self.writable = True
        """False after a write failed: the run goes on without storing (warned once)."""

    @classmethod
    def from_env(cls) -> StageCache | None:
        """The default cache, or None when ``DEPOTBENCH_CACHE=off``."""
        return cls() if cache_enabled() else None

    def _unusable(self, doing: str, reason: str) -> None:
        if self.writable:
            log.warning(
                "the stage cache %s cannot %s (%s); going on without storing stages, which costs "
                "time, not results (set DEPOTBENCH_CACHE_DIR to a writable folder, or DEPOTBENCH_CACHE=off)",
                self.root,
                doing,
                reason,
            )
        self.writable = False

    def _path(self, stage: str, key: str) -> Path:
        if not stage.isidentifier() or not key.isalnum():
            raise ValueError(f"bad cache stage or key: {stage!r} {key!r}")
        return self.root / stage / key

    def get(self, stage: str, key: str) -> bytes | None:
        path = self._path(stage, key)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            self.misses += 1
            return None
        except OSError as exc:  # a file where a folder should be, an unreadable entry
            self._unusable("be read", exc.strerror or str(exc))
            self.misses += 1
            return None
        with contextlib.suppress(OSError):  # evicted meanwhile: the bytes read are still whole
            os.utime(path)  # most recently used
        self.hits += 1
        return data

    def put(self, stage: str, key: str, data: bytes) -> None:
        if not self.writable:
            return
        path = self._path(stage, key)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(path, data)
        except OSError as exc:
            self._unusable("store an entry", exc.strerror or str(exc))
            return
        except OutputError as exc:  # the atomic write's own one-line error
            self._unusable("store an entry", str(exc))
            return
        self.evict()

    def entries(self) -> list[tuple[float, int, Path]]:
        """(mtime, size, path) of every entry, oldest first."""
        out = []
        try:
            stages = [stage for stage in self.root.iterdir() if stage.is_dir()]
            for stage in stages:
                for entry in stage.iterdir():
                    if entry.name.startswith("."):
                        continue  # a writer's temporary file
                    with contextlib.suppress(FileNotFoundError):  # evicted by another process
                        st = entry.stat()
                        out.append((st.st_mtime, st.st_size, entry))
        except FileNotFoundError:
            pass
        except OSError as exc:  # not a folder, or not readable: nothing to list or evict
            self._unusable("be listed", exc.strerror or str(exc))
        return sorted(out)

    def size_bytes(self) -> int:
        return sum(size for _, size, _ in self.entries())

    def evict(self) -> int:
        """Remove least recently used entries until the cache fits; returns how many went."""
        entries = self.entries()
        total = sum(size for _, size, _ in entries)
        removed = 0
        for _, size, path in entries:
            if total <= self.max_bytes:
                break
            try:
                path.unlink()
            except FileNotFoundError:
                pass
            except OSError as exc:  # a read-only cache stays as it is
                self._unusable("evict an entry", exc.strerror or str(exc))
                break
            total -= size
            removed += 1
        return removed
