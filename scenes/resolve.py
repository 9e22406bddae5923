"""A scenario named as users name it (a library name, a YAML file, or ``default``) turned
into the simulator's typed spec, with top-level fields changed and checked against the
schema's limits: what ``depotbench generate`` and ``depotbench.generate`` both take."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from depotbench.scenes import library
from depotbench.scenes.schema import Scenario, check_option, load_scenario, to_scenario
from depotbench.sim.spec import ScenarioSpec, default_scenario

DEFAULT = "default"
"""The built-in default scenario's name (two walkers, a seated person, a dog, chairs)."""


def scenario_model(spec: str | Path) -> Scenario:
    """The validated scenario of a library name or a file (.yaml, .yml, .json, or any path that exists)."""
    path = Path(spec)
    if path.suffix in (".yaml", ".yml", ".json") or path.exists():
        return load_scenario(path)
    return library.get(str(spec))


def resolve(spec: str | Path, changes: dict[str, Any] | None = None, option: str = "--") -> ScenarioSpec:
    """The simulator spec of ``spec`` with ``changes`` (``seed``, ``frames``, ``flow``, ...)
    applied, each checked as the schema checks that field; ``option`` prefixes a field's name
    in messages (``--seed`` on the command line)."""
    base = default_scenario() if str(spec) == DEFAULT else to_scenario(scenario_model(spec))
    checked = {}
    for name, value in (changes or {}).items():
        if name in Scenario.model_fields:
            checked[name] = check_option(name, value, f"{option}{name}")
        elif name in {f.name for f in dataclasses.fields(ScenarioSpec)}:
            checked[name] = value
        else:
            raise library.SpecError(f"{option}{name}: not a field of a scenario")
    try:
        return dataclasses.replace(base, **checked)
    except (TypeError, ValueError) as exc:
        raise library.SpecError(f"{spec}: {exc}") from None
