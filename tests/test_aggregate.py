"""Figures over seeds (issue 36 point 2): statistics equal numpy's and scipy's on a closed
case, failures are counted, and the best configuration is one that held on every seed."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from depotbench.eval.metrics.record import RunRecord
from depotbench.eval.metrics.statistics import SuccessRule, paired_change, stats, summarize
from depotbench.eval.sweep.summary import best_per_family, configurations
from scipy import stats as sps

from tests.records import record

ATES = [0.010, 0.014, 0.009, 0.030]


def _row(
    seed: int, ate: float | None, tracked: float = 1.0, failure: str | None = None, **extra
) -> RunRecord:
    row = {
        "key": f"k{seed}-{extra.get('settings', '{}')}",
        "family": "walk",
        "sequence": f"walk-{seed:04d}",
        "tracker": "builtin",
        "parameters": "{}",
        "detector": "groundtruth",
        "strategy": "box_rule",
        "settings": "{}",
        "failure": failure,
        "ate_rmse_m": ate,
        "ate_max_m": None if ate is None else 2 * ate,
        "rpe_translation_rmse_m": None,
        "rpe_rotation_rmse_deg": None,
        "rejection_precision": 0.5,
        "rejection_recall": 0.9,
        "tracked_fraction": tracked,
        "track_ms_median": 20.0 + seed,
    }
    return record(**(row | extra))


def test_statistics_over_seeds_equal_numpy_and_scipy_on_a_closed_case():
    s = stats(ATES)
    assert s.n == 4 and s.mean == pytest.approx(np.mean(ATES)) and s.median == pytest.approx(np.median(ATES))
    assert s.std == pytest.approx(np.std(ATES, ddof=1)) and s.worst == 0.030
    assert s.p90 == pytest.approx(np.percentile(ATES, 90))
    reference = sps.bootstrap(
        (np.array(ATES),), np.mean, confidence_level=0.95, n_resamples=2000, method="BCa",
        random_state=np.random.default_rng(20261125),
    ).confidence_interval  # fmt: skip
    assert (s.ci_low, s.ci_high) == pytest.approx((reference.low, reference.high))
    assert stats(ATES) == s  # seeded: the same interval on every evaluation
    recall = stats([0.9, 0.7, 0.95], higher_is_better=True)
    assert recall.worst == 0.7 and recall.p90 == pytest.approx(np.percentile([0.9, 0.7, 0.95], 10))
    assert stats([None, None]).n == 0 and stats([0.5]).ci_low is None


def test_a_failed_or_mostly_lost_run_is_counted_as_a_failure_never_dropped():
    rows = [
        _row(1, 0.01),
        _row(2, 0.02),
        _row(3, 0.005, tracked=0.6),
        _row(4, None, failure="exited with code 3"),
    ]
    summary = summarize(rows, SuccessRule(0.9))
    assert (summary["runs"], summary["successes"], summary["failed"]) == (4, 2, 1)
    assert summary["success_rate"] == 0.5
    assert summary["stats"]["ate_rmse_m"]["n"] == 3  # the failed run has no ATE to average


def test_a_configuration_that_lost_track_on_one_seed_of_four_is_not_the_best():
    steady = [_row(seed, ate + 0.002, settings='{"k": 2}') for seed, ate in enumerate(ATES)]
    lost_once = [_row(seed, ate, settings='{"k": 3}') for seed, ate in enumerate(ATES)]
    lost_once[2] = replace(lost_once[2], tracked_fraction=0.5)
    configs = configurations(steady + lost_once)
    rates = {c["settings"]["k"]: c["success_rate"] for c in configs}
    assert rates == {2: 1.0, 3: 0.75}
    assert best_per_family(configs)["walk"]["settings"] == {"k": 2}
    assert best_per_family(configs, min_success_rate=0.75)["walk"]["settings"] == {"k": 3}


def test_a_paired_change_is_a_ratio_for_errors_and_a_difference_for_rates():
    baseline = [0.010, 0.020, 0.040, 0.015]
    worse = [v * 1.2 for v in baseline]
    change = paired_change("ate_rmse_m", baseline, worse)
    assert change.pairs == 4 and change.change == pytest.approx(0.2) and change.p_worse < 1e-6
    noisy = [v * f for v, f in zip(baseline, [1.05, 0.96, 1.02, 0.98], strict=True)]
    assert paired_change("ate_rmse_m", baseline, noisy).p_worse > 0.3
    recall = paired_change("rejection_recall", [0.9, 0.8, 0.85], [0.8, 0.7, 0.76])
    assert recall.change == pytest.approx(-0.0966666, rel=1e-4) and recall.p_worse < 0.01
    t = sps.ttest_rel(np.log(noisy), np.log(baseline), alternative="greater").pvalue
    assert paired_change("ate_rmse_m", baseline, noisy).p_worse == pytest.approx(t)


def test_the_best_table_keeps_its_columns_for_long_family_names_and_labels():
    """A suite's family names reach 40 characters ('walkers actors.0.count=1'): the table ran
    them into the configuration column."""
    from depotbench.eval.sweep.summary import format_best

    family = "walkers actors.0.count=1 camera.motion=xyz"
    rows = [_row(seed, ate, family=family, settings='{"k": 2.5}') for seed, ate in enumerate(ATES)]
    best = best_per_family(configurations(rows))
    lines = format_best(best, {"another family with a long name": 0.5}).splitlines()
    header, rule, row, missing = lines
    assert set(rule.strip()) == {"-"}
    assert row.startswith(family + "  ") and missing.startswith("another family with a long name  ")
    assert row.index(best[family]["label"]) == header.index("best configuration")
    assert row.split()[-1] == "4/4" and len(row) == len(header)


def test_near_equal_values_get_the_percentile_interval_without_a_warning():
    """BCa is NaN on values one ulp apart, and scipy said so on the terminal twice."""
    import warnings

    values = [1.0, 1.0 + 2**-52, 1.0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = stats(values)
    assert s.ci_low == pytest.approx(1.0) and s.ci_high == pytest.approx(1.0)


def test_the_best_table_lists_families_in_natural_order():
    """'demo actors.0.count=12' came before '...=6' (sorted as text)."""
    from depotbench.eval.sweep.summary import format_best

    rows = [
        _row(seed, ate, family=f"demo actors.0.count={count}")
        for count in (12, 0, 6)
        for seed, ate in enumerate(ATES)
    ]
    lines = format_best(best_per_family(configurations(rows)), {"demo actors.0.count=10": 0.5}).splitlines()
    assert [line.split()[1] for line in lines[2:5]] == [
        "actors.0.count=0",
        "actors.0.count=6",
        "actors.0.count=12",
    ]
