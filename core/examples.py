"""The examples depotbench ships, by name: sweep specs, gate files, suites and example
trackers, found as the scenario library's scenarios are (``depotbench sweep smallest``)
and copied into a user's folder (``depotbench examples copy``).

A name is a file's stem, unique across every shelf (a test holds it so). A path that
exists always wins over a name, so a user's own ``smallest`` folder or file is never
shadowed by the shipped one. An example's kind is read from the file as ``depotbench
validate`` reads it (the one top-level key each kind has), so a suite kept beside the
sweep specs that use it is listed as a suite.
"""

from __future__ import annotations

import ast
import difflib
import functools
import os
import shlex
import stat
from dataclasses import dataclass
from enum import StrEnum
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from depotbench.core.errors import FileError, InputError
from depotbench.core.files import MAX_SPEC_BYTES, read_text
from depotbench.core.output import write_bytes_atomic


class Kind(StrEnum):
    SWEEP = "sweep spec"
    GATES = "gate file"
    SUITE = "suite"
    TRACKER = "example tracker"
    TRAJECTORY = "trajectory"
    BENCHMARK = "benchmark"


KEYS: dict[str, Kind] = {
    "sweep": Kind.SWEEP,
    "gates": Kind.GATES,
    "suite": Kind.SUITE,
    "benchmark": Kind.BENCHMARK,
}
"""The top-level key that marks a YAML file's kind (a gate file's matrix is under ``run``)."""


@dataclass(frozen=True)
class Shelf:
    """A folder of shipped files: a package's data folder and the files it holds."""

    package: str
    folder: str
    pattern: str


SHELVES: tuple[Shelf, ...] = (
    Shelf("depotbench.assets", "sweeps", "*.yaml"),
    Shelf("depotbench.assets", "gates", "*.yaml"),
    Shelf("depotbench.scenes", "suites", "*.yaml"),  # the scenes' suites: data only, no code imported
    Shelf("depotbench.assets", "examples/external", "*.py"),
    Shelf("depotbench.assets", "examples", "*.txt"),
    Shelf("depotbench.assets", "benchmarks", "*.yaml"),  # each with its lock, NAME.lock.json
)


@dataclass(frozen=True)
class Example:
    """One shipped file: its name (the stem), kind, place and one-line description."""

    name: str
    kind: Kind
    path: Path
    description: str

    def to_dict(self) -> dict[str, str]:
        return {"name": self.name, "kind": self.kind.value, "description": self.description}


def _shelf_folder(shelf: Shelf) -> Path:
    return Path(str(resources.files(shelf.package).joinpath(*shelf.folder.split("/"))))


def _first_sentence(text: str) -> str:
    """A description on one line: its first sentence (the listing is one line per example)."""
    flat = " ".join(text.split())
    head, dot, _ = flat.partition(". ")
    return head + ("." if dot else "")


def _yaml_data(path: Path) -> dict[str, Any]:
    data = yaml.safe_load(read_text(path, MAX_SPEC_BYTES, "YAML file"))
    if not isinstance(data, dict):
        raise FileError(path, None, "is not a YAML mapping")
    return data


def _first_comment(text: str) -> str:
    for line in text.splitlines():
        if line.startswith("#") and not line.startswith("#!"):
            return line.lstrip("# ").strip()
    return ""


def _trajectory(text: str) -> str:
    """A TUM trajectory's own words say little (evo's test data keeps the recorder's header),
    so its description is what it holds: poses and the time they span."""
    stamps = [float(line.split()[0]) for line in text.splitlines() if line.strip() and line[0] != "#"]
    span = f" over {stamps[-1] - stamps[0]:.1f} s" if stamps else ""
    return f"A TUM trajectory: {len(stamps)} poses{span}."


def _read(path: Path) -> tuple[Kind, str]:
    text = read_text(path, MAX_SPEC_BYTES, "example")
    if path.suffix == ".txt":
        return Kind.TRAJECTORY, _trajectory(text)
    if path.suffix == ".py":
        doc = ast.get_docstring(ast.parse(text, filename=str(path))) or ""
        return Kind.TRACKER, (doc.strip().splitlines() or [_first_comment(text)])[0]
    data = _yaml_data(path)
    kind = next((k for key, k in KEYS.items() if key in data), None)
    if kind is None:
        raise FileError(path, None, f"a shipped example needs one of {', '.join(KEYS)} at its top level")
    description = data.get("description")
    return kind, _first_sentence(description) if isinstance(description, str) else _first_comment(text)


@functools.cache
def examples() -> dict[str, Example]:
    """Every shipped example by name, by kind (sweep specs, gate files, suites, trackers) and name."""
    found: dict[str, Example] = {}
    for shelf in SHELVES:
        for path in sorted(_shelf_folder(shelf).glob(shelf.pattern)):
            if path.stem in found:  # a packaging mistake of ours, not the user's
                raise RuntimeError(
                    f"two shipped examples are named {path.stem!r}: {found[path.stem].path}, {path}"
                )
            kind, description = _read(path)
            found[path.stem] = Example(path.stem, kind, path, description)
    order = list(Kind)
    return dict(sorted(found.items(), key=lambda item: (order.index(item[1].kind), item[0])))


def _unknown(name: str, kind: Kind) -> str:
    of_kind = [e.name for e in examples().values() if e.kind is kind]
    other = examples().get(name)
    if other is not None:
        return f"{name}: a shipped {other.kind}, not a {kind}; shipped {kind}s: {', '.join(of_kind)}"
    return f"{name}: no such file, nor a shipped {kind}; {hint(Path(name).stem, of_kind)}"


def reads_as_path(text: str) -> bool:
    """A folder or a suffix: a path, never a name (no shipped name holds either)."""
    return "/" in text or bool(Path(text).suffix)


def hint(name: str, known: list[str], lister: str = "depotbench examples lists them all") -> str:
    """The close names, or every name where none is close (a kind has a handful)."""
    close = difflib.get_close_matches(name, known, n=3, cutoff=0.6)
    if close:
        return f"did you mean {' or '.join(close)}? ({lister})"
    return f"known: {', '.join(known)}" if known else "none ships"


def find(text: str | Path, kind: Kind) -> Path:
    """The file ``text`` names: the path itself where it exists or where it reads as a path
    (a folder or a suffix: its reader says what is wrong with it), else the shipped example
    of that name and kind; anything else is one line with the close names."""
    path = Path(text)
    if path.exists() or reads_as_path(str(text)):
        return path
    example = examples().get(str(text))
    if example is not None and example.kind is kind:
        return example.path
    raise InputError(_unknown(str(text), kind))


def named(text: str, kind: Kind) -> Path | None:
    """The shipped example ``text`` names if it is one of ``kind`` (no file is consulted)."""
    example = examples().get(text)
    return example.path if example is not None and example.kind is kind else None


def _references(data: dict[str, Any]) -> list[str]:
    """The relative file names a sweep spec, gate file or suite holds: its suite, its
    sequences, its base scenario, and each tracker's program (a word with a slash, as the
    sweep runs it) and settings template."""
    matrix = data.get("run") if isinstance(data.get("run"), dict) else data
    names = [matrix.get("suite"), data.get("base"), *(matrix.get("sequences") or [])]
    if "benchmark" in data:  # its lock, NAME-VERSION.lock.json (eval/benchmark/spec.py)
        names.append(f"{data['benchmark']}-{data.get('version')}.lock.json")
    for tracker in matrix.get("trackers") or []:
        if not isinstance(tracker, dict):
            continue
        names.append(tracker.get("settings"))
        try:
            words = shlex.split(str(tracker.get("command") or ""))
        except ValueError:
            words = []
        if words and "/" in words[0]:
            names.append(words[0])
    return [n for n in names if isinstance(n, str)]


def companions(path: Path) -> list[Path]:
    """The files an example reads by a relative name that lie beside it or below its folder
    (a sweep spec's suite file, a tracker's program), found again in each of them: copied with
    it, they keep the spec working from its new folder. A name that is not such a file (a
    library scenario, a shipped suite's name) needs no copy."""
    folder, seen, todo = path.parent.resolve(), [path], [path]
    while todo:
        current = todo.pop()
        if current.suffix not in (".yaml", ".yml"):
            continue
        for name in _references(_yaml_data(current)):
            target = (current.parent / name).resolve()
            if Path(name).is_absolute() or not target.is_file() or not target.is_relative_to(folder):
                continue
            if target not in seen:
                seen.append(target)
                todo.append(target)
    return seen[1:]


def copy_plan(names: list[str], folder: Path) -> dict[Path, Path]:
    """Each file to write in ``folder`` and its source: the examples named and their
    companions, at their place relative to the example."""
    plan: dict[Path, Path] = {}
    for name in names:
        example = examples().get(name)
        if example is None:
            close = difflib.get_close_matches(name, list(examples()), n=3, cutoff=0.6)
            hint = f"did you mean {' or '.join(close)}? " if close else ""
            raise InputError(f"{name}: no shipped example of that name; {hint}depotbench examples lists them")
        base = example.path.parent.resolve()
        for source in (example.path.resolve(), *companions(example.path)):
            plan.setdefault(folder / source.relative_to(base), source)
    return plan


def copy_examples(names: list[str], folder: Path, *, overwrite: bool = False) -> list[Path]:
    """The examples named (and their companions) copied into ``folder``, made if missing;
    nothing is written when any file is already there, unless ``overwrite``. A program
    (a file starting with ``#!``) is made executable, as a sweep runs it by its path."""
    plan = copy_plan(names, folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    for target in plan:
        if target.is_dir():
            raise InputError(f"{target}: is a folder; give another folder to copy into")
        if target.exists() and not overwrite:
            raise InputError(f"{target}: exists; --overwrite replaces it")
    written = []
    for target, source in plan.items():
        data = source.read_bytes()
        target.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(target, data)
        if data.startswith(b"#!"):
            mode = os.stat(target).st_mode
            os.chmod(target, mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
        written.append(target)
    return written
