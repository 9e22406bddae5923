"""The named scenario library: YAML files in scenes/library, found by name or tag."""

from __future__ import annotations

from pathlib import Path

from depotbench.scenes.schema import Scenario, SpecError, load_scenario

LIBRARY_DIR = Path(__file__).resolve().parent / "library"


def library_files() -> dict[str, Path]:
    return {p.stem: p for p in sorted(LIBRARY_DIR.glob("*.yaml"))}


def names(tag: str | None = None) -> list[str]:
    """Library scenario names, optionally only those carrying ``tag``."""
    if tag is None:
        return list(library_files())
    return [name for name, path in library_files().items() if tag in load_scenario(path).tags]


def get(name: str) -> Scenario:
    files = library_files()
    if name not in files:
        raise SpecError(f"no library scenario named {name!r}; known: {', '.join(files)}")
    scenario = load_scenario(files[name])
    if scenario.name != name:
        raise SpecError(f"{files[name]}: name {scenario.name!r} differs from the file name")
    return scenario
