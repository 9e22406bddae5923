"""What world building keeps between the worlds one process builds.

Carving a person's or an animal's meshes out of its signed-distance body and drawing the
materials' textures are a third of building a world (0.45 s a person, 0.85 s of textures
for walking_static), and each is a pure function of its inputs: the meshes of the figure's
proportions and look, the textures of their generator's state and the actors' clothes and
looks. A process that builds the same seed's world again (a suite's grid over knobs of one
seed, a sweep worker, a test process) takes them from here. A hit is exact: it returns the
arrays the first build made, read-only, and leaves the texture stream where that build
left it, so the sequence is the same bytes either way (tests/test_memo.py).

Entries are keyed by a digest of the inputs' full content (every float's bits, every
array's bytes), never by ``repr`` or identity, and bounded per kind, least recently used
first out.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
from collections import OrderedDict
from collections.abc import Callable
from typing import Any, ParamSpec, TypeVar

import numpy as np

P = ParamSpec("P")
R = TypeVar("R")


def content_key(*values: Any) -> bytes:
    """A digest of ``values``' content: equal content, equal key; anything else, another."""
    digest = hashlib.blake2b(digest_size=20)
    for value in values:
        _feed(digest, value)
    return digest.digest()


def _feed(digest: Any, value: Any) -> None:
    """Type-tagged and length-prefixed, so that no two different values feed the same bytes."""
    if value is None or isinstance(value, bool | int | str | bytes | float | enum.Enum):
        text = value.hex() if isinstance(value, float) else repr(value)
        _tagged(digest, type(value).__qualname__, text.encode())
    elif isinstance(value, np.ndarray):
        _tagged(digest, f"ndarray {value.dtype.str} {value.shape}", np.ascontiguousarray(value).tobytes())
    elif isinstance(value, np.generic):
        _feed(digest, np.asarray(value))
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        _tagged(digest, type(value).__qualname__, b"")
        fields = dataclasses.fields(value)
        _feed(digest, {f.name: getattr(value, f.name) for f in fields})
    elif isinstance(value, dict):
        _tagged(digest, "dict", str(len(value)).encode())
        for name, item in value.items():
            _feed(digest, name)
            _feed(digest, item)
    elif isinstance(value, list | tuple):
        _tagged(digest, type(value).__qualname__, str(len(value)).encode())
        for item in value:
            _feed(digest, item)
    else:
        raise TypeError(f"memo key: {type(value).__qualname__} has no content digest")


def _tagged(digest: Any, tag: str, payload: bytes) -> None:
    digest.update(f"{tag}:{len(payload)}:".encode())
    digest.update(payload)


def frozen(value: Any) -> Any:
    """``value`` with every array in it made read-only (in place), so that a user of a kept
    entry that writes into it fails at once instead of changing later worlds."""
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            frozen(getattr(value, f.name))
    elif isinstance(value, dict):
        for item in value.values():
            frozen(item)
    elif isinstance(value, list | tuple):
        for item in value:
            frozen(item)
    return value


class Memo:
    """A bounded store of results by content key, least recently used out first."""

    def __init__(self, name: str, size: int) -> None:
        self.name, self.size = name, size
        self._entries: OrderedDict[bytes, Any] = OrderedDict()
        self.hits = self.misses = 0

    def get(self, key: bytes) -> Any | None:
        entry = self._entries.get(key)
        if entry is None:
            self.misses += 1
            return None
        self._entries.move_to_end(key)
        self.hits += 1
        return entry

    def put(self, key: bytes, entry: Any) -> None:
        self._entries[key] = entry
        while len(self._entries) > self.size:
            self._entries.popitem(last=False)

    def clear(self) -> None:
        self._entries.clear()
        self.hits = self.misses = 0

    def __len__(self) -> int:
        return len(self._entries)


MEMOS: dict[str, Memo] = {}
"""Every memo by name (tests clear them, or read their counts)."""


def memo(name: str, size: int) -> Memo:
    MEMOS[name] = kept = Memo(name, size)
    return kept


def kept(name: str, size: int) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """Decorate a pure function of its arguments' content: its results are kept (frozen)."""

    def decorate(function: Callable[P, R]) -> Callable[P, R]:
        store = memo(name, size)

        @functools.wraps(function)
        def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
            key = content_key(args, kwargs)
            result = store.get(key)
            if result is None:
                result = frozen(function(*args, **kwargs))
                store.put(key, result)
            return result

        return wrapper

    return decorate
