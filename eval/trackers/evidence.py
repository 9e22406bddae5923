"""What a failed program run leaves for its author: how it was started and what it wrote.

The scratch folder a program runs in goes with the run; before it goes, a failed run's
files are read into an ``Evidence`` (bounded: ``KEEP_MAX_BYTES`` in all), which travels
with the ``TrackerError`` (from a worker process too) to whoever writes the run's folder:
``depotbench run`` its ``-o`` folder, a sweep ``failures/<key>/``. ``write_evidence``
lays it out:

``failure.json``  the reason, argv (JSON), the same as one shell-quoted line, the
                  environment variables the bench set, the files kept and those skipped
``program.log``   the end of the program's standard output and error
``scratch/``      the program's scratch folder as it was: the rendered settings, the
                  parameters and detections it was handed, what it wrote
"""

from __future__ import annotations

import json
import os
import shlex
import stat
from dataclasses import dataclass, field
from pathlib import Path

from depotbench.core.errors import InputError
from depotbench.core.files import open_regular

KEEP_MAX_BYTES = 64 << 20
"""What a failed run keeps of its scratch folder, in all: 64 MiB (a keypoint file of a long
sequence fits; a program that wrote gigabytes keeps the list of what it wrote)."""
KEEP_MAX_FILES = 1000
SKIPPED_LISTED = 100
"""Skipped files named in failure.json; the rest are counted."""
BENCH_FOLDERS = {"view": "the sequence as handed (a view of it)", "masked": "the masked frames"}
"""Scratch folders of the bench's own making, left out: the sequence's frames, which the
bench writes again from the sequence and the mask settings."""


@dataclass(frozen=True)
class Evidence:
    """A failed run's command, environment and scratch files."""

    argv: tuple[str, ...]
    environment: tuple[tuple[str, str], ...]
    """The variables the bench set for the program (``DEPOTBENCH_*``, the tracker's ``env``)."""
    files: tuple[tuple[str, bytes], ...] = ()
    """Scratch files by path relative to the scratch folder, with their bytes."""
    skipped: tuple[tuple[str, str], ...] = ()
    """Scratch files not kept, with why (at most ``SKIPPED_LISTED``)."""
    skipped_count: int = 0
    extra: dict[str, object] = field(default_factory=dict)
    """More to record in failure.json (the run's identity, say)."""


def collect(scratch: Path, argv: list[str], environment: dict[str, str]) -> Evidence:
    """The scratch folder's regular files (up to ``KEEP_MAX_BYTES`` and ``KEEP_MAX_FILES``),
    smallest first so that a huge output does not push out the settings; links, pipes and
    what is over the bounds are listed as skipped, never followed or read."""
    found: list[tuple[int, str, Path]] = []
    skipped: list[tuple[str, str]] = []
    for folder, dirs, names in os.walk(scratch):
        here = Path(folder)
        if here == scratch:
            for name in sorted(set(dirs) & set(BENCH_FOLDERS)):
                skipped.append((name + "/", BENCH_FOLDERS[name]))
                dirs.remove(name)
        dirs.sort()
        for name in sorted(names):
            path = here / name
            relative = path.relative_to(scratch).as_posix()
            try:
                info = path.lstat()
            except OSError as exc:
                skipped.append((relative, f"cannot be read ({exc.strerror})"))
                continue
            if not stat.S_ISREG(info.st_mode):
                skipped.append((relative, "not a regular file"))
                continue
            found.append((info.st_size, relative, path))
    files: list[tuple[str, bytes]] = []
    total = 0
    for size, relative, path in sorted(found):
        if len(files) >= KEEP_MAX_FILES or total + size > KEEP_MAX_BYTES:
            skipped.append((relative, f"{size} bytes, past the bound of what is kept"))
            continue
        try:
            fd = open_regular(path, KEEP_MAX_BYTES - total, "scratch file")
            with os.fdopen(fd, "rb") as handle:
                data = handle.read(KEEP_MAX_BYTES - total + 1)
        except (OSError, InputError) as exc:
            skipped.append((relative, f"cannot be read ({exc})"))
            continue
        if len(data) > KEEP_MAX_BYTES - total:  # it grew while read
            skipped.append((relative, "grew past the bound of what is kept"))
            continue
        files.append((relative, data))
        total += len(data)
    skipped.sort()
    return Evidence(
        tuple(argv),
        tuple(sorted(environment.items())),
        tuple(sorted(files)),
        tuple(skipped[:SKIPPED_LISTED]),
        len(skipped),
    )


def write_evidence(folder: Path, reason: str, log: str, evidence: Evidence | None) -> None:
    """failure.json, program.log and scratch/ into ``folder`` (made by the caller)."""
    facts: dict[str, object] = {"reason": reason}
    if evidence is not None:
        facts |= {
            "argv": list(evidence.argv),
            "command": shlex.join(evidence.argv),
            "environment": dict(evidence.environment),
            "kept": [name for name, _ in evidence.files],
            "skipped": [{"file": name, "why": why} for name, why in evidence.skipped],
            "skipped_count": evidence.skipped_count,
            **evidence.extra,
        }
        for name, data in evidence.files:
            target = folder / "scratch" / name
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
    (folder / "failure.json").write_text(json.dumps(facts, indent=2, default=str) + "\n", encoding="utf-8")
    (folder / "program.log").write_text(log or "(the program printed nothing)\n", encoding="utf-8")
