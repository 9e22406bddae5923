"""The table of figures is the one list: the run record holds every measured figure, and
the statistics, the gates and compare take theirs from the table."""

from __future__ import annotations

import pytest
from depotbench.eval.gates.budgets import METRICS as BUDGETS
from depotbench.eval.gates.compare import COMPARED
from depotbench.eval.metrics.figures import FIGURES, is_baseline, with_derived
from depotbench.eval.metrics.record import FIELDS, RunRecord
from depotbench.eval.metrics.statistics import METRICS, SuccessRule, summarize

from tests.records import record


def test_every_measured_figure_is_a_field_of_the_run_record():
    assert [f.name for f in FIGURES if not f.derived and f.name not in FIELDS] == []


def test_statistics_gates_and_compare_read_the_table():
    names = [f.name for f in FIGURES]
    assert list(METRICS) == names and list(BUDGETS) == names
    assert set(COMPARED) == {f.name for f in FIGURES if f.compared}


def _row(sequence: str, strategy: str, ate: float | None, settings: str = "{}") -> RunRecord:
    return record(
        **{
            "sequence": sequence,
            "tracker": "builtin",
            "parameters": "{}",
            "detector": "groundtruth",
            "strategy": strategy,
            "settings": settings,
            "ate_rmse_m": ate,
            "tracked_fraction": 0.75,
        }
    )


def test_rho_is_taken_against_the_bare_none_run_of_the_same_sequence():
    rows = [
        _row("a", "none", 0.10),
        _row("a", "box_rule", 0.025, '{"k": 1}'),
        _row("b", "box_rule", 0.02),  # no none run on b: no rho
        _row("a", "none", 0.5, '{"odd": 1}'),  # a none run with settings is not the baseline
    ]
    derived = with_derived(rows)
    assert [r["rho_percent"] for r in derived] == [0.0, pytest.approx(75.0), None, pytest.approx(-400.0)]
    assert all(r["lost_fraction"] == pytest.approx(0.25) for r in derived)
    assert [is_baseline(r) for r in rows] == [True, False, False, False]


def test_a_figure_added_to_the_table_is_summarised_over_seeds():
    rows = [_row(s, "none", 0.1) for s in "abc"]
    summary = summarize(with_derived(rows), SuccessRule(0.5))
    assert summary["stats"]["lost_fraction"]["mean"] == pytest.approx(0.25)
    assert summary["stats"]["ate_rmse_m"]["n"] == 3
