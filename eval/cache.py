"""A disk cache for stages that do not depend on the swept thresholds.

Entries are files named by a content hash of everything their value depends on
(the caller makes the key), written atomically, so readers see a whole entry or
none and concurrent writers of one key write the same bytes. Reading an entry
marks it used (its mtime); when the cache grows past its bound the least
recently used entries go. ``DEPOTBENCH_CACHE_DIR`` moves it (default
``~/.cache/depotbench/stages``), ``DEPOTBENCH_CACHE_MAX_BYTES`` bounds it
(default 2 GiB), and ``DEPOTBENCH_CACHE=off`` turns it off.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from pathlib import Path

from sim.output import write_bytes_atomic

DEFAULT_MAX_BYTES = 2 << 30


def default_root() -> Path:
    env = os.environ.get("DEPOTBENCH_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "depotbench" / "stages"


def content_hash(*parts: object) -> str:
    """A stable key of JSON-able parts."""
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:32]


class StageCache:
    def __init__(self, root: Path | None = None, max_bytes: int | None = None) -> None:
        self.root = root or default_root()
        env = os.environ.get("DEPOTBENCH_CACHE_MAX_BYTES")
        self.max_bytes = max_bytes if max_bytes is not None else int(env) if env else DEFAULT_MAX_BYTES
        self.hits = 0
        self.misses = 0

    @classmethod
    def from_env(cls) -> StageCache | None:
        """The default cache, or None when ``DEPOTBENCH_CACHE=off``."""
        if os.environ.get("DEPOTBENCH_CACHE", "").lower() in ("off", "0", "no", "false"):
            return None
        return cls()

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
        with contextlib.suppress(OSError):  # evicted meanwhile: the bytes read are still whole
            os.utime(path)  # most recently used
        self.hits += 1
        return data

    def put(self, stage: str, key: str, data: bytes) -> None:
        path = self._path(stage, key)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, data)
        self.evict()

    def entries(self) -> list[tuple[float, int, Path]]:
        """(mtime, size, path) of every entry, oldest first."""
        out = []
        if not self.root.is_dir():
            return out
        for stage in self.root.iterdir():
            if not stage.is_dir():
                continue
            for entry in stage.iterdir():
                if entry.name.startswith("."):
                    continue  # a writer's temporary file
                try:
                    st = entry.stat()
                except FileNotFoundError:
                    continue
                out.append((st.st_mtime, st.st_size, entry))
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
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
            total -= size
            removed += 1
        return removed
