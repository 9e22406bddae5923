"""Two or more result sets side by side: per family and configuration, how each figure
changed from the first set, paired by sequence, with its 95 % interval and a one-sided
paired test, so that a real change is told from run-to-run noise (as evo's ``evo_res``
compares results, with statistics over seeds added).

A configuration is paired with the same configuration of the other set; where the sets
differ in a threshold or a parameter (so no configuration is in both), configurations of
one family, tracker, detector and strategy are paired when there is one on each side.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError
from depotbench.eval.metrics.figures import (
    FIGURES,
    HIGHER_IS_BETTER,
    RATIO,
    TIME,
    ScoredRun,
    configuration_of,
    with_derived,
)
from depotbench.eval.metrics.record import RunRecord
from depotbench.eval.metrics.statistics import Change, paired_change, stats
from depotbench.eval.sweep.summary import configuration_label

COMPARED = tuple(f.name for f in FIGURES if f.compared)
ALPHA = 0.05


@dataclass(frozen=True)
class Comparison:
    """One figure of one configuration, from the first set (``base``) to another."""

    family: str
    base: str
    """The configuration's label in the first set."""
    other: str
    """Its label in the other set (different where the sets differ in a setting)."""
    figure: str
    base_mean: float | None
    other_mean: float | None
    change: Change

    @property
    def significant(self) -> bool:
        """The change is real, in either direction (the two-sided p of the paired test)."""
        p = self.change.p_worse
        return p is not None and 2.0 * min(p, 1.0 - p) < ALPHA

    def text(self) -> str:
        """One line: where, what and how much."""
        ratio = self.figure in RATIO
        p = "-" if self.change.p_worse is None else f"{self.change.p_worse:.3g}"
        return (
            f"{self.family} · {self.other} {self.figure} {change_text(self.change.change, ratio)} "
            f"over {self.change.pairs} pairs (p(worse)={p})"
        )

    def regression(self, tolerance: float) -> bool:
        """Worse beyond ``tolerance`` (relative for errors and time, absolute for rates), and
        significant (the same two-sided test that marks a change)."""
        c = self.change
        if c.change is None or not self.significant:
            return False
        worse = -c.change if self.figure in HIGHER_IS_BETTER else c.change
        return worse > tolerance

    def to_dict(self) -> dict[str, Any]:
        return {
            "family": self.family,
            "base": self.base,
            "other": self.other,
            "figure": self.figure,
            "base_mean": self.base_mean,
            "other_mean": self.other_mean,
            **self.change.to_dict(),
            "significant": self.significant,
        }


def load_rows(folder: Path) -> list[RunRecord]:
    """A sweep's or check's runs (results.sqlite), or a run folder's one run (record.json)."""
    from depotbench.core.files import read_text
    from depotbench.eval.sweep.store import ResultStore

    if (folder / "results.sqlite").is_file():
        with ResultStore(folder / "results.sqlite", readonly=True) as store:
            return store.records()
    if (folder / "record.json").is_file():
        try:
            row = json.loads(read_text(folder / "record.json", 1 << 20, "run record"))
        except ValueError as exc:
            raise InputError(f"{folder / 'record.json'}: not valid JSON ({exc})") from None
        if not isinstance(row, dict) or "key" not in row:
            raise InputError(f"{folder / 'record.json'}: not a run record")
        try:
            return [RunRecord.from_row(row)]
        except KeyError as exc:
            raise InputError(f"{folder / 'record.json'}: not a run record (no {exc.args[0]})") from None
    raise InputError(f"{folder}: neither a sweep folder (results.sqlite) nor a run folder (record.json)")


def _label(key: tuple) -> str:
    _, tracker, parameters, detector, strategy, settings = key
    label = configuration_label(tracker, json.loads(parameters), strategy, json.loads(settings))
    return f"{label} ({detector})"


def _groups(records: list[RunRecord]) -> dict[tuple, dict[str, ScoredRun]]:
    """Per configuration, its runs by sequence name (what pairs runs across sets)."""
    out: dict[tuple, dict[str, ScoredRun]] = {}
    for row in with_derived(records):
        out.setdefault(configuration_of(row), {})[Path(row["sequence"]).name] = row
    return out


def _pairs(base: dict[tuple, Any], other: dict[tuple, Any]) -> list[tuple[tuple, tuple]]:
    """Configurations paired across two sets: the same one, else the only one of its family,
    tracker, detector and strategy on each side."""
    pairs = [(key, key) for key in sorted(base) if key in other]
    left = [k for k in sorted(base) if k not in other]
    right = [k for k in sorted(other) if k not in base]

    def loose(key: tuple) -> tuple:
        family, tracker, _, detector, strategy, _ = key
        return (family, tracker, detector, strategy)

    for key in left:
        matches = [k for k in right if loose(k) == loose(key)]
        if len(matches) == 1 and sum(loose(k) == loose(key) for k in left) == 1:
            pairs.append((key, matches[0]))
    return pairs


@dataclass(frozen=True)
class SetComparison:
    """One set against the first: the paired figures, and what could not be paired (said,
    not dropped)."""

    comparisons: list[Comparison]
    only_first: list[str] = field(default_factory=list)
    """Configurations of the first set with no counterpart here."""
    only_this: list[str] = field(default_factory=list)
    unshared: list[str] = field(default_factory=list)
    """Paired configurations that ran on no common sequence."""

    def regressions(self, tolerance: float, time: bool = False) -> list[Comparison]:
        """Real changes for the worse; time only when asked (``time``): two sweeps run at
        different moments differ in load, and the built-in tracker's median frame time moved
        by 54 % between two identical 4-sequence sweeps run one after the other."""
        return [c for c in self.comparisons if c.regression(tolerance) and (time or c.figure not in TIME)]

    def to_dict(self) -> dict[str, Any]:
        return {
            "comparisons": [c.to_dict() for c in self.comparisons],
            "only_first": self.only_first,
            "only_this": self.only_this,
            "no_common_sequence": self.unshared,
        }


def compare_rows(base_records: list[RunRecord], other_records: list[RunRecord]) -> SetComparison:
    base, other = _groups(base_records), _groups(other_records)
    pairs = _pairs(base, other)
    out, unshared = [], []
    for key_a, key_b in pairs:
        runs_a, runs_b = base[key_a], other[key_b]
        shared = sorted(set(runs_a) & set(runs_b))
        if not shared:
            unshared.append(f"{key_a[0]}: {_label(key_a)}")
            continue
        for figure in COMPARED:
            if figure == "rho_percent" and key_a[4] == "none":
                continue  # ρ is taken against the none run itself: 0 by definition
            a = [runs_a[name].get(figure) for name in shared]
            b = [runs_b[name].get(figure) for name in shared]
            if all(v is None for v in a + b):
                continue
            out.append(
                Comparison(
                    family=key_a[0],
                    base=_label(key_a),
                    other=_label(key_b),
                    figure=figure,
                    base_mean=stats(a).mean,
                    other_mean=stats(b).mean,
                    change=paired_change(figure, a, b),
                )
            )
    paired_a, paired_b = {a for a, _ in pairs}, {b for _, b in pairs}
    return SetComparison(
        comparisons=out,
        only_first=[f"{k[0]}: {_label(k)}" for k in sorted(base) if k not in paired_a],
        only_this=[f"{k[0]}: {_label(k)}" for k in sorted(other) if k not in paired_b],
        unshared=unshared,
    )


def format_comparisons(name: str, result: SetComparison) -> str:
    """Per configuration a block: each figure's change, its interval and p; ``*`` marks a
    significant one. What could not be paired is listed under it."""
    lines = [name]
    if not result.comparisons:
        lines.append("  no configuration of the first set ran on the same sequences here")
    block = None
    for c in result.comparisons:
        if (c.family, c.base, c.other) != block:
            block = (c.family, c.base, c.other)
            config = c.base if c.base == c.other else f"{c.base} -> {c.other}"
            lines.append(f"{c.family} · {config}")
            lines.append(
                f"  {'figure':24s} {'first':>9s} {'this':>9s} {'change':>9s} {'95% interval':>21s} "
                f"{'pairs':>5s} {'p(worse)':>9s}"
            )
        ch = c.change
        ratio = c.figure in RATIO
        interval = f"[{change_text(ch.ci_low, ratio)}, {change_text(ch.ci_high, ratio)}]"
        lines.append(
            f"  {c.figure:24s} {value_text(c.base_mean):>9s} {value_text(c.other_mean):>9s} "
            f"{change_text(ch.change, ratio):>9s} {interval:>21s} {ch.pairs:5d} "
            f"{'-' if ch.p_worse is None else f'{ch.p_worse:.3g}':>9s}{' *' if c.significant else ''}"
        )
    if result.comparisons:
        significant = sum(c.significant for c in result.comparisons)
        total = len(result.comparisons)
        lines.append(f"{significant} of {total} changes are significant (*: two-sided p < {ALPHA})")
    for title, items in (
        ("only in the first set", result.only_first),
        ("only in this set", result.only_this),
        ("paired but on no common sequence", result.unshared),
    ):
        if items:
            lines.append(f"{title}, not compared: " + "; ".join(items))
    return "\n".join(lines)


def value_text(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def change_text(value: float | None, ratio: bool) -> str:
    if value is None:
        return "-"
    return f"{value:+.1%}" if ratio else f"{value:+.4g}"
