"""Pairing runs across result sets: by sequence content, within one program version.

Each case is a probe reproduction (``reliability-probe-2.md``: O2, N3, N4, O13, O14) on small
stores written row by row, read back through the code ``check --baseline`` and ``compare``
use; the expected change and p are scipy's paired t-test on the same numbers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from depotbench.core.errors import InputError
from depotbench.eval.cli.main import main
from depotbench.eval.gates.budgets import GateFile, evaluate, format_report
from depotbench.eval.gates.check import load_baseline
from depotbench.eval.gates.compare import compare_rows, load_rows
from depotbench.eval.metrics.figures import with_derived
from depotbench.eval.metrics.record import RunRecord
from depotbench.eval.metrics.statistics import SuccessRule, summarize
from depotbench.eval.sweep.store import ResultStore
from scipy.stats import ttest_1samp

from tests.records import record

GOOD = [0.010, 0.012, 0.009, 0.011, 0.010, 0.013]
NOISE = [1.0, 1.1, 0.9, 1.05, 0.95, 1.0]
BAD = [40 * a * f for a, f in zip(GOOD, NOISE, strict=True)]


def _rows(ates: list[float], version: str | None, tag: str = "", folder: str = "/suite") -> list[RunRecord]:
    """One configuration of an external tracker ``mine`` on len(ates) sequences."""
    return [
        record(
            key=f"{version}{tag}-{i}",
            family="walk",
            sequence=f"{folder}/walk-{i:04d}",
            tracker="mine",
            ate_rmse_m=ate,
            tracker_fingerprint=version,
        )
        for i, ate in enumerate(ates)
    ]


def _store(folder: Path, rows: list[RunRecord]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    with ResultStore(folder / "results.sqlite") as store:
        for row in rows:
            store.add(row)
    return folder


def _gates() -> GateFile:
    import yaml

    text = """
gates: o2
run: {sequences: [x]}
checks:
  - name: no-regression-against-the-baseline
    trackers: [mine]
    budgets: {ate_rmse_m.vs_baseline: {max: 0.2}}
"""
    return GateFile.model_validate(yaml.safe_load(text))


def test_o2_a_baseline_swept_by_two_builds_is_refused_naming_both(tmp_path: Path):
    """O2: sweep a bad build, then a good build, into B; ``check --baseline B`` with the bad
    build said "within noise" for a 40x regression (each sequence paired with whichever row
    came last). Now B is refused in one line naming both fingerprints and how to choose."""
    baseline = _store(tmp_path / "B", _rows(BAD, "worsebuild00") + _rows(GOOD, "goodbuild000"))
    with pytest.raises(InputError) as refused:
        load_baseline(baseline)
    message = str(refused.value)
    assert "\n" not in message and "worsebuild00 (6 rows)" in message and "goodbuild000 (6 rows)" in message
    assert "--baseline-fingerprint" in message and "--prune-stale" in message
    # Chosen, the good build's rows are the baseline: the bad build fails, as against a
    # folder holding only them (the probe's p = 0.00015 there).
    rows = load_baseline(baseline, ("goodbuild000",))
    assert {r.tracker_fingerprint for r in rows} == {"goodbuild000"}
    report = evaluate(_gates(), _rows(BAD, "worsebuild00", tag="now"), rows)
    (verdict,) = report.results[0].verdicts
    expected = ttest_1samp(np.log(BAD) - np.log(GOOD), 0.0, alternative="greater").pvalue
    assert not verdict.passed and "within noise" not in verdict.note
    assert verdict.value == pytest.approx(np.exp(np.mean(np.log(BAD) - np.log(GOOD))) - 1)
    assert f"p={expected:.3g}" in verdict.note
    with pytest.raises(InputError, match="2 program versions"):
        load_baseline(baseline, ("typo",))


def test_o2_compare_refuses_a_folder_of_two_builds_and_takes_one_when_told(tmp_path: Path, capsys):
    mixed = _store(tmp_path / "B", _rows(BAD, "worsebuild00") + _rows(GOOD, "goodbuild000"))
    good = _store(tmp_path / "G", _rows(GOOD, "goodbuild000"))
    assert main(["compare", str(good), str(mixed)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "worsebuild00" in err and "goodbuild000" in err
    assert main(["compare", str(good), str(mixed), "--fingerprint", "worsebuild00", "--json"]) == 0
    (result,) = json.loads(capsys.readouterr().out).values()
    (ate,) = [c for c in result["comparisons"] if c["figure"] == "ate_rmse_m"]
    assert ate["pairs"] == 6 and ate["change"] == pytest.approx(
        np.exp(np.mean(np.log(BAD) - np.log(GOOD))) - 1
    )


def test_rows_written_before_fingerprints_are_their_own_unknown_version(tmp_path: Path):
    old = _store(tmp_path / "old", _rows(GOOD, None) + _rows(BAD, "worsebuild00"))
    with pytest.raises(InputError, match=r"unknown \(6 rows\)"):
        load_rows(old)
    assert len(load_rows(old, ("unknown",))) == 6


def test_statistics_refuse_to_average_two_program_versions():
    rows = with_derived(_rows(GOOD[:3], "goodbuild000") + _rows(GOOD[3:], "worsebuild00", tag="x"))
    with pytest.raises(InputError, match="2 program versions"):
        summarize(rows, SuccessRule())
    assert summarize(rows[:3], SuccessRule())["runs"] == 3


def test_n3_a_baseline_holding_two_runs_per_sequence_is_reported_not_within_noise():
    """N3: ``--baseline`` = ``-o`` the second time holds, per sequence, the old run and the
    current one (keys differ by bench version, tracker fingerprint alike); pairing by name,
    last one wins, paired the current runs with themselves: "within noise" for a 3x change."""
    now = _rows([3 * a for a in GOOD], "samebuild000", tag="1now")  # keys sort after the old
    baseline = _rows(GOOD, "samebuild000", tag="0old") + now
    report = evaluate(_gates(), now, baseline)
    (verdict,) = report.results[0].verdicts
    assert not verdict.passed and "the baseline holds 2 runs of this configuration" in verdict.note


def test_n3_two_folders_named_seq_are_two_sequences(tmp_path: Path, capsys):
    """Identical runs on a/seq and b/seq in both sets: by name they were cross-paired (a
    change where there is none) or counted once; by fingerprint, two pairs and no change."""

    def rows(order: list[str], ates: dict[str, float]) -> list[RunRecord]:
        return [
            record(
                key=f"{i}-{where}", sequence=f"/{where}/seq", ate_rmse_m=ates[where], tracker_fingerprint="v"
            )
            for i, where in enumerate(order)
        ]

    ates = {"a": 0.01, "b": 0.05}
    first = _store(tmp_path / "first", rows(["a", "b"], ates))
    second = _store(tmp_path / "second", rows(["b", "a"], ates))
    assert main(["compare", str(first), str(second), "--json"]) == 0
    (result,) = json.loads(capsys.readouterr().out).values()
    (ate,) = [c for c in result["comparisons"] if c["figure"] == "ate_rmse_m"]
    assert ate["pairs"] == 2 and ate["change"] == 0.0
    assert ate["base_mean"] == pytest.approx(0.03) and not result["duplicates"]


def test_n3_two_runs_of_one_configuration_on_one_sequence_are_reported_by_compare():
    first = _rows(GOOD, "v")
    second = _rows(GOOD, "v", tag="old") + _rows([3 * a for a in GOOD[:2]], "v", tag="new")
    result = compare_rows(first, second)
    assert len(result.duplicates) == 2 and "(2 runs)" in result.duplicates[0]
    (ate,) = [c for c in result.comparisons if c.figure == "ate_rmse_m"]
    assert ate.change.pairs == 4 and ate.change.change == pytest.approx(0.0)


@pytest.mark.parametrize("tolerance", ["nan", "inf", "1e999", "-0.1"])
def test_n4_a_tolerance_that_disarms_fail_on_regression_is_refused(tolerance: str, tmp_path: Path, capsys):
    first = _store(tmp_path / "a", _rows(GOOD, "v"))
    with pytest.raises(SystemExit) as exited:
        main(["compare", str(first), str(first), "--fail-on-regression", "--tolerance", tolerance])
    assert exited.value.code == 2 and "--tolerance" in capsys.readouterr().err


def test_o13_check_counts_runs_once_and_configurations_apart_and_keeps_long_names():
    import yaml

    gates = GateFile.model_validate(
        yaml.safe_load(
            """
gates: o13
run: {sequences: [x]}
checks:
  - name: a-check-name-well-past-twenty-four-characters
    budgets: {ate_rmse_m: {max: 1.0}}
  - name: second
    budgets: {ate_rmse_m: {max: 1.0}, ate_rmse_m.mean: {max: 1.0}}
"""
        )
    )
    report = evaluate(gates, _rows(GOOD, "v"))
    text = format_report(report)
    assert "a-check-name-well-past-twenty-four-characters" in text
    assert text.splitlines()[-1] == "o13: 6/6 runs and 1/1 configurations within budget; all budgets held"


def test_o14_sweeps_differing_in_one_parameter_pair_every_configuration():
    """Two full sweeps, one parameter changed (window 3 -> 5) on every configuration: each is
    paired with the one sharing all else, and the pair names what differs."""

    def sweep(window: int) -> list[RunRecord]:
        return [
            record(
                key=f"{window}-{strategy}-{confidence}-{i}",
                sequence=f"/suite/walk-{i:04d}",
                tracker="mine",
                parameters=json.dumps({"window": window}),
                strategy=strategy,
                settings=json.dumps({"min_confidence": confidence}),
                ate_rmse_m=ate * (2 + 0.1 * (i % 3) if window == 5 else 1),
                tracker_fingerprint=f"w{window}",
            )
            for strategy in ("none", "mask")
            for confidence in (0.3, 0.5)
            for i, ate in enumerate(GOOD)
        ]

    result = compare_rows(sweep(3), sweep(5))
    assert not result.only_first and not result.only_this
    ate = [c for c in result.comparisons if c.figure == "ate_rmse_m"]
    expected = np.exp(np.mean(np.log([2 + 0.1 * (i % 3) for i in range(len(GOOD))]))) - 1
    assert len(ate) == 4 and all(c.change.change == pytest.approx(expected) and c.significant for c in ate)
    assert all(c.differs == "window 3 -> 5" for c in ate)


def test_n13_compare_streams_a_store_and_agrees_with_its_records(tmp_path: Path):
    """N13: compare held every row of a store as a record (200,000 rows: 1.53 GB); it now
    reads the columns it needs a row at a time (``load_set``). Its comparison of two stores
    is the one of their records: rho against each sequence's none run, missing figures and
    a second program version chosen away included."""
    from depotbench.eval.gates.compare import load_set

    def sweep(scale: float) -> list[RunRecord]:
        rows = []
        for strategy, factor in (("none", 1.0), ("box_rule", 0.5)):
            for i, ate in enumerate(GOOD):
                recall = None if strategy == "none" else 0.8 + 0.01 * i * scale
                rows.append(
                    record(
                        key=f"{strategy}-{i}",
                        sequence=f"/suite/walk-{i:04d}",
                        tracker="mine",
                        strategy=strategy,
                        ate_rmse_m=ate * factor * (scale * NOISE[i] if strategy != "none" else 1.0),
                        rejection_recall=recall,
                        tracker_fingerprint="v",
                    )
                )
        return rows

    first = _store(tmp_path / "a", sweep(1.0))
    second = _store(tmp_path / "b", sweep(1.3) + _rows(BAD, "worsebuild00"))
    streamed = compare_rows(load_set(first), load_set(second, ("v",)))
    held = compare_rows(load_rows(first), load_rows(second, ("v",)))
    assert streamed.to_dict() == held.to_dict()
    assert {c.figure for c in streamed.comparisons} >= {"ate_rmse_m", "rho_percent", "rejection_recall"}
    with pytest.raises(InputError, match="2 program versions"):
        load_set(second)
