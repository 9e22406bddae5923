"""`depotbench compare`: paired changes between result sets, checked against scipy's paired
test on a closed case and end to end on two real sweeps that differ in one parameter."""

from __future__ import annotations

import json
import math
import shlex
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.gates.compare import compare_rows
from depotbench.eval.metrics.record import RunRecord
from scipy.stats import ttest_rel

from tests.conftest import REPO
from tests.records import record

ORACLE = REPO / "tests" / "programs" / "oracle_slam.py"
COMMAND = (
    f"{shlex.quote(sys.executable)} {ORACLE} {{sequence}} {{detections}} {{parameters}} {{trajectory}} "
    "{keypoints}"
)
ATE = [0.010, 0.020, 0.040, 0.015]


def _rows(strategy: str, settings: dict, ates: list[float], tracked: float = 1.0) -> list[RunRecord]:
    return [
        record(
            **{
                "key": f"{strategy}-{json.dumps(settings)}-{seed}",
                "family": "walk",
                "sequence": f"/suite/walk-{seed:04d}",
                "tracker": "builtin",
                "parameters": "{}",
                "detector": "groundtruth",
                "strategy": strategy,
                "settings": json.dumps(settings),
                "ate_rmse_m": ate,
                "rpe_translation_rmse_m": 0.001,
                "tracked_fraction": tracked,
                "track_ms_median": 20.0,
            }
        )
        for seed, ate in enumerate(ates)
    ]


def _by(result, strategy: str, figure: str):
    (found,) = [c for c in result.comparisons if c.figure == figure and f"{strategy}" in c.base]
    return found


def test_a_changed_threshold_is_significant_and_an_unchanged_configuration_is_not():
    """Two sets that differ in one box_rule threshold: box_rule's ATE grew by 30 % on every
    seed (with a few percent of noise), none ran the same. The pairing crosses the changed
    setting; significance is scipy's two-sided paired t-test on the logarithms."""
    worse = [a * 1.3 * f for a, f in zip(ATE, [1.02, 0.99, 1.01, 0.98], strict=True)]
    noisy = [a * f for a, f in zip(ATE, [1.08, 0.93, 1.05, 0.97], strict=True)]
    first = _rows("none", {}, ATE) + _rows("box_rule", {"min_iou": 0.5}, ATE)
    second = _rows("none", {}, noisy) + _rows("box_rule", {"min_iou": 0.7}, worse)
    result = compare_rows(first, second)
    assert not result.only_first and not result.only_this
    grown = _by(result, "box_rule", "ate_rmse_m")
    assert "min_iou=0.5" in grown.base and "min_iou=0.7" in grown.other
    expected = math.exp(np.mean(np.log(worse) - np.log(ATE))) - 1
    assert grown.change.change == pytest.approx(expected) and grown.change.pairs == 4
    assert grown.significant and ttest_rel(np.log(worse), np.log(ATE)).pvalue < 0.05
    assert grown.regression(0.05) and not grown.regression(0.5)
    steady = _by(result, "none", "ate_rmse_m")
    assert not steady.significant and ttest_rel(np.log(noisy), np.log(ATE)).pvalue >= 0.05
    assert steady.change.p_worse == pytest.approx(
        ttest_rel(np.log(noisy), np.log(ATE), alternative="greater").pvalue
    )
    same = _by(result, "none", "tracked_fraction")
    assert same.change.change == 0 and not same.significant


def test_slower_time_is_a_regression_only_when_asked():
    """Two sweeps run at different moments differ in load: time fails a comparison only with
    ``time=True`` (``--time``)."""
    first = _rows("none", {}, ATE)
    second = [replace(row, track_ms_median=40.0 + i) for i, row in enumerate(_rows("none", {}, ATE))]
    result = compare_rows(first, second)
    assert result.regressions(0.05) == []
    (slower,) = result.regressions(0.05, time=True)
    assert slower.figure == "track_ms_median" and slower.change.change == pytest.approx(
        math.exp(np.mean(np.log([40.0, 41.0, 42.0, 43.0]) - np.log(20.0))) - 1
    )


def test_configurations_that_cannot_be_paired_are_named_not_dropped():
    """Two box_rule values on each side: which pairs with which is not knowable, so none are
    paired and all four are listed."""
    first = _rows("box_rule", {"min_iou": 0.5}, ATE) + _rows("box_rule", {"min_iou": 0.6}, ATE)
    second = _rows("box_rule", {"min_iou": 0.7}, ATE) + _rows("box_rule", {"min_iou": 0.8}, ATE)
    result = compare_rows(first, second)
    assert result.comparisons == []
    assert len(result.only_first) == 2 and len(result.only_this) == 2
    assert any("min_iou=0.5" in line for line in result.only_first)


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two sweeps over 4 seeds that differ in one parameter of an external program (its
    position noise, 1 cm then 3 cm); the built-in tracker runs the same in both."""
    root = tmp_path_factory.mktemp("compare")
    for seed in range(1, 5):
        args = ["generate", "smoke", "-o", str(root / f"s{seed}"), "--frames", "4", "--seed", str(seed)]
        assert main(args) == 0
    sequences = ", ".join(str(root / f"s{seed}") for seed in range(1, 5))
    for name, noise in (("a", 0.01), ("b", 0.03)):
        spec = root / f"{name}.yaml"
        spec.write_text(
            f"sweep: {name}\nsequences: [{sequences}]\nstrategies: [none]\ntrackers:\n  - builtin\n"
            f"  - name: oracle\n    command: {json.dumps(COMMAND)}\n"
            f"    parameters: {{noise_m: {noise}, margin_px: 4, mode: ok}}\n"
        )
        assert main(["sweep", str(spec), "-o", str(root / name)]) == 0
    return root


def _blocks(out: str) -> dict[str, dict[str, str]]:
    """The table's blocks: configuration line -> figure -> its line."""
    blocks: dict[str, dict[str, str]] = {}
    for line in out.splitlines():
        if line.startswith("smoke · "):
            current = blocks.setdefault(line, {})
        elif line.startswith("  ") and not line.strip().startswith("figure"):
            current[line.split()[0]] = line
    return blocks


def test_compare_names_the_configurations_whose_difference_is_significant(sweeps: Path, capsys):
    capsys.readouterr()
    assert main(["compare", str(sweeps / "a"), str(sweeps / "b")]) == 0
    out = capsys.readouterr().out
    blocks = _blocks(out)
    (oracle,) = [lines for title, lines in blocks.items() if "oracle" in title]
    (builtin,) = [lines for title, lines in blocks.items() if "oracle" not in title]
    assert "noise_m=0.01 · none (groundtruth) -> oracle" in next(t for t in blocks if "oracle" in t)
    assert oracle["ate_rmse_m"].endswith(" *") and oracle["rpe_translation_rmse_m"].endswith(" *"), out
    # the built-in tracker ran the same: its figures did not move (its time may: load differs)
    assert builtin["ate_rmse_m"].split()[3] == "+0.0%" and not builtin["ate_rmse_m"].endswith("*")

    assert main(["compare", str(sweeps / "a"), str(sweeps / "b"), "--json"]) == 0
    (result,) = json.loads(capsys.readouterr().out).values()
    ate = [c for c in result["comparisons"] if c["figure"] == "ate_rmse_m" and "oracle" in c["base"]]
    (oracle,) = ate
    assert oracle["pairs"] == 4 and oracle["significant"] and oracle["change"] > 1.0  # 3 cm against 1 cm


def test_fail_on_regression_exits_1_and_the_html_page_is_written_once(sweeps: Path, tmp_path: Path, capsys):
    page = tmp_path / "compare.html"
    args = ["compare", str(sweeps / "a"), str(sweeps / "b"), "--html", str(page)]
    assert main([*args, "--fail-on-regression"]) == 1
    out = capsys.readouterr().out
    assert "REGRESSION" in out and "oracle" in out
    text = page.read_text()
    assert "significant" in text and "noise_m=0.01 · none (groundtruth) → " in text
    assert main(args) == 2  # the page exists: not replaced without --overwrite
    assert "--overwrite" in capsys.readouterr().err and page.read_text() == text
    assert main([*args, "--overwrite"]) == 0  # a regression alone, without the flag, passes
    # the other way round it is an improvement: nothing to fail on
    assert main(["compare", str(sweeps / "b"), str(sweeps / "a"), "--fail-on-regression"]) == 0
    assert (
        main(["compare", str(sweeps / "a"), str(sweeps / "b"), "--tolerance", "5", "--fail-on-regression"])
        == 0
    )


def test_a_run_folder_compares_with_a_run_folder(sweeps: Path, tmp_path: Path, capsys):
    for name in ("r1", "r2"):
        assert main(["run", str(sweeps / "s1"), "-o", str(tmp_path / name), "--strategy", "none"]) == 0
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "r1"), str(tmp_path / "r2")]) == 0
    out = capsys.readouterr().out
    assert "ate_rmse_m" in out and " *" not in out  # one pair: no test, nothing significant


@pytest.mark.parametrize(
    ("make", "needle"),
    [
        (lambda p: p.mkdir(), "neither a sweep folder"),
        (lambda p: (p.mkdir(), (p / "record.json").write_text("{nope")), "record.json: not valid JSON"),
        (lambda p: (p.mkdir(), (p / "record.json").write_text("[1]")), "record.json: not a run record"),
    ],
)
def test_a_folder_that_holds_no_results_is_refused_naming_it(
    sweeps: Path, tmp_path: Path, capsys, make, needle
):
    bad = tmp_path / "bad"
    make(bad)
    assert main(["compare", str(sweeps / "a"), str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and str(bad) in err[0]


def test_compare_needs_two_folders(sweeps: Path, capsys):
    assert main(["compare", str(sweeps / "a")]) == 2
    assert "two folders or more" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("column", "value", "needle", "compared"),
    [
        ("ate_rmse_m", "oops", "not a number", True),
        ("frames", [1], "not an integer", False),
        ("settings", "{", "not a JSON object", True),
        ("knobs", "[1, 2]", "not a JSON object", False),
    ],
)
def test_a_run_record_or_row_edited_by_hand_is_one_line_naming_its_column(
    sweeps: Path, tmp_path: Path, capsys, column, value, needle, compared
):
    """Probe N23: record.json values were not type-checked (a TypeError in a mean) and the
    store's JSON columns not parsed (a JSONDecodeError in a label). compare reads a store's
    rows a column at a time: a column it does not use (``compared`` False) is not its
    business, and the comparison goes on."""
    import sqlite3

    run = tmp_path / "r"
    assert main(["run", str(sweeps / "s1"), "-o", str(run), "--strategy", "none"]) == 0
    record = json.loads((run / "record.json").read_text())
    (run / "record.json").write_text(json.dumps({**record, column: value}))
    sweep = tmp_path / "sw"
    shutil.copytree(sweeps / "a", sweep)
    with sqlite3.connect(sweep / "results.sqlite") as db:
        stored = json.dumps(value) if isinstance(value, list) else value
        db.execute(f"UPDATE runs SET {column} = ?", (stored,))
    capsys.readouterr()
    for bad, file in ((run, "record.json"), (sweep, "results.sqlite")):
        if file == "results.sqlite" and not compared:
            assert main(["compare", str(sweeps / "a"), str(bad)]) == 0
            continue
        assert main(["compare", str(sweeps / "a"), str(bad)]) == 2, file
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "Traceback" not in err[0], err
        assert str(bad / file) in err[0] and f"{column} is " in err[0] and needle in err[0], err[0]
