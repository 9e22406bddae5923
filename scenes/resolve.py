"""A scenario named as users name it (a library name, a YAML file, or ``default``) turned
into the simulator's typed spec, with top-level fields changed and checked against the
schema's limits: what ``depotbench generate`` and ``depotbench.generate`` both take."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from depotbench.scenes import library
from depotbench.scenes.schema import Scenario, check_option, load_scenario, to_scenario, validate_model
from depotbench.scenes.suite import LENGTH_FIELDS
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
    in messages (``--seed`` on the command line).

    A scenario's fields change before its ranges are drawn: an actor's speed or scale given as
    a range is drawn from the scenario's seed (``to_scenario``), so ``--seed 301`` of
    walking_halfsphere is the sequence a suite's or a benchmark's seed 301 is (its walkers at
    0.93 and 0.99 m/s), not the file's own seed's draws under another seed."""
    model_changes: dict[str, Any] = {}
    spec_changes: dict[str, Any] = {}
    for name, value in (changes or {}).items():
        if name in Scenario.model_fields:
            model_changes[name] = check_option(name, value, f"{option}{name}")
        elif name in {f.name for f in dataclasses.fields(ScenarioSpec)}:
            spec_changes[name] = value
        else:
            raise library.SpecError(f"{option}{name}: not a field of a scenario")
    if str(spec) == DEFAULT:
        base, spec_changes = default_scenario(), model_changes | spec_changes
    else:
        model = scenario_model(spec)
        if model_changes:
            if any(model_changes.get(length) is not None for length in LENGTH_FIELDS):
                # the length set one way drops the way the file set it (frames over duration_s)
                model_changes = {length: None for length in LENGTH_FIELDS} | model_changes
            model = validate_model(Scenario, dict(model) | model_changes, str(spec))
        base = to_scenario(model)
    try:
        return dataclasses.replace(base, **spec_changes)
    except (TypeError, ValueError) as exc:
        raise library.SpecError(f"{spec}: {exc}") from None
