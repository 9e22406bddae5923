"""A store of generated sequences shared by every job of a machine, by content key.

A sequence's bytes depend only on its content key (``depotbench.sim.spec.content_key``: the
simulator spec, seed, format and generator version), so a sequence rendered once can
be copied wherever it is asked for again: ``depotbench generate``, a sweep's suite and
the pytest plugin render a sequence once per machine instead of once per job.

- **Where.** The ``sequences`` folder of the cache root (``depotbench.core.cache_home``:
  ``~/.cache/depotbench/sequences``), beside the stage cache; ``DEPOTBENCH_CACHE`` moves
  or switches off every cache, ``DEPOTBENCH_CACHE_SEQUENCES`` this one.
- **What.** One folder per key and PNG compression level, ``HEX-L`` (the key's SHA-256
  digest; the level shapes the bytes, not the pixels, and the key leaves it out): a
  complete sequence with its marker, written through ``depotbench.core.output.StagedOutput``
  (staged, locked, swapped into place), and beside it ``HEX-L.json`` with the key, the
  bytes and the files, written last. A second writer of one entry finds it locked (or
  complete) and leaves it be.
- **Copies out.** A sequence comes out as a copy (a hard link would let an edit in one
  place change the other), written through ``StagedOutput`` like a rendered one, with
  the marker of its key; the bytes and files copied are counted against ``HEX-L.json``,
  so a copy made while the entry was evicted is never taken.
- **Bounded.** ``DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES`` (default 20 GiB; ``500M``,
  ``20GiB`` and plain bytes are read); using an entry marks it used (its mtime) and the
  least recently used go first. An evicted entry is first renamed aside, so a reader
  copying it fails and renders instead.

The store only saves time: one that cannot be written (read-only, full, a file where
its folder should be) is read where it can be and otherwise left alone, with one
warning; the sequences are the same without it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import re
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path

from depotbench.core.cache_home import CACHES, cache_bound, cache_folder
from depotbench.core.files import DEFAULT_PNG_COMPRESSION
from depotbench.core.output import (
    MARKER_NAME,
    OutputError,
    OutputKind,
    OutputLock,
    StagedOutput,
    hidden_sibling,
    lock_path,
    read_marker,
    write_text_atomic,
)

NAME = "sequences"
"""The store's name under the cache root (``depotbench.core.cache_home.CACHES``)."""
VARIABLE = CACHES[NAME].variable
DEFAULT_MAX_BYTES = CACHES[NAME].default_bound
_KEY = re.compile(r"sha256:([0-9a-f]{64})")
_ENTRY = re.compile(r"[0-9a-f]{64}-[0-9]")
_EVICTED = ".evicted-"
log = logging.getLogger("depotbench.store")
_warned: set[str] = set()
"""Stores already warned about in this process: one warning each, however many sequences."""


@dataclass(frozen=True)
class _Entry:
    path: Path
    used: float
    """Its mtime: when it was last stored or copied out."""
    bytes: int


class SequenceStore:
    """Complete sequences by content key (see the module's docstring)."""

    def __init__(self, root: Path, max_bytes: int | None = None) -> None:
        self.root = Path(root)
        self.max_bytes = cache_bound(NAME) if max_bytes is None else max_bytes
        self.writable = True
        """False after a write failed: the run goes on without storing (warned once)."""

    @classmethod
    def from_env(cls) -> SequenceStore | None:
        """The store where the cache variables put it, or None when they switch it off. A
        bad ``DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES`` is refused."""
        root = cache_folder(NAME)
        return None if root is None else cls(root)

    # -- reading -----------------------------------------------------------------------

    def entry(self, key: str, png_compression: int = DEFAULT_PNG_COMPRESSION) -> Path | None:
        """The folder of ``key``'s entry written at this PNG level; None for a key that is
        not a content key."""
        match = _KEY.fullmatch(key or "")
        if match is None or png_compression not in range(10):
            return None
        return self.root / f"{match.group(1)}-{int(png_compression)}"

    def _manifest(self, entry: Path) -> dict | None:
        try:
            data = json.loads(entry.with_name(entry.name + ".json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return data if isinstance(data, dict) else None

    def has(self, key: str, png_compression: int = DEFAULT_PNG_COMPRESSION) -> bool:
        """Whether the store holds a complete sequence of ``key`` at this PNG level."""
        entry = self.entry(key, png_compression)
        if entry is None:
            return False
        marker = read_marker(entry)
        if marker is None or marker.kind is not OutputKind.SEQUENCE or marker.content_key != key:
            return False
        manifest = self._manifest(entry)
        return manifest is not None and manifest.get("content_key") == key

    def fetch(self, key: str, target: Path, png_compression: int = DEFAULT_PNG_COMPRESSION) -> bool:
        """Put a copy of ``key``'s sequence at ``target`` (staged, locked and marked as a
        rendered one is, replacing a stale sequence there); False when the store does not
        hold it (or it was evicted while being copied): then render it."""
        if not self.has(key, png_compression):
            return False
        entry = self.entry(key, png_compression)
        assert entry is not None
        manifest = self._manifest(entry) or {}
        with StagedOutput(target, OutputKind.SEQUENCE, overwrite=True, content_key=key) as out:
            try:
                copied = _copy_tree(entry, out.path)
            except OSError:
                if self.has(key, png_compression):
                    raise  # the store still holds it whole: the copy could not be written
                return False  # evicted meanwhile
            if copied != (manifest.get("bytes"), manifest.get("files")) or not self.has(key, png_compression):
                return False  # not what was stored: render it
            out.commit()
        with contextlib.suppress(OSError):  # a read-only store is still read
            os.utime(entry)  # most recently used
        return True

    # -- writing -----------------------------------------------------------------------

    def _unusable(self, doing: str, reason: str) -> None:
        if self.writable and str(self.root) not in _warned:
            _warned.add(str(self.root))
            log.warning(
                "the sequence store %s cannot %s (%s); going on without storing sequences, which "
                "costs time, not results (set %s to a writable folder, or %s=off)",
                self.root,
                doing,
                reason,
                VARIABLE,
                VARIABLE,
            )
        self.writable = False

    def put(self, sequence: Path, key: str, png_compression: int = DEFAULT_PNG_COMPRESSION) -> bool:
        """Add a copy of the complete sequence at ``sequence`` (of ``key``, its PNGs written
        at ``png_compression``), then evict what exceeds the bound; True when the store
        holds it afterwards. Never raises for the store's sake: a store that cannot be
        written costs one warning."""
        entry = self.entry(key, png_compression)
        if entry is None or not self.writable:
            return False
        if self.has(key, png_compression):
            with contextlib.suppress(OSError):
                os.utime(entry)
            return True
        try:
            if not self.root.is_dir():
                if self.root.exists():
                    raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(self.root))
                self.root.mkdir(parents=True, exist_ok=True)
            marker = read_marker(entry)
            if marker is not None and marker.content_key == key:  # stored, but HEX-L.json is missing
                size = _measure(entry)
            else:
                size = _measure(sequence)
                if size[0] > self.max_bytes:
                    return False  # it would evict everything, itself too
                with StagedOutput(entry, OutputKind.SEQUENCE, overwrite=True, content_key=key) as out:
                    if _copy_tree(sequence, out.path) != size:
                        return False  # the sequence changed while it was copied
                    out.commit()
            manifest = {"content_key": key, "bytes": size[0], "files": size[1]}
            write_text_atomic(entry.with_name(entry.name + ".json"), json.dumps(manifest) + "\n")
        except OutputError as exc:
            stored = read_marker(entry)
            if _busy(entry) or (stored is not None and stored.content_key == key):
                return False  # another process is storing (or has stored) this key: the same bytes
            self._unusable("store a sequence", str(exc))
            return False
        except FileNotFoundError:
            return False  # the entry was evicted, or the sequence removed, meanwhile
        except OSError as exc:
            self._unusable("store a sequence", exc.strerror or str(exc))
            return False
        self.evict()
        return self.has(key, png_compression)

    def entries(self) -> list[_Entry]:
        """Every complete-looking entry, least recently used first."""
        found = []
        try:
            names = [p for p in self.root.iterdir() if _ENTRY.fullmatch(p.name)]
        except FileNotFoundError:
            return []
        except OSError as exc:
            self._unusable("be listed", exc.strerror or str(exc))
            return []
        for path in names:
            with contextlib.suppress(OSError):  # evicted by another process meanwhile
                used = path.stat().st_mtime
                manifest = self._manifest(path)
                size = manifest.get("bytes") if manifest else None
                if not isinstance(size, int):
                    size = _measure(path)[0]
                found.append(_Entry(path, used, size))
        return sorted(found, key=lambda e: (e.used, e.path.name))

    def size_bytes(self) -> int:
        return sum(e.bytes for e in self.entries())

    def evict(self) -> int:
        """Remove least recently used entries until the store fits; returns how many went.
        An entry being written (locked) stays."""
        self._clean_evicted()
        entries = self.entries()
        total = sum(e.bytes for e in entries)
        removed = 0
        for item in entries:
            if total <= self.max_bytes:
                break
            lock = OutputLock(item.path)
            try:
                lock.acquire()
            except OutputError:
                continue  # being written (or not writable at all: then nothing is evicted)
            try:
                aside = hidden_sibling(item.path, f"{_EVICTED}{uuid.uuid4().hex[:8]}")
                os.rename(item.path, aside)  # readers copying it now fail, and render instead
                item.path.with_name(item.path.name + ".json").unlink(missing_ok=True)
                shutil.rmtree(aside, ignore_errors=True)
            except FileNotFoundError:
                pass  # evicted by another process
            except OSError as exc:
                self._unusable("evict an entry", exc.strerror or str(exc))
                break
            finally:
                lock.release()
            total -= item.bytes
            removed += 1
        return removed

    def _clean_evicted(self) -> None:
        """What an evicting process killed midway left (already renamed aside: nobody reads it)."""
        with contextlib.suppress(OSError):
            for path in self.root.glob(f".*{_EVICTED}*"):
                shutil.rmtree(path, ignore_errors=True)


def _busy(entry: Path) -> bool:
    """Whether another process holds ``entry``'s lock (so is storing it now)."""
    try:
        fd = os.open(lock_path(entry), os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    finally:
        os.close(fd)  # closing drops a lock taken here
    return False


def _copy_tree(source: Path, target: Path) -> tuple[int, int]:
    """Copy every file of ``source`` but its marker into the existing folder ``target``
    (contents only: fresh times and modes, as a rendered sequence has); returns the bytes
    and files copied."""
    total = files = 0
    for folder, dirs, names in os.walk(source, onerror=_raise):
        dirs.sort()
        relative = Path(folder).relative_to(source)
        (target / relative).mkdir(exist_ok=True)
        for name in sorted(names):
            if relative == Path(".") and name == MARKER_NAME:
                continue
            shutil.copyfile(Path(folder) / name, target / relative / name, follow_symlinks=False)
            total += (target / relative / name).lstat().st_size
            files += 1
    return total, files


def _measure(source: Path) -> tuple[int, int]:
    """The bytes and files ``_copy_tree`` would copy."""
    total = files = 0
    for folder, _, names in os.walk(source, onerror=_raise):
        relative = Path(folder).relative_to(source)
        for name in names:
            if relative == Path(".") and name == MARKER_NAME:
                continue
            total += (Path(folder) / name).lstat().st_size
            files += 1
    return total, files


def _raise(exc: OSError) -> None:
    raise exc
