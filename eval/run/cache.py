"""A disk cache for stages that do not depend on the swept thresholds.

Entries are files named by a content hash of everything their value depends on
(the caller makes the key), written atomically, so readers see a whole entry or
none and concurrent writers of one key write the same bytes. Reading an entry
marks it used (its mtime); when the cache grows past its bound the least
recently used entries go. It lives in the ``stages`` folder of the cache root
(``depotbench.core.cache_home``: ``DEPOTBENCH_CACHE`` moves or switches off every cache,
``DEPOTBENCH_CACHE_STAGES`` this one, ``DEPOTBENCH_CACHE_STAGES_MAX_BYTES`` bounds it,
2 GiB by default).

Each entry is stored with a SHA-256 digest of its bytes ahead of them (``ENTRY_HEADER``);
an entry whose bytes no longer match (a flipped block, a truncation: the numpy archives
the stages are stored as are uncompressed, so a changed byte inside an array decodes
without complaint) is a miss, and the stage is computed and stored again.

Only files named as entries are ever listed, evicted or cleared (``STAGE/HEX``, 32
hexadecimal digits): a cache folder set by mistake to one holding other files loses none
of them.

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
import re
import stat
import tempfile
import time
from pathlib import Path

from depotbench.core.cache_home import CACHES, Contents, cache_bound, cache_folder, warning_level
from depotbench.core.errors import FileError
from depotbench.core.files import read_bytes
from depotbench.core.output import OutputError, write_bytes_atomic

NAME = "stages"
"""The cache's name under the root (``depotbench.core.cache_home.CACHES``)."""
DEFAULT_MAX_BYTES = CACHES[NAME].default_bound
_ENTRY = re.compile(r"[0-9a-f]{32}")
_TEMPORARY = re.compile(r"\.[0-9a-f]{32}\.[0-9a-f]{8}\.tmp")
"""What ``write_bytes_atomic`` writes first (``.KEY.XXXXXXXX.tmp``), left by a killed writer."""
STALE_TEMPORARY_S = 3600.0
"""A temporary file older than an hour is a killed writer's: an entry (12 MB of features
for 150 frames of 640x480) is written in well under a second, so clearing never takes a
live writer's file."""
log = logging.getLogger("depotbench.cache")
_warned: set[str] = set()
"""Caches already warned about in this process: one warning each, however many jobs."""
ENTRY_HEADER = b"depotbench stage entry 1\n"
"""What an entry begins with, before the 32-byte SHA-256 digest of its value; an entry
without it (one an older version wrote) is a miss, like a damaged one."""
_DIGEST_BYTES = 32
ENTRY_OVERHEAD = len(ENTRY_HEADER) + _DIGEST_BYTES
"""Bytes an entry's file holds beyond its value."""


def content_hash(*parts: object) -> str:
    """A stable key of JSON-able parts."""
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:32]


def _verified(stored: bytes) -> bytes | None:
    """An entry's value, or None when its digest does not match (or it has no header)."""
    head = ENTRY_OVERHEAD
    if not stored.startswith(ENTRY_HEADER) or len(stored) < head:
        return None
    data = stored[head:]
    return data if hashlib.sha256(data).digest() == stored[len(ENTRY_HEADER) : head] else None


class StageCache:
    def __init__(self, root: Path, max_bytes: int | None = None, unwritable: str | None = None) -> None:
        """``max_bytes``: the bound, ``DEPOTBENCH_CACHE_STAGES_MAX_BYTES``'s when None;
        ``unwritable``: what the warning says of a folder that cannot be written, where it is
        not the stage cache (a sweep folder's views)."""
        self.root = Path(root)
        self.unwritable = unwritable
        self.max_bytes = cache_bound(NAME) if max_bytes is None else max_bytes
        self.hits = 0
        self.misses = 0
        self.writable = True
        """False after a write failed: the run goes on without storing (warned once)."""

    @classmethod
    def from_env(cls) -> StageCache | None:
        """The cache where the cache variables put it, or None when they switch it off."""
        root = cache_folder(NAME)
        return None if root is None else cls(root)

    def probe(self) -> bool:
        """Whether the cache can be written, warned here when not. A sweep asks before its
        workers start, so that the warning comes once, from the command, with its prefix:
        workers only log it for debugging (``warning_level``)."""
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=self.root):  # unnamed (O_TMPFILE): nothing left behind
                pass
        except OSError as exc:
            self._unusable("be written", exc.strerror or str(exc))
            return False
        return True

    def _unusable(self, doing: str, reason: str) -> None:
        if self.writable and str(self.root) not in _warned:
            _warned.add(str(self.root))
            if self.unwritable is not None:
                log.log(warning_level(), "%s %s cannot %s (%s)", self.unwritable, self.root, doing, reason)
            else:
                log.log(
                    warning_level(),
                    "the stage cache %s cannot %s (%s); going on without storing stages, which costs "
                    "time, not results (set %s to a writable folder, or %s=off)",
                    self.root,
                    doing,
                    reason,
                    CACHES[NAME].variable,
                    CACHES[NAME].variable,
                )
        self.writable = False

    def _path(self, stage: str, key: str) -> Path:
        if not stage.isidentifier() or _ENTRY.fullmatch(key) is None:
            raise ValueError(f"bad cache stage or key: {stage!r} {key!r}")
        return self.root / stage / key

    def get(self, stage: str, key: str) -> bytes | None:
        """The entry's value; None (a miss) when there is none or it is damaged."""
        path = self._path(stage, key)
        try:  # bounded: an entry larger than the cache's bound is evicted when stored
            stored = read_bytes(path, max(self.max_bytes, 0) + ENTRY_OVERHEAD, "stage entry")
        except FileNotFoundError:
            return self._miss(stage, key, "no entry")
        except OSError as exc:  # a file where a folder should be, an unreadable entry
            self._unusable("be read", exc.strerror or str(exc))
            return self._miss(stage, key, exc.strerror or "unreadable")
        except FileError:  # not a regular file, or over the bound: recomputed, then replaced
            return self._miss(stage, key, "not a regular file or over the bound")
        data = _verified(stored)
        if data is None:
            return self._miss(stage, key, "damaged (digest does not match)")
        with contextlib.suppress(OSError):  # evicted meanwhile: the bytes read are still whole
            os.utime(path)  # most recently used
        self.hits += 1
        log.debug("stage cache hit: %s %s (%d bytes) in %s", stage, key, len(data), self.root)
        return data

    def _miss(self, stage: str, key: str, why: str) -> None:
        self.misses += 1
        log.debug("stage cache miss: %s %s (%s) in %s", stage, key, why, self.root)

    def put(self, stage: str, key: str, data: bytes) -> None:
        if not self.writable:
            return
        path = self._path(stage, key)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(path, ENTRY_HEADER + hashlib.sha256(data).digest() + data)
        except OSError as exc:
            self._unusable("store an entry", exc.strerror or str(exc))
            return
        except OutputError as exc:  # the atomic write's own one-line error
            self._unusable("store an entry", str(exc))
            return
        log.debug("stage cache stored: %s %s (%d bytes)", stage, key, len(data))
        self.evict()

    def entries(self) -> list[tuple[float, int, Path]]:
        """(mtime, size, path) of every entry, oldest first."""
        out = []
        try:
            for stage in self._stages():
                for entry in stage.iterdir():
                    if _ENTRY.fullmatch(entry.name) is None:
                        continue  # a writer's temporary file, or not the cache's
                    with contextlib.suppress(FileNotFoundError):  # evicted by another process
                        st = entry.stat(follow_symlinks=False)
                        if stat.S_ISREG(st.st_mode):
                            out.append((st.st_mtime, st.st_size, entry))
        except FileNotFoundError:
            pass
        except OSError as exc:  # not a folder, or not readable: nothing to list or evict
            self._unusable("be listed", exc.strerror or str(exc))
        return sorted(out)

    def _stages(self) -> list[Path]:
        return [p for p in self.root.iterdir() if p.name.isidentifier() and p.is_dir() and not p.is_symlink()]

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

    def retain(self, stage: str, names: set[str]) -> int:
        """Remove the entries of ``stage`` not named in ``names`` (the ones still wanted);
        returns how many went. A folder that cannot be written keeps them, warned once."""
        removed = 0
        for _, _, path in self.entries():
            if path.parent.name != stage or path.name in names:
                continue
            try:
                path.unlink()
            except FileNotFoundError:
                continue  # evicted by another process
            except OSError as exc:
                self._unusable("remove an entry", exc.strerror or str(exc))
                break
            removed += 1
        return removed

    def clear(self) -> Contents:
        """Remove every entry (and what killed writers left an hour ago or more); what
        another process reads meanwhile stays whole for it (an unlinked file's bytes live
        until it is closed), and one it writes meanwhile simply stays."""
        entries = self.entries()
        removed = freed = 0
        for _, size, path in entries:
            try:
                path.unlink()
            except FileNotFoundError:
                continue  # evicted by another process
            removed += 1
            freed += size
        now = time.time()
        with contextlib.suppress(FileNotFoundError):
            for stage in self._stages():
                for path in stage.iterdir():
                    if _TEMPORARY.fullmatch(path.name) is None:
                        continue
                    with contextlib.suppress(FileNotFoundError):
                        st = path.stat(follow_symlinks=False)
                        if stat.S_ISREG(st.st_mode) and now - st.st_mtime >= STALE_TEMPORARY_S:
                            path.unlink()
                            freed += st.st_size
        return Contents(removed, freed)
