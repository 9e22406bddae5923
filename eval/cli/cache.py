"""``depotbench cache``: where the caches are, what they hold, and clearing them.

Clearing deletes only what the caches themselves wrote, recognised by name: stage entries
(``stages/STAGE/`` + 32 hexadecimal digits), stored sequences (``sequences/`` + a
SHA-256 digest and a PNG level, each with its ``.json``) and vocabularies
(``vocabulary/orb-kK-LL-`` + 16 digits + ``.txt``). A cache variable set by mistake to a
folder of one's own (``DEPOTBENCH_CACHE=$HOME``) costs no file of it, and no folder is
removed. Clearing is safe beside a running bench: a stage entry being read stays whole
for its reader, a sequence being stored is locked and kept, one being copied out is
noticed by its reader, who renders it instead.
"""

from __future__ import annotations

import argparse
import os
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from depotbench.core.cache_home import CACHES, ROOT_VARIABLE, Contents
from depotbench.eval.cli.conventions import add_json, add_verbosity, add_version, print_result


def add_cache(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "cache",
        help="show or clear the caches (stages, sequences, vocabularies): where, how big, bounds",
    )
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    info = actions.add_parser(
        "info",
        help="each cache's folder, size, entries and bound, or that it is off",
        description="Print each cache's folder, size, entries and bound, or which variable switches "
        "it off. Nothing is created or changed.",
        epilog="examples:\n  depotbench cache info\n  depotbench cache info --json",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    info.add_argument("--json", action="store_true", help="print JSON instead of text")
    info.set_defaults(handler=_cmd_info)
    clear = actions.add_parser(
        "clear",
        help="delete what the caches hold (all of them, or those named) and say what it freed",
        description="Delete the entries of every cache, or of those named. Only files the caches "
        "wrote are deleted, recognised by their names, and no folder; entries being written by "
        "another depotbench are kept.",
        epilog="examples:\n  depotbench cache clear\n  depotbench cache clear --stage --sequences",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    clear.add_argument("--stage", "--stages", dest="stages", action="store_true", help="the stage cache")
    clear.add_argument("--sequences", action="store_true", help="the stored sequences")
    clear.add_argument("--vocabulary", action="store_true", help="the ORB vocabularies")
    add_json(clear, "each cache's folder, entries and bytes removed, and what was kept or skipped")
    clear.set_defaults(handler=_cmd_clear)
    for child in (info, clear):
        add_verbosity(child, top=False)
        add_version(child)


@dataclass(frozen=True)
class _Handling:
    """How ``info`` measures a cache's folder and ``clear`` empties it (its entries, bytes);
    ``clear`` also says what it kept because another process is writing it."""

    contents: Callable[[Path], Contents]
    clear: Callable[[Path], tuple[Contents, int]]


def _stage_contents(folder: Path) -> Contents:
    from depotbench.eval.run.cache import StageCache

    entries = StageCache(folder).entries()
    return Contents(len(entries), sum(size for _, size, _ in entries))


def _stage_clear(folder: Path) -> tuple[Contents, int]:
    from depotbench.eval.run.cache import StageCache

    return StageCache(folder).clear(), 0


def _sequence_contents(folder: Path) -> Contents:
    from depotbench.scenes.store import SequenceStore

    entries = SequenceStore(folder).entries()
    return Contents(len(entries), sum(e.bytes for e in entries))


def _sequence_clear(folder: Path) -> tuple[Contents, int]:
    """The store's own eviction with a bound below any entry: locked, renamed aside, then
    removed, as eviction always is; an entry another process is writing stays."""
    from depotbench.scenes.store import SequenceStore

    store = SequenceStore(folder, max_bytes=-1)
    before = {e.path: e.bytes for e in store.entries()}
    store.evict()
    after = {e.path for e in store.entries()}
    gone = [size for path, size in before.items() if path not in after]
    return Contents(len(gone), sum(gone)), len(before) - len(gone)


def _vocabulary_contents(folder: Path) -> Contents:
    from depotbench.eval.trackers.vocabulary import cached_files

    files = cached_files(folder)
    return Contents(len(files), sum(_size(p) for p in files))


def _vocabulary_clear(folder: Path) -> tuple[Contents, int]:
    from depotbench.eval.trackers.vocabulary import clear_cached

    return clear_cached(folder), 0


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0  # removed by another process meanwhile


HANDLING: dict[str, _Handling] = {
    "stages": _Handling(_stage_contents, _stage_clear),
    "sequences": _Handling(_sequence_contents, _sequence_clear),
    "vocabulary": _Handling(_vocabulary_contents, _vocabulary_clear),
}
"""One entry per cache of ``depotbench.core.cache_home.CACHES`` (a test holds them equal)."""


def _not_a_folder(folder: Path) -> str | None:
    """Why a cache's folder cannot hold the cache (a file is there, or above it), or None.
    Such a cache is shown and left alone, each one alike: the caches only save time, and the
    bench runs without them (each warns once when used)."""
    try:
        info = os.stat(folder)
    except FileNotFoundError:
        return None  # made when first written
    except NotADirectoryError:
        return f"not a folder: a file is in the way above {folder}"
    except OSError as exc:
        return f"not a folder that can be read: {folder}: {exc.strerror or exc}"
    return None if stat.S_ISDIR(info.st_mode) else f"not a folder: {folder} is a file"


def _root_origin() -> str:
    """Which setting gives the cache root, for ``info``."""
    if os.environ.get(ROOT_VARIABLE, "").strip():
        return f"{ROOT_VARIABLE}={os.environ[ROOT_VARIABLE]!r}"
    if os.path.isabs(os.environ.get("XDG_CACHE_HOME", "")):
        return "$XDG_CACHE_HOME/depotbench"
    return "~/.cache/depotbench"


def bytes_text(size: int) -> str:
    """``1.5 GiB``: units of 1024, as the bounds are read."""
    value = float(size)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if value < 1024:
            return f"{size} B" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1024
    return f"{value:.1f} TiB"


def _state() -> dict:
    """Every cache's settings and contents (what ``info`` prints)."""
    from depotbench.core.cache_home import settings

    now = settings()
    caches = {}
    for name, cache in CACHES.items():
        folder = now.folders[name]
        problem = None if folder is None else _not_a_folder(folder)
        usable = folder is not None and problem is None
        contents = HANDLING[name].contents(folder) if usable else Contents(0, 0)
        caches[name] = {
            "holds": cache.holds,
            "location": None if folder is None else str(folder),
            "off": folder is None,
            "switched_off_by": now.off_by[name],
            "variable": cache.variable,
            "entries": contents.entries,
            "bytes": contents.bytes,
            "bound_bytes": now.bounds[name],
            "bound_variable": cache.bound_variable,
            "problem": problem,
        }
    root = None if now.root is None else str(now.root)
    return {"root": root, "root_from": _root_origin(), "caches": caches}


def _cmd_info(args: argparse.Namespace) -> int:
    from depotbench.core.files import dumps_json

    state = _state()
    if args.json:
        print(dumps_json(state))
        return 0
    root = state["root"] or "off"
    print(f"cache root: {root} ({state['root_from']})")
    for name, cache in state["caches"].items():
        print(f"{name}: {cache['holds']}")
        if cache["off"]:
            print(f"  off ({cache['switched_off_by']})")
            continue
        entries = cache["entries"]
        bound = cache["bound_bytes"]
        limit = "unbounded" if bound is None else f"bound {bytes_text(bound)} ({cache['bound_variable']})"
        print(f"  location: {cache['location']}")
        if cache["problem"]:
            print(f"  {cache['problem']}; the cache is not used")
            continue
        print(
            f"  size: {bytes_text(cache['bytes'])} in {entries} entr{'y' if entries == 1 else 'ies'}, {limit}"
        )
    return 0


def _cmd_clear(args: argparse.Namespace) -> int:
    from depotbench.core.cache_home import settings

    now = settings()  # every setting read before any file goes
    named = [name for name in CACHES if getattr(args, name)] or list(CACHES)
    freed_total = 0
    lines, caches = [], {}
    for name in named:
        folder = now.folders[name]
        if folder is None:
            lines.append(f"{name}: off ({now.off_by[name]}), nothing to clear")
            caches[name] = {"folder": None, "skipped": f"off ({now.off_by[name]})"}
            continue
        problem = _not_a_folder(folder)
        if problem is not None:
            lines.append(f"{name}: {problem}, nothing to clear")
            caches[name] = {"folder": folder, "skipped": problem}
            continue
        freed, kept = HANDLING[name].clear(folder)
        freed_total += freed.bytes
        note = f"; kept {kept} being written by another depotbench" if kept else ""
        lines.append(
            f"{name}: removed {freed.entries} entries, {bytes_text(freed.bytes)} freed ({folder}){note}"
        )
        caches[name] = {"folder": folder, "entries": freed.entries, "bytes": freed.bytes, "kept": kept}
    lines.append(f"freed {bytes_text(freed_total)}")
    print_result(args, {"caches": caches, "freed_bytes": freed_total}, "\n".join(lines))
    return 0
