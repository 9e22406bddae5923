"""A program's parameters swept over text and booleans as well as numbers, and ``env:``
values given as numbers and booleans (docs/external-trackers.md): what the program is
given (recorded by the program itself), what the rows store (typed JSON), what the summary
shows, and one-line errors for what a parameter cannot be.

The program is ``tests/programs/timed_slam.py`` on a 5-frame 64x48 sequence written
through the real writer (no rendering)."""

from __future__ import annotations

import csv
import json
import shlex
import sys
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.gates.budgets import Check, _same_value
from depotbench.eval.metrics.record import typed
from depotbench.eval.sweep.spec import load_sweep, tracker_configs, tracker_variants
from depotbench.eval.sweep.summary import settings_text, threshold_figures
from depotbench.scenes.schema import SpecError

from tests.conftest import REPO
from tests.sequences import write_sequence

PROGRAM = REPO / "tests" / "programs" / "timed_slam.py"
COMMAND = f"{shlex.quote(sys.executable)} {PROGRAM} {{sequence}} {{parameters}} {{trajectory}}"


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("params") / "seq"
    write_sequence(root, n=5)
    return root


def _spec(folder: Path, sequence: Path, tracker_extra: str = "", rest: str = "") -> Path:
    path = folder / "spec.yaml"
    path.write_text(
        f"sweep: typed\nsequences: [{sequence}]\nstrategies: [none]\ntrackers:\n"
        f"  - name: timed\n    command: {json.dumps(COMMAND)}\n"
        "    parameters: {mode: fast, flag: true, sleep_ms: 0}\n"
        f"{tracker_extra}{rest}"
    )
    return path


def test_a_grid_of_text_and_booleans_reaches_the_program_and_the_rows_typed(
    sequence: Path, tmp_path: Path, capsys
):
    record = tmp_path / "given.jsonl"
    spec = _spec(
        tmp_path,
        sequence,
        f"    env: {{TIMED_RECORD: {json.dumps(str(record))}, TIMED_N: 3, TIMED_ON: true, TIMED_X: 0.5}}\n",
        "parameters:\n  timed:\n    mode: {grid: [fast, accurate]}\n    flag: {grid: [true, false]}\n"
        "    sleep_ms: {grid: [0, 1]}\n",
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw"), "--workers", "1"]) == 0
    given = [json.loads(line) for line in record.read_text().splitlines() if '"sleep_ms": 0' in line]
    # The program's parameters.json holds JSON booleans and text, as the spec wrote them.
    assert sorted((g["params"]["mode"], g["params"]["flag"]) for g in given) == [
        ("accurate", False),
        ("accurate", True),
        ("fast", False),
        ("fast", True),
    ]
    # Numbers and booleans of env: reach the program as the text YAML wrote them.
    assert {k: v for k, v in given[0]["env"].items() if k != "TIMED_RECORD"} == {
        "TIMED_N": "3",
        "TIMED_ON": "true",
        "TIMED_X": "0.5",
    }
    with (tmp_path / "sw" / "results.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    stored = sorted(
        (json.loads(r["parameters"])["mode"], json.loads(r["parameters"])["flag"])
        for r in rows
        if json.loads(r["parameters"])["sleep_ms"] == 0
    )
    assert stored == [("accurate", False), ("accurate", True), ("fast", False), ("fast", True)]
    assert all(not r["failure"] for r in rows)
    best = json.loads((tmp_path / "sw" / "summary.json").read_text())["best"]["test"]
    # The figure over the numeric sleep_ms draws a line per text and boolean value, named
    # as the spec wrote them.
    configs = json.loads((tmp_path / "sw" / "summary.json").read_text())["configurations"]
    labels = {
        line.get_label()
        for _, fig in threshold_figures(configs)
        for ax in fig.axes
        for line in ax.get_lines()
    }
    assert "test / flag=true mode=fast" in labels and not any("True" in label for label in labels), labels
    flag, mode = best["parameters"]["flag"], best["parameters"]["mode"]
    assert isinstance(flag, bool) and mode in ("fast", "accurate"), best
    shown = settings_text({"flag": flag, "mode": mode})  # the swept ones, as the spec wrote them
    out = capsys.readouterr().out
    assert f"timed {shown}" in out and "flag=True" not in out and "flag=False" not in out, out


def test_parameter_text_round_trips_through_typed():
    """What a spec's value becomes for the program, and what a row reads back from it."""
    spec_values = [True, False, "fast", 3, 2.5, "True", "yes"]
    from depotbench.core.parameters import parameter_text

    texts = [parameter_text(v) for v in spec_values]
    assert texts == ["true", "false", "fast", "3", "2.5", "True", "yes"]
    assert [typed(t) for t in texts] == [True, False, "fast", 3, 2.5, "True", "yes"]
    assert settings_text({"flag": True, "mode": "fast", "k": 2.0}) == "flag=true mode=fast k=2"


def test_variants_hold_text_and_booleans_and_a_default_boolean_is_not_one(sequence: Path, tmp_path: Path):
    spec_path = _spec(tmp_path, sequence, rest="parameters:\n  timed:\n    flag: {grid: [false, true]}\n")
    spec = load_sweep(spec_path)
    variants = tracker_variants(spec, tracker_configs(spec, str(spec_path)), str(spec_path))
    assert [dict(v.parameters)["flag"] for v in variants] == ["false", "true"]
    assert {dict(v.parameters)["mode"] for v in variants} == {"fast"}
    # A default of true is the boolean, not pydantic's number 1.0.
    assert dict(tracker_configs(spec, str(spec_path))[0].parameters)["flag"] == "true"


@pytest.mark.parametrize(
    ("yaml", "expected"),
    [
        (
            "parameters:\n  timed:\n    mode: {grid: [fast, {a: 1}]}\n",
            "parameters.timed.mode.grid.1: give text, a number or a boolean, not a mapping",
        ),
        ("parameters:\n  timed:\n    mode: {grid: [fast, .nan]}\n", "grid.1: give a finite number (got nan)"),
        ("parameters:\n  timed:\n    mode: {grid: []}\n", "parameters.timed.mode.grid"),
        # A bad range is the range's error, not 'grid: Field required' (read as a grid).
        (
            "parameters:\n  timed:\n    sleep_ms: {range: [3, 1, 1]}\n",
            "parameters.timed.sleep_ms.range: range is [start, stop, step] with start <= stop",
        ),
        (
            "parameters:\n  timed:\n    sleep_ms: {ragne: [1, 3, 1]}\n",
            "sleep_ms: give one of grid:, range: or",
        ),
    ],
)
def test_a_bad_grid_is_one_line_naming_its_place(sequence: Path, tmp_path: Path, yaml: str, expected: str):
    spec_path = _spec(tmp_path, sequence, rest=yaml)
    with pytest.raises(SpecError) as caught:
        load_sweep(spec_path)
    message = str(caught.value)
    assert "\n" not in message and expected in message, message


def test_an_env_value_that_is_no_scalar_is_one_line(sequence: Path, tmp_path: Path):
    spec_path = _spec(tmp_path, sequence, "    env: {TIMED_N: [1, 2]}\n")
    with pytest.raises(SpecError) as caught:
        load_sweep(spec_path)
    message = str(caught.value)
    assert "\n" not in message and "env.TIMED_N: give text, a number or a boolean, not a list" in message


def test_a_gate_selects_rows_by_a_boolean_or_text_parameter():
    check = Check(name="c", parameters={"flag": True, "mode": "fast"}, budgets={"ate_rmse_m": {"max": 1}})
    assert check.parameters["flag"] is True  # not the number 1.0
    assert _same_value(True, True) and not _same_value(1, True) and not _same_value(True, 1.0)
    assert _same_value("fast", "fast") and _same_value(2, 2.0)
