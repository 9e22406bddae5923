"""A spec's mistake in a union field is one line naming the value (probe N29).

Pydantic reports every alternative of a union, each under a validator's name: ``grid:
[.nan]`` gave five lines, four of them ``function-after[_steps(), Range].grid: unknown
field`` or ``Random.random: Field required``; a tracker's ``env: {A=B: 1}`` two (the
entry is not a ``str`` either). ``--set n_features=1e12`` said "is not a number".
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.run.harness import slam_config
from depotbench.scenes.schema import Strict, relevant_errors
from depotbench.slam.config import ConfigError, parse_setting
from pydantic import ValidationError

SPECS = {
    "grid": (
        "strategies: [box_rule]\nthresholds:\n  box_rule:\n    k: {grid: [.nan]}\n",
        "thresholds.box_rule.k.grid.0: Input should be a finite number (got nan)",
    ),
    "env": (
        "trackers:\n  - name: mine\n    command: ./prog {sequence}\n    env: {A=B: 1}\n",
        "trackers.0.env: 'A=B' is not an environment variable name",  # the value 1 is fine
    ),
    "range": (
        "strategies: [box_rule]\nthresholds:\n  box_rule:\n    k: {range: [1, 2]}\n",
        "thresholds.box_rule.k.range.2: Field required",  # the third of [start, stop, step]
    ),
}


@pytest.mark.parametrize("name", sorted(SPECS))
def test_a_mistake_in_a_union_field_is_one_line_naming_the_value(name: str, tmp_path: Path, capsys):
    text, expected = SPECS[name]
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"sweep: s\nsequences: [x]\n{text}")
    assert main(["validate", str(spec)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert re.search(rf"spec\.yaml:\d+: {re.escape(expected)}$", err[0]), err  # FILE:LINE: field


class _Grid(Strict):
    grid: list[float]


class _Range(Strict):
    range: tuple[float, float, float]


class _Spec(Strict):
    axis: _Grid | _Range
    name: str
    value: int | str


def test_only_the_nearest_alternative_is_kept_and_other_fields_keep_their_errors():
    """Closed case: the axis reads as a Grid (its error at grid.0 is deeper than the
    Range's missing field), the plain field keeps its error, and a union whose alternatives
    fail equally deep keeps its first alternative's."""
    with pytest.raises(ValidationError) as caught:
        _Spec.model_validate({"axis": {"grid": ["x"]}, "name": 3, "value": [1]})
    kept = [(".".join(str(p) for p in e["loc"]), e["type"]) for e in relevant_errors(caught.value.errors())]
    assert kept == [("axis.grid.0", "float_parsing"), ("name", "string_type"), ("value", "int_type")]


def test_a_whole_number_setting_written_with_an_exponent_is_a_number():
    assert parse_setting("n_features", "1e12") == 10**12 and parse_setting("n_features", "2e3") == 2000
    assert parse_setting("n_features", "1000") == 1000
    with pytest.raises(ConfigError, match="n_features='abc' is not a number"):
        parse_setting("n_features", "abc")
    with pytest.raises(ConfigError, match="n_features=8.5 must be a whole number"):
        parse_setting("n_features", "8.5")
    with pytest.raises(Exception, match=r"n_features = 1000000000000 is out of range \[50, 20000\]"):
        slam_config("none", {"n_features": parse_setting("n_features", "1e12")})
