"""Suites: a base scenario expanded over knobs (a grid, or seeded random draws).

A suite file names a base scenario (library name or file), optional overrides,
and either ``grid`` (every combination, times every seed) or ``random`` (a count
of seeded draws). Each variation is validated as a full scenario, so an error
names the variation and the field.
"""

from __future__ import annotations

import copy
import itertools
import math
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from depotbench.scenes import library
from depotbench.scenes.schema import (
    Scenario,
    SpecError,
    Strict,
    load_model,
    parse_scenario,
    read_yaml,
)
from pydantic import Field, model_validator

MAX_VARIATIONS = 10_000
LENGTH_FIELDS = ("frames", "duration_s")
"""A scenario's length, given one way (the schema refuses both): a suite's override or knob that
sets one replaces the other that the base gave, as a user who writes ``frames: 60`` over a
10-second base means."""
Bound = Annotated[float, Field(ge=-1e12, le=1e12)]
IntBound = Annotated[int, Field(ge=-(2**53), le=2**53)]


class Draw(Strict):
    """One random knob: exactly one of ``uniform``, ``int`` (inclusive) or ``choice``."""

    uniform: tuple[Bound, Bound] | None = None
    int_range: tuple[IntBound, IntBound] | None = Field(None, alias="int")
    choice: list[Any] | None = None

    @model_validator(mode="after")
    def _one(self) -> Draw:
        given = [x for x in (self.uniform, self.int_range, self.choice) if x is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of uniform: [low, high], int: [low, high], choice: [...]")
        if self.choice is not None and not self.choice:
            raise ValueError("choice needs at least one value")
        for name, bounds in (("uniform", self.uniform), ("int", self.int_range)):
            if bounds is not None and bounds[0] > bounds[1]:
                raise ValueError(f"{name}: [low, high] needs low <= high, got {list(bounds)}")
        return self

    def sample(self, rng: np.random.Generator) -> Any:
        if self.uniform is not None:
            return round(float(rng.uniform(*self.uniform)), 6)
        if self.int_range is not None:
            return int(rng.integers(self.int_range[0], self.int_range[1] + 1))
        assert self.choice is not None
        return self.choice[int(rng.integers(len(self.choice)))]


class RandomKnobs(Strict):
    count: int = Field(ge=1, le=MAX_VARIATIONS)
    seed: int = Field(0, ge=0)
    knobs: dict[str, Draw]


class Suite(Strict):
    suite: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    description: str = ""
    base: str
    overrides: dict[str, Any] = {}
    grid: dict[str, list[Any]] = {}
    seeds: list[Annotated[int, Field(ge=0, le=2**32 - 1)]] = Field([0], min_length=1)
    random: RandomKnobs | None = None

    @model_validator(mode="after")
    def _shape(self) -> Suite:
        if self.grid and self.random is not None:
            raise ValueError("give grid or random, not both")
        if any(not values for values in self.grid.values()):
            raise ValueError("every grid knob needs at least one value")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds: {self.seeds} repeats a seed (the same sequence twice)")
        knobs = list(self.grid) + (list(self.random.knobs) if self.random else [])
        reserved_knobs = (("name", "names are the suite's, numbered"), ("seed", "list seeds in seeds:"))
        for reserved, instead in reserved_knobs:
            if reserved in knobs:
                raise ValueError(f"'{reserved}' cannot be a knob ({instead})")
        given = {name for name, value in self.overrides.items() if value is not None}  # null: unset
        drawn = {name for name, values in self.grid.items() if any(v is not None for v in values)}
        drawn |= set(self.random.knobs) if self.random else set()
        for where, names in (("overrides", given), ("knobs", drawn)):
            if set(LENGTH_FIELDS) <= names:
                raise ValueError(
                    f"{where}: give frames or duration_s, not both (either one replaces the base's length)"
                )
        return self


def set_path(data: dict[str, Any], dotted: str, value: Any, source: str) -> None:
    """Set ``a.b.0.c`` inside nested dicts and lists (list indices are integers)."""
    keys = dotted.split(".")
    node: Any = data
    for i, key in enumerate(keys):
        last = i == len(keys) - 1
        if isinstance(node, list):
            if not key.isdigit() or int(key) >= len(node):
                raise SpecError(f"{source}: knob {dotted!r}: {'.'.join(keys[:i])} has no item {key}")
            index: Any = int(key)
        elif isinstance(node, dict):
            index = key
        else:
            raise SpecError(f"{source}: knob {dotted!r}: {'.'.join(keys[:i])} is not a mapping or list")
        if last:
            node[index] = value
        else:
            if isinstance(node, dict) and key not in node:
                node[key] = {}
            node = node[index]


def set_field(data: dict[str, Any], dotted: str, value: Any, source: str) -> None:
    """``set_path``, where setting the length one way (``LENGTH_FIELDS``) drops the other way
    the scenario had it (a null, ``duration_s: null``, unsets that way alone)."""
    if dotted in LENGTH_FIELDS and value is not None:
        for other in LENGTH_FIELDS:
            if other != dotted:
                data.pop(other, None)
    set_path(data, dotted, value, source)


def _base_data(suite: Suite, suite_path: Path) -> dict[str, Any]:
    if suite.base in library.library_files():
        return read_yaml(library.library_files()[suite.base])
    path = (suite_path.parent / suite.base).resolve()
    if not path.exists():
        raise SpecError(f"{suite_path}: base {suite.base!r} is neither a library scenario nor a file")
    data = read_yaml(path)
    if "suite" in data:
        raise SpecError(f"{suite_path}: base {suite.base!r} is a suite; a suite's base is a scenario")
    return data


def count_variations(suite: Suite) -> int:
    """How many sequences the suite expands to, counted without building them."""
    if suite.random is not None:
        return suite.random.count
    return math.prod(len(values) for values in suite.grid.values()) * len(suite.seeds)


def variations(suite: Suite, suite_path: Path) -> list[tuple[str, dict[str, Any], Scenario]]:
    """Every (sequence name, knob values, validated scenario) of the suite, in a fixed order."""
    count = count_variations(suite)
    if count > MAX_VARIATIONS:
        sizes = " x ".join(str(len(v)) for v in suite.grid.values())
        raise SpecError(
            f"{suite_path}: the grid ({sizes} values x {len(suite.seeds)} seeds) makes {count} "
            f"sequences, more than the limit of {MAX_VARIATIONS}"
        )
    base = _base_data(suite, suite_path)
    for key, value in suite.overrides.items():
        set_field(base, key, value, str(suite_path))
    if suite.random is not None:
        rng = np.random.default_rng(suite.random.seed)
        draws = [{k: d.sample(rng) for k, d in suite.random.knobs.items()} for _ in range(suite.random.count)]
        knob_sets = [{**d, "seed": int(base.get("seed", 0)) + i} for i, d in enumerate(draws)]
    else:
        keys = list(suite.grid)
        combos = itertools.product(*(suite.grid[k] for k in keys))
        knob_sets = [
            {**dict(zip(keys, combo, strict=True)), "seed": seed} for combo in combos for seed in suite.seeds
        ]
    result = []
    for i, knobs in enumerate(knob_sets):
        data = copy.deepcopy(base)
        for key, value in knobs.items():
            set_field(data, key, value, str(suite_path))
        name = f"{suite.suite}-{i:04d}"
        data["name"] = name
        result.append((name, knobs, parse_scenario(data, f"{suite_path} (variation {name})")))
    return result


def load_suite(path: Path) -> Suite:
    return load_model(Suite, path)


def is_suite_file(path: Path) -> bool:
    return "suite" in read_yaml(path)
