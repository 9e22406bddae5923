"""Statistics over seeds: what a configuration did on every sequence of its family, and
whether a change between two result sets is real or noise.

A bench whose figures swing with the seed (rho of one setting ranged from -11 % to 80 %
over five seeds) needs every figure with its spread: n, mean, median, standard deviation,
the worst seed, the 90th percentile and a 95 % bootstrap confidence interval of the mean
(scipy.stats.bootstrap, seeded, so a verdict is the same on every evaluation). A failed or
mostly lost run counts as a failure (``SuccessRule``), never as a missing value.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from depotbench.eval.metrics.figures import FIGURES, HIGHER_IS_BETTER, RATIO, ScoredRun
from depotbench.eval.metrics.versions import check_one_version

CONFIDENCE = 0.95
RESAMPLES = 2000
"""Bootstrap resamples of a confidence interval: the interval's ends move by about 1 % of
its width between 2000-resample draws."""
BOOTSTRAP_SEED = 20261125
"""The resampling is seeded: the same rows give the same interval, and a gate the same verdict."""

METRICS = tuple(f.name for f in FIGURES)
"""The per-run figures aggregated over seeds (each where rows carry it): every figure."""


@dataclass(frozen=True)
class SuccessRule:
    """A run succeeds when it did not fail, has an ATE and tracked at least this fraction
    of its frames: ATE is measured on tracked frames only, so a run that lost half the clip
    can show a small ATE (a best configuration tracked 0.68 of its frames)."""

    min_tracked_fraction: float = 0.9

    def holds(self, row: dict[str, Any]) -> bool:
        return (
            not row.get("failure")
            and row.get("ate_rmse_m") is not None
            and (row.get("tracked_fraction") or 0.0) >= self.min_tracked_fraction
        )


@dataclass(frozen=True)
class Stats:
    """One figure over seeds (the values that exist: a failed run has no ATE)."""

    n: int
    mean: float | None
    median: float | None
    std: float | None
    worst: float | None
    p90: float | None
    """The value nine seeds in ten do at least as well as."""
    ci_low: float | None
    ci_high: float | None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def stats(values: list[float | None], higher_is_better: bool = False) -> Stats:
    finite = np.array([v for v in values if v is not None and math.isfinite(v)], float)
    if not len(finite):
        return Stats(0, None, None, None, None, None, None, None)
    worst = float(finite.min() if higher_is_better else finite.max())
    p90 = float(np.percentile(finite, 10 if higher_is_better else 90))
    low, high = confidence_interval(finite)
    return Stats(
        n=len(finite),
        mean=float(finite.mean()),
        median=float(np.median(finite)),
        std=float(finite.std(ddof=1)) if len(finite) > 1 else None,
        worst=worst,
        p90=p90,
        ci_low=low,
        ci_high=high,
    )


def confidence_interval(values: np.ndarray) -> tuple[float | None, float | None]:
    """The 95 % bootstrap interval of the mean (BCa; percentile where BCa cannot be had)."""
    if len(values) < 2:
        return None, None
    if np.all(values == values[0]):
        return float(values[0]), float(values[0])
    import warnings

    from scipy.stats import DegenerateDataWarning, bootstrap

    for method in ("BCa", "percentile"):
        with warnings.catch_warnings():
            # BCa's NaN on near-equal values (1, 1 + 2**-52, 1) is answered below by the
            # percentile interval; scipy's warnings about it would reach the user's terminal
            warnings.simplefilter("ignore", DegenerateDataWarning)
            warnings.simplefilter("ignore", RuntimeWarning)
            result = bootstrap(
                (values,),
                np.mean,
                confidence_level=CONFIDENCE,
                n_resamples=RESAMPLES,
                method=method,
                vectorized=True,
                random_state=np.random.default_rng(BOOTSTRAP_SEED),
            )
        low, high = result.confidence_interval
        if math.isfinite(low) and math.isfinite(high):
            return float(low), float(high)
    return None, None


def summarize(rows: list[ScoredRun], rule: SuccessRule) -> dict[str, Any]:
    """The runs of one configuration in one family (its seeds): counts and every figure's
    statistics. Runs of two versions of the tracker's program are refused, not averaged."""
    check_one_version(rows, "the runs of one configuration")
    successes = sum(rule.holds(r) for r in rows)
    out: dict[str, Any] = {
        "runs": len(rows),
        "successes": successes,
        "success_rate": successes / len(rows) if rows else None,
        "failed": sum(1 for r in rows if r.get("failure")),
        "stats": {},
    }
    for metric in METRICS:
        if any(metric in r for r in rows):
            out["stats"][metric] = stats([r.get(metric) for r in rows], metric in HIGHER_IS_BETTER).to_dict()
    return out


@dataclass(frozen=True)
class Change:
    """A figure's paired change from a baseline to a candidate, over the sequences both ran."""

    pairs: int
    change: float | None
    """The relative change of a ratio metric (geometric mean ratio - 1: +0.1 is 10 % larger),
    the mean difference of the others."""
    ci_low: float | None
    ci_high: float | None
    p_worse: float | None
    """One-sided paired t-test that the candidate is worse; on the logarithms of ratio
    metrics. With 4 pairs Wilcoxon's signed-rank test cannot go below p = 0.0625, so a
    regression on 4 seeds could never be shown with it."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def paired_change(metric: str, baseline: list[float], candidate: list[float]) -> Change:
    """The change of ``metric`` over pairs (seeds) where both values exist."""
    pairs = [
        (b, c)
        for b, c in zip(baseline, candidate, strict=True)
        if b is not None and c is not None and math.isfinite(b) and math.isfinite(c)
    ]
    ratio = metric in RATIO
    if ratio:
        pairs = [(b, c) for b, c in pairs if b > 0 and c > 0]
    if not pairs:
        return Change(0, None, None, None, None)
    b, c = np.array(pairs).T
    differences = np.log(c) - np.log(b) if ratio else c - b
    worse = differences if metric not in HIGHER_IS_BETTER else -differences
    mean = float(differences.mean())
    low, high = confidence_interval(differences)
    to_change = (lambda d: math.expm1(d)) if ratio else (lambda d: d)  # noqa: E731
    return Change(
        pairs=len(differences),
        change=to_change(mean),
        ci_low=None if low is None else to_change(low),
        ci_high=None if high is None else to_change(high),
        p_worse=_p_worse(worse),
    )


def _p_worse(worse: np.ndarray) -> float | None:
    """One-sided p-value that the mean of ``worse`` (positive: the candidate is worse) is
    above 0. Equal differences leave no variance: certain either way, or no evidence when
    they are all 0."""
    if len(worse) < 2:
        return None
    if np.all(worse == worse[0]):
        return 0.0 if worse[0] > 0 else 1.0 if worse[0] < 0 else 0.5
    from scipy.stats import ttest_1samp

    return float(ttest_1samp(worse, 0.0, alternative="greater").pvalue)
