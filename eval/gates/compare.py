"""Two or more result sets side by side: per family and configuration, how each figure
changed from the first set, paired by sequence, with its 95 % interval and a one-sided
paired test, so that a real change is told from run-to-run noise (as evo's ``evo_res``
compares results, with statistics over seeds added).

A configuration is paired with the same configuration of the other set; where the sets
differ in a tracker's parameters or a strategy's settings (so no configuration is in both),
a configuration is paired with the one configuration on the other side that shares
everything else (then the one that shares all but its settings, then all but both), and
the pair says which fields differ. Runs are paired by the sequence's fingerprint (its
files' content and place), never by its folder's name: two folders named ``seq`` are two
sequences, and two runs of one configuration on one sequence are reported, not compared.
Each set holds one program version per tracker (``versions.one_version``).
"""

from __future__ import annotations

import json
import math
import sys
from array import array
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError
from depotbench.core.text_table import Column, render
from depotbench.eval.metrics.figures import (
    DERIVED_COLUMNS,
    FIGURES,
    HIGHER_IS_BETTER,
    RATIO,
    TIME,
    configuration_of,
    is_baseline,
    parameters_of,
    with_derived,
)
from depotbench.eval.metrics.record import UNKNOWN_FINGERPRINT, RunRecord
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
    differs: str = ""
    """What differs between the two configurations (``window 3 -> 5``), empty when they are one."""

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
            "differs": self.differs,
            **self.change.to_dict(),
            "significant": self.significant,
        }


def load_rows(folder: Path, chosen: tuple[str, ...] = (), option: str = "--fingerprint") -> list[RunRecord]:
    """A sweep's or check's runs (results.sqlite), or a run folder's one run (record.json),
    with one program version per tracker (``chosen``: the fingerprints ``option`` gave, for a
    folder holding several; see ``versions.one_version``)."""
    from depotbench.core.files import read_text
    from depotbench.eval.metrics.record import FIELDS
    from depotbench.eval.metrics.versions import one_version
    from depotbench.eval.sweep.store import ResultStore, checked_row

    if (folder / "results.sqlite").is_file():
        with ResultStore(folder / "results.sqlite", readonly=True) as store:
            return one_version(store.records(), chosen, folder, option)
    if (folder / "record.json").is_file():
        try:
            row = json.loads(read_text(folder / "record.json", 1 << 20, "run record"))
        except ValueError as exc:
            raise InputError(f"{folder / 'record.json'}: not valid JSON ({exc})") from None
        if not isinstance(row, dict) or "key" not in row:
            raise InputError(f"{folder / 'record.json'}: not a run record")
        known = checked_row(
            {name: value for name, value in row.items() if name in FIELDS},
            str(folder / "record.json"),
            "the file was changed outside depotbench",
        )
        try:
            record = RunRecord.from_row(known)
        except KeyError as exc:
            raise InputError(f"{folder / 'record.json'}: not a run record (no {exc.args[0]})") from None
        return one_version([record], chosen, folder, option)
    raise InputError(f"{folder}: neither a sweep folder (results.sqlite) nor a run folder (record.json)")


def _label(key: tuple) -> str:
    _, tracker, parameters, detector, strategy, settings = key
    label = configuration_label(tracker, json.loads(parameters), strategy, json.loads(settings))
    return f"{label} ({detector})"


def sequence_of(row: Any) -> str:
    """What pairs a run with another set's: its sequence's fingerprint (the content and place
    of its files), the folder itself for a row that has none."""
    return row.get("sequence_fingerprint") or row["sequence"]


@dataclass(frozen=True, slots=True)
class _Run:
    """What compare keeps of a run: its sequence folder's name (for messages) and its
    ``COMPARED`` figures in that order, NaN where it has none (an array: 13 doubles, 170 bytes,
    where a record takes some 7 kB)."""

    name: str
    figures: array

    def get(self, index: int) -> float | None:
        value = self.figures[index]
        return None if math.isnan(value) else value


@dataclass(frozen=True)
class RunSet:
    """A result set as compare pairs it: per configuration (``configuration_of``), its runs
    by sequence (``sequence_of``)."""

    runs: dict[tuple, dict[str, _Run]]
    duplicates: dict[tuple, dict[str, int]]
    """Per configuration, the sequences it ran on more than once, and how many times."""

    @classmethod
    def of(cls, items: Iterable[tuple[tuple, str, str, tuple]]) -> RunSet:
        """From (configuration, sequence, folder name, figures) per run."""
        runs: dict[tuple, dict[str, _Run]] = {}
        duplicates: dict[tuple, dict[str, int]] = {}
        for config, sequence, name, figures in items:
            mine = runs.setdefault(config, {})
            sequence = sys.intern(sequence)  # a few hundred sequences under 200,000 rows
            if sequence in mine:
                seen = duplicates.setdefault(config, {})
                seen[sequence] = seen.get(sequence, 1) + 1
            values = array("d", (math.nan if v is None else v for v in figures))
            mine[sequence] = _Run(sys.intern(name), values)
        return cls(runs, duplicates)

    @classmethod
    def of_records(cls, records: Iterable[RunRecord]) -> RunSet:
        return cls.of(
            (configuration_of(row), sequence_of(row), Path(row["sequence"]).name, _figures(row))
            for row in with_derived(records)
        )


def _figures(row: Any) -> tuple:
    return tuple(row.get(name) for name in COMPARED)


STREAMED = (
    "family",
    "tracker",
    "parameters",
    "detector",
    "strategy",
    "settings",
    "sequence",
    "sequence_fingerprint",
    "tracker_fingerprint",
)
"""The columns a streamed store gives compare besides the figures it compares."""


def load_set(folder: Path, chosen: tuple[str, ...] = (), option: str = "--fingerprint") -> RunSet:
    """``load_rows``'s runs as compare keeps them; a results store is read a row at a time,
    its needed columns only (a 200,000-row store: ``docs/statistics.md``)."""
    if not (folder / "results.sqlite").is_file():
        return RunSet.of_records(load_rows(folder, chosen, option))
    from depotbench.eval.metrics.accuracy import improvement_rate
    from depotbench.eval.metrics.versions import chosen_versions, version_of
    from depotbench.eval.sweep.store import ResultStore

    stored = [name for name in COMPARED if name not in DERIVED_COLUMNS]
    with ResultStore(folder / "results.sqlite", readonly=True) as store:
        counts: dict[str, Counter[str]] = {}
        for tracker, fingerprint in store.columns(("tracker", "tracker_fingerprint")):
            counts.setdefault(tracker, Counter())[fingerprint or UNKNOWN_FINGERPRINT] += 1
        keep = chosen_versions(counts, chosen, folder, option)

        def rows():
            for values in store.columns((*STREAMED, *stored)):
                row = dict(zip(STREAMED, values[: len(STREAMED)], strict=True))
                if keep.get(row["tracker"], version_of(row)) == version_of(row):
                    yield row, values[len(STREAMED) :]

        def where(row: dict) -> tuple:  # what rho pairs a run with its none run by
            return (row["sequence"], row["tracker"], parameters_of(row), row["detector"])

        figures = dict(zip(stored, range(len(stored)), strict=True))
        ate = figures["ate_rmse_m"]
        baseline = {where(row): values[ate] for row, values in rows() if is_baseline(row)}

        def items():
            for row, values in rows():
                base, mine = baseline.get(where(row)), values[ate]
                rho = improvement_rate(base, mine) if base and mine is not None and base > 0 else None
                derived = {"rho_percent": rho}
                yield (
                    configuration_of(row),
                    sequence_of(row),
                    Path(row["sequence"]).name,
                    tuple(derived[n] if n in derived else values[figures[n]] for n in COMPARED),
                )

        return RunSet.of(items())


def _without_parameters(key: tuple) -> tuple:
    family, tracker, _, detector, strategy, settings = key
    return (family, tracker, detector, strategy, settings)


def _without_settings(key: tuple) -> tuple:
    return key[:5]


def _loose(key: tuple) -> tuple:
    family, tracker, _, detector, strategy, _ = key
    return (family, tracker, detector, strategy)


RELAXED = (_without_parameters, _without_settings, _loose)
"""How configurations that are in one set only are paired, in turn: sharing all but the
tracker's parameters (two sweeps of one program parameter), all but the settings, all but
both; at each step only where exactly one configuration on each side shares it."""


def _pairs(base: dict[tuple, Any], other: dict[tuple, Any]) -> list[tuple[tuple, tuple]]:
    """Configurations paired across two sets: the same one, else (``RELAXED``) the one on each
    side that shares the most with it."""
    pairs = [(key, key) for key in sorted(base) if key in other]
    left = [k for k in sorted(base) if k not in other]
    right = [k for k in sorted(other) if k not in base]
    for relax in RELAXED:
        for key in list(left):
            matches = [k for k in right if relax(k) == relax(key)]
            if len(matches) == 1 and sum(relax(k) == relax(key) for k in left) == 1:
                pairs.append((key, matches[0]))
                left.remove(key)
                right.remove(matches[0])
    return pairs


def _differs(key_a: tuple, key_b: tuple) -> str:
    """The parameters and settings two paired configurations differ in, ``name a -> b``."""
    out = []
    for index in (2, 5):  # parameters, settings: sorted JSON objects
        a, b = json.loads(key_a[index] or "{}"), json.loads(key_b[index] or "{}")
        for name in sorted(set(a) | set(b)):
            if a.get(name) != b.get(name):
                out.append(f"{name} {a.get(name, '-')} -> {b.get(name, '-')}")
    return ", ".join(out)


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
    duplicates: list[str] = field(default_factory=list)
    """Configurations with more than one run on one sequence (a folder resumed after the bench
    changed): those sequences are not compared, since which run stands for them is unknown."""

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
            "duplicates": self.duplicates,
        }


def compare_rows(
    base_records: list[RunRecord] | RunSet, other_records: list[RunRecord] | RunSet
) -> SetComparison:
    """Each figure's paired change per configuration from the first set to the other (sets as
    records, or as ``load_set`` streamed them)."""
    grouped_a, grouped_b = (
        group if isinstance(group, RunSet) else RunSet.of_records(group)
        for group in (base_records, other_records)
    )
    base, other = grouped_a.runs, grouped_b.runs
    pairs = _pairs(base, other)
    out, unshared, duplicates = [], [], []
    for key_a, key_b in pairs:
        runs_a, runs_b = base[key_a], other[key_b]
        twice = {**grouped_a.duplicates.get(key_a, {}), **grouped_b.duplicates.get(key_b, {})}
        for sequence in sorted(set(twice) & (set(runs_a) | set(runs_b))):
            name = (runs_a.get(sequence) or runs_b[sequence]).name
            duplicates.append(f"{key_a[0]}: {_label(key_a)} on {name} ({twice[sequence]} runs)")
        shared = sorted((set(runs_a) & set(runs_b)) - set(twice))
        if not shared:
            unshared.append(f"{key_a[0]}: {_label(key_a)}")
            continue
        differs = _differs(key_a, key_b)
        for index, figure in enumerate(COMPARED):
            if figure == "rho_percent" and key_a[4] == "none":
                continue  # ρ is taken against the none run itself: 0 by definition
            a = [runs_a[name].get(index) for name in shared]
            b = [runs_b[name].get(index) for name in shared]
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
                    differs=differs,
                )
            )
    paired_a, paired_b = {a for a, _ in pairs}, {b for _, b in pairs}
    return SetComparison(
        comparisons=out,
        only_first=[f"{k[0]}: {_label(k)}" for k in sorted(base) if k not in paired_a],
        only_this=[f"{k[0]}: {_label(k)}" for k in sorted(other) if k not in paired_b],
        unshared=unshared,
        duplicates=duplicates,
    )


def format_comparisons(name: str, result: SetComparison) -> str:
    """Per configuration a block: each figure's change, its interval and p; ``*`` marks a
    significant one. What could not be paired is listed under it."""
    lines = [name]
    if not result.comparisons:
        lines.append("  no configuration of the first set ran on the same sequences here")
    columns = [Column("figure", "left"), Column("first"), Column("this"), Column("change")]
    columns += [Column("95% interval"), Column("pairs"), Column("p(worse)"), Column("", "left")]
    blocks: dict[tuple[str, str, str, str], list[list[str]]] = {}  # family, base, other, differs
    for c in result.comparisons:
        ch = c.change
        ratio = c.figure in RATIO
        blocks.setdefault((c.family, c.base, c.other, c.differs), []).append(
            [
                c.figure,
                value_text(c.base_mean),
                value_text(c.other_mean),
                change_text(ch.change, ratio),
                f"[{change_text(ch.ci_low, ratio)}, {change_text(ch.ci_high, ratio)}]",
                str(ch.pairs),
                "-" if ch.p_worse is None else f"{ch.p_worse:.3g}",
                "*" if c.significant else "",
            ]
        )
    for (family, base, other, why), rows in blocks.items():
        config = base if base == other else f"{base} -> {other}"
        lines.append(f"{family} · {config}" + (f" (differs: {why})" if why else ""))
        lines.append(render(columns, rows, indent=2))
    if result.comparisons:
        significant = sum(c.significant for c in result.comparisons)
        total = len(result.comparisons)
        lines.append(f"{significant} of {total} changes are significant (*: two-sided p < {ALPHA})")
    for title, items in (
        ("only in the first set", result.only_first),
        ("only in this set", result.only_this),
        ("paired but on no common sequence", result.unshared),
        ("more than one run of a configuration on one sequence", result.duplicates),
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
