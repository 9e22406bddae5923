"""The sequence as a program is handed it: a private view, and a check that nothing changed.

A program gets ``{sequence}`` as a folder of its own in its scratch folder: the files at
the sequence's root (the frame lists, ``groundtruth.txt``, ``camera.yaml``, ``meta.json``)
and ``gt/objects.jsonl`` are private copies, the frames hard links to the originals (the
900 files of a 300-frame 640x480 sequence: ~90 ms; a copy would write its 150-460 MB), so
that a program writing into ``{sequence}/groundtruth.txt`` never changes what later runs
are scored against.
Permission bits would not do: CI runs as root, which ignores them.

``SequenceGuard`` then checks, after the run, that the program changed neither its view
nor the original (reached through a link or by its absolute path): the text files by
content (a same-size edit in place is seen), the frames by inode, size and modification
time: ~45 ms before the run and ~15 ms after it on that sequence, where hashing every file
took 1.4 s (a program that edits a frame in place and sets its mtime back is not seen;
one that writes a file is). A run that changed anything fails, naming the file.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from depotbench.core.errors import InputError
from depotbench.core.files import file_digest
from depotbench.sim.sequence import TEXT_FILES, Sequence

CONTENT_CHECKED = (*TEXT_FILES, "gt/objects.jsonl")
"""The files compared by content: small (a 300-frame sequence's are ~0.5 MB together), and
what scores a run (the ground truth) or feeds it (lists, camera)."""


def view_of(sequence: Sequence, into: Path) -> Path:
    """A view of ``sequence`` at ``into`` (made here): the files at its root and those read
    by content (``CONTENT_CHECKED``) copied, the frames hard-linked (copied where the scratch
    folder is on another file system), links kept as links. Real folders, not links to the
    originals: the sequence reader refuses a frame that a link leads out of its folder."""
    root = sequence.root
    for folder, dirs, names in os.walk(root):
        here = Path(folder)
        relative = here.relative_to(root)
        (into / relative).mkdir(parents=True, exist_ok=True)
        for name in [*names, *(d for d in dirs if (here / d).is_symlink())]:
            source, target = here / name, into / relative / name
            if source.is_symlink():
                target.symlink_to(os.readlink(source))
            elif relative == Path(".") or (relative / name).as_posix() in CONTENT_CHECKED:
                shutil.copyfile(source, target)
            else:
                _link_or_copy(source, target)
    return into


def _link_or_copy(source: Path, target: Path) -> None:
    try:
        os.link(source, target)
    except OSError:  # another file system, or one without hard links: a copy reads the same
        shutil.copyfile(source, target)


def _digest(path: Path) -> bytes | None:
    """SHA-256 of a regular file; None for one that is gone or is not a regular file (a FIFO
    put in its place is refused without blocking, and counts as a change)."""
    try:
        return file_digest(path, "sequence file")
    except (OSError, InputError):
        return None


def _stat(path: Path) -> tuple[int, int, int] | None:
    try:
        info = path.stat()
    except OSError:
        return None
    return (info.st_ino, info.st_size, info.st_mtime_ns)


@dataclass(frozen=True)
class SequenceGuard:
    """What a sequence and the folder handed for it held before a program ran."""

    root: Path
    handed: Path
    contents: dict[str, bytes | None]
    """Digests of the original's text files, by name relative to its root."""
    stats: dict[str, tuple[int, int, int] | None]
    """(inode, size, mtime) of the original's other files (frames, instance masks, flow)."""
    copies: dict[str, bytes | None]
    """Digests of the handed folder's private copies (its root files, ``gt/objects.jsonl``),
    where it is not the original."""

    @classmethod
    def before(cls, sequence: Sequence, handed: Path) -> SequenceGuard:
        root = sequence.root
        contents: dict[str, bytes | None] = {}
        stats: dict[str, tuple[int, int, int] | None] = {}
        for path in sequence.files():
            name = path.relative_to(root).as_posix()
            if name in CONTENT_CHECKED:
                contents[name] = _digest(path)
            else:
                stats[name] = _stat(path)
        copies: dict[str, bytes | None] = {}
        if handed.resolve() != root.resolve():
            with os.scandir(handed) as entries:
                names = [entry.name for entry in entries if entry.is_file(follow_symlinks=False)]
            for name in [*names, *(n for n in CONTENT_CHECKED if "/" in n and (handed / n).is_file())]:
                copies[name] = _digest(handed / name)
        return cls(root, handed, contents, stats, copies)

    def change(self, what: str) -> str | None:
        """The reason a run that changed a file fails (naming the file), or None."""
        for name, stat in self.stats.items():
            if _stat(self.root / name) != stat:
                return self._original(what, name)
        for name, digest in self.contents.items():
            if _digest(self.root / name) != digest:
                return self._original(what, name)
        for name, digest in self.copies.items():
            if _digest(self.handed / name) != digest:
                return (
                    f"{what}: changed {name} of the sequence it was handed (a program may only read "
                    "{sequence}; the sequence itself is unchanged)"
                )
        return None

    def _original(self, what: str, name: str) -> str:
        return (
            f"{what}: changed {self.root / name} (a program may only read its sequence); "
            "restore the file: runs on the sequence are scored against it"
        )
