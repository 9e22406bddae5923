"""A store of generated sequences shared by every job of a machine, by content key.

A sequence's bytes depend only on its content key (``depotbench.sim.spec.content_key``: the
simulator spec, seed, format and generator version), so a sequence rendered once can
be copied wherever it is asked for again: ``depotbench generate``, a sweep's suite and
the pytest plugin render a sequence once per machine instead of once per job.

- **Where.** The ``sequences`` folder of the cache root (``depotbench.core.cache_home``:
  ``~/.cache/depotbench/sequences``), beside the stage cache; ``DEPOTBENCH_CACHE`` moves
  or switches off every cache, ``DEPOTBENCH_CACHE_SEQUENCES`` this one.
- **What.** One folder per key and PNG compression level, ``HEX-L-r2`` (the key's SHA-256
  digest; the level shapes the bytes, not the pixels, and the key leaves it out): a
  complete sequence with its marker, written through ``depotbench.core.output.StagedOutput``
  (staged, locked, swapped into place), and beside it ``HEX-L.json`` with the key, the
  bytes, the files and a digest of the whole (each file's path, size and SHA-256), written
  last. A second writer of one entry finds it locked (or
  complete) and leaves it be.
- **Copies out.** A sequence comes out as a copy (a hard link would let an edit in one
  place change the other), written through ``StagedOutput`` like a rendered one, with
  the marker of its key; the bytes, files and digest of what was copied are checked
  against ``HEX-L.json``, so a copy made while the entry was evicted is never taken, and
  an entry changed in place (edited, rotted) is removed with one warning and rendered
  again, never served under its key. Hashing while copying costs about 0.1 s on a
  300-frame entry (162 MB in 900 files: 0.3 s against 0.2 s for a plain copy).
- **Bounded.** ``DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES`` (default 20 GiB; ``500M``,
  ``20GiB`` and plain bytes are read); using an entry marks it used (its mtime) and the
  least recently used go first, when one is stored and before one is copied out (so a
  bound lowered below what the store holds takes effect at once). An evicted entry is
  first renamed aside, so a reader copying it fails and renders instead.

The store only saves time: one that cannot be written (read-only, full, a file where
its folder should be) is read where it can be and otherwise left alone, with one
warning; the sequences are the same without it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import logging
import os
import re
import shutil
import stat
import uuid
from dataclasses import dataclass
from pathlib import Path

from depotbench.core.cache_home import CACHES, cache_bound, cache_folder, warning_level
from depotbench.core.errors import InputError
from depotbench.core.files import DEFAULT_PNG_COMPRESSION, read_json
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
ENTRY_SUFFIX = "-r2"
"""Entries written since the bench set numpy's and OpenBLAS's code for the CPU
(``core/numerics.py``, 2026-12-04): an AVX-512 machine's older entries hold its own bytes
under the key, so they are never read again, only evicted (``HEX-L`` without the suffix)."""
_ENTRY = re.compile(r"[0-9a-f]{64}-[0-9](-r2)?")
_EVICTED = ".evicted-"
MANIFEST_MAX_BYTES = 64 * 1024
"""``HEX-L.json`` holds the key, two counts and a digest: about 200 bytes."""
log = logging.getLogger("depotbench.store")
_warned: set[str] = set()
"""Stores already warned about in this process: one warning each, however many sequences."""


@dataclass(frozen=True)
class _Copied:
    """What ``_copy_tree`` copied: what ``HEX-L.json`` records of an entry."""

    bytes: int
    files: int
    digest: str
    """SHA-256 over each file's relative path, size and SHA-256, in a fixed order."""


class _Damaged(Exception):
    """An entry (or a sequence being stored) holding what a sequence never holds: a link,
    a FIFO, a device."""


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
    def from_env(cls, workers: bool = False) -> SequenceStore | None:
        """The store where the cache variables put it, or None when they switch it off or
        when the process that renders computes otherwise than the bench sets numpy and
        OpenBLAS: this one (numpy imported before the bench: its sequences are this
        machine's own bytes, and ``generate`` says so), or with ``workers`` the workers a
        local pool spawns (a suite's), where the user set the variables otherwise. Such
        bytes are neither taken from the store nor put in it. A bad
        ``DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES`` is refused."""
        from depotbench.core.numerics import off_reference, workers_on_reference

        root = cache_folder(NAME)
        if root is None:
            return None
        on_reference = workers_on_reference() if workers else not off_reference()
        return cls(root) if on_reference else None

    # -- reading -----------------------------------------------------------------------

    def entry(self, key: str, png_compression: int = DEFAULT_PNG_COMPRESSION) -> Path | None:
        """The folder of ``key``'s entry written at this PNG level; None for a key that is
        not a content key."""
        match = _KEY.fullmatch(key or "")
        if match is None or png_compression not in range(10):
            return None
        return self.root / f"{match.group(1)}-{int(png_compression)}{ENTRY_SUFFIX}"

    def _manifest(self, entry: Path) -> dict | None:
        """``HEX-L.json``, or None when it is missing, damaged or not a regular file (a FIFO
        would block a plain read; ``/dev/zero`` would fill the memory)."""
        try:
            data = read_json(entry.with_name(entry.name + ".json"), MANIFEST_MAX_BYTES, "store manifest")
        except (OSError, InputError):
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
        return manifest is not None and manifest.get("content_key") == key and _recorded(manifest) is not None

    def fetch(self, key: str, target: Path, png_compression: int = DEFAULT_PNG_COMPRESSION) -> bool:
        """Put a copy of ``key``'s sequence at ``target`` (staged, locked and marked as a
        rendered one is, replacing a stale sequence there); False when the store does not
        hold it (or it was evicted while being copied, or it is not what was stored): then
        render it."""
        self.evict()
        if not self.has(key, png_compression):
            log.debug("sequence store miss: %s (PNG level %d) in %s", key, png_compression, self.root)
            return False
        entry = self.entry(key, png_compression)
        assert entry is not None
        recorded = _recorded(self._manifest(entry) or {})
        with StagedOutput(target, OutputKind.SEQUENCE, overwrite=True, content_key=key) as out:
            try:
                copied: _Copied | None = _copy_tree(entry, out.path)
            except _Damaged:
                copied = None
            except OSError:
                if self.has(key, png_compression):
                    raise  # the store still holds it whole: the copy could not be written
                return False  # evicted meanwhile
            if copied != recorded or not self.has(key, png_compression):
                if self.has(key, png_compression):  # still there, so changed in place
                    self._discard(entry)
                return False  # not what was stored: render it
            out.commit()
        with contextlib.suppress(OSError):  # a read-only store is still read
            os.utime(entry)  # most recently used
        log.debug("sequence store hit: %s copied from %s to %s", key, entry, target)
        return True

    # -- writing -----------------------------------------------------------------------

    def _discard(self, entry: Path) -> None:
        """Remove an entry whose files are not what was stored, saying so once."""
        log.warning(
            "the sequence store's entry %s is not what was stored (a file in it changed); "
            "removed it, and the sequence is rendered again",
            entry,
        )
        self._remove(entry)

    def _remove(self, entry: Path) -> bool:
        """Lock, rename aside and delete an entry; False when another process holds it (is
        writing it) or it cannot be removed (then the store is read-only: warned once)."""
        lock = OutputLock(entry)
        try:
            lock.acquire()
        except OutputError:
            return False  # being written (or not writable at all: then nothing is removed)
        try:
            aside = hidden_sibling(entry, f"{_EVICTED}{uuid.uuid4().hex[:8]}")
            os.rename(entry, aside)  # readers copying it now fail, and render instead
            entry.with_name(entry.name + ".json").unlink(missing_ok=True)
            shutil.rmtree(aside, ignore_errors=True)
        except FileNotFoundError:
            pass  # removed by another process
        except OSError as exc:
            self._unusable("evict an entry", exc.strerror or str(exc))
            return False
        finally:
            lock.release()
        return True

    def _unusable(self, doing: str, reason: str) -> None:
        if self.writable and str(self.root) not in _warned:
            _warned.add(str(self.root))
            log.log(
                warning_level(),
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
            size = _measure(sequence)
            if size[0] > self.max_bytes:
                return False  # it would evict everything, itself too
            # Copied again even when an entry of this key is there without its HEX-L.json:
            # its files cannot be trusted without the digest that manifest would hold.
            with StagedOutput(entry, OutputKind.SEQUENCE, overwrite=True, content_key=key) as out:
                copied = _copy_tree(sequence, out.path)
                if (copied.bytes, copied.files) != size:
                    return False  # the sequence changed while it was copied
                out.commit()
            manifest = {
                "content_key": key,
                "bytes": copied.bytes,
                "files": copied.files,
                "digest": copied.digest,
            }
            write_text_atomic(entry.with_name(entry.name + ".json"), json.dumps(manifest) + "\n")
            log.debug("sequence store stored: %s (%d bytes, %d files) at %s", key, *size, entry)
        except _Damaged:
            return False  # a link or a FIFO in the sequence: not one the store takes
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
            if not self._remove(item.path):
                if not self.writable:
                    break
                continue  # being written by another process
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


def _recorded(manifest: dict) -> _Copied | None:
    """What ``HEX-L.json`` says was stored; None for one without a digest (an older
    version's, which cannot be checked: the entry is then stored again)."""
    size, files, digest = manifest.get("bytes"), manifest.get("files"), manifest.get("digest")
    if not isinstance(size, int) or not isinstance(files, int) or not isinstance(digest, str):
        return None
    return _Copied(size, files, digest)


def _copy_tree(source: Path, target: Path) -> _Copied:
    """Copy every file of ``source`` but its marker into the existing folder ``target``
    (contents only: fresh times and modes, as a rendered sequence has), hashing the bytes
    as they pass; returns what was copied."""
    total = files = 0
    tree = hashlib.sha256()
    for folder, dirs, names in os.walk(source, onerror=_raise):
        dirs.sort()
        relative = Path(folder).relative_to(source)
        (target / relative).mkdir(exist_ok=True)
        for name in sorted(names):
            if relative == Path(".") and name == MARKER_NAME:
                continue
            size, digest = _copy_file(Path(folder) / name, target / relative / name)
            tree.update(os.fsencode(relative / name) + b"\0" + str(size).encode() + b"\0" + digest)
            total += size
            files += 1
    return _Copied(total, files, tree.hexdigest())


def _copy_file(source: Path, target: Path) -> tuple[int, bytes]:
    """Copy one regular file (a link, FIFO or device is ``_Damaged``: a FIFO would block);
    returns its size and SHA-256."""
    try:
        fd = os.open(source, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise _Damaged(f"{source} is a link") from None
        raise
    with os.fdopen(fd, "rb") as reader:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise _Damaged(f"{source} is not a regular file")
        digest = hashlib.sha256()
        size = 0
        with open(target, "xb") as writer:
            while chunk := reader.read(1 << 20):
                digest.update(chunk)
                writer.write(chunk)
                size += len(chunk)
    return size, digest.digest()


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
