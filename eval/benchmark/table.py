"""The papers' tables from results files: per scenario (TUM's "sequence"), each error's RMSE,
mean, median and STD, the share of frames tracked and rho against a chosen baseline, with
the spread over seeds and over repeats. Printed as Markdown, written as Markdown, LaTeX
(booktabs) and CSV.

How figures combine, so that a table can be checked by hand:

- a sequence's figure is the median over its repeats (the built-in tracker has one);
- a scenario's figure is the median over its sequences (seeds) of those, with their
  minimum and maximum (the spread over seeds);
- the repeat spread of a scenario is the median, over its sequences, of max - min over
  each sequence's repeats: how far two runs of one sequence fall apart;
- rho = (baseline - figure) / baseline x 100 % on the scenario's ATE RMSE, the baseline
  taken the same way from the baseline's results on the same sequences (Yu et al. 2018's
  improvement over ORB-SLAM2, here over any results file: ``none``, ORB-SLAM3, a user's
  ``reject=0``, an earlier release).
"""

from __future__ import annotations

import csv
import io
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from depotbench.core.errors import InputError
from depotbench.eval.benchmark.results import METRICS, STATISTICS

UNITS = {
    "ate_m": ("ATE", "mm", 1000.0),
    "rpe_translation_m": ("RPE-t", "mm", 1000.0),
    "rpe_rotation_deg": ("RPE-r", "deg", 1.0),
}
"""Each error's column name, unit and factor from the stored unit (the papers print mm and deg)."""


@dataclass(frozen=True)
class Figure:
    median: float
    low: float
    high: float
    """The spread over seeds: the smallest and largest sequence figure."""
    repeat_spread: float
    """The median over sequences of max - min over a sequence's repeats (0 with one run)."""


@dataclass(frozen=True)
class Row:
    """One scenario of one results file."""

    scenario: str
    tracker: str
    sequences: int
    runs: int
    failed: int
    figures: dict[tuple[str, str], Figure | None]
    """(metric, statistic): None where no run of the scenario was scored."""
    tracked: Figure
    rho: float | None

    def to_dict(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario,
            "tracker": self.tracker,
            "sequences": self.sequences,
            "runs": self.runs,
            "failed": self.failed,
            "figures": {f"{m}_{s}": None if f is None else asdict(f) for (m, s), f in self.figures.items()},
            "tracked_share": asdict(self.tracked),
            "rho_percent": self.rho,
        }


def tracker_label(results: dict[str, Any]) -> str:
    """The tracker's name, its strategy and every parameter: one results file on its own
    (a CSV line, a baseline named in a title)."""
    return _label(results, _parameters(results))


def tracker_labels(loaded: list[dict[str, Any]]) -> list[str]:
    """Each results file's name in a table of several: its tracker and strategy, and of its
    parameters only those that tell it from another file of the same tracker and strategy
    (ORB-SLAM3's settings alone are six pairs, the same in every file; ``parameter_notes``
    prints them all under the table)."""
    bases = [_label(r, {}) for r in loaded]
    labels = []
    for results, base in zip(loaded, bases, strict=True):
        peers = [_parameters(r) for r, b in zip(loaded, bases, strict=True) if b == base]
        mine = _parameters(results)
        varying = {k: v for k, v in mine.items() if any(p.get(k) != v for p in peers)}
        labels.append(_label(results, varying))
    return labels


def parameter_notes(loaded: list[dict[str, Any]]) -> list[str]:
    """One line per results file with parameters: its table name and all of them."""
    return [
        f"{label}: {parameter_text(r)}"
        for r, label in zip(loaded, tracker_labels(loaded), strict=True)
        if _parameters(r)
    ]


def parameter_text(results: dict[str, Any]) -> str:
    """Every parameter of the tracker, NAME=VALUE by name."""
    return " ".join(f"{k}={v}" for k, v in sorted(_parameters(results).items()))


def _parameters(results: dict[str, Any]) -> dict[str, Any]:
    return dict(results["tracker"].get("parameters", {}))


def _label(results: dict[str, Any], parameters: dict[str, Any]) -> str:
    t = results["tracker"]
    label = t["label"] if t["kind"] != "builtin" else f"builtin {t['strategy']}"
    if t["kind"] != "builtin" and t["strategy"] != "none":
        label += f" {t['strategy']}"
    return f"{label} {' '.join(f'{k}={v}' for k, v in sorted(parameters.items()))}".strip()


def ate_medians(sequences: list[dict[str, Any]]) -> list[tuple[str, float | None]]:
    """Each sequence's scenario and its median ATE RMSE over its scored repeats (None where
    no repeat was scored), in the results' order."""
    return [
        (q["scenario"], float(np.median(v)) if (v := q["values"][("ate_m", "rmse")]) else None)
        for q in per_sequence({"sequences": sequences}).values()
    ]


def per_sequence(results: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Each sequence's repeats: per (metric, statistic) the scored runs' values, the tracked
    shares and the failed runs."""
    out = {}
    for sequence in results["sequences"]:
        values: dict[tuple[str, str], list[float]] = {(m, s): [] for m in METRICS for s in STATISTICS}
        shares, failed = [], 0
        for run in sequence["runs"]:
            if run["status"] != "ok":
                failed += 1
                shares.append(0.0)
                continue
            figures = run["figures"]
            shares.append(figures["tracked_share"])
            if figures["errors"] is None:
                continue
            for m in METRICS:
                for s in STATISTICS:
                    values[(m, s)].append(figures["errors"][m][s])
        out[sequence["name"]] = {
            "scenario": sequence["scenario"],
            "seed": sequence["seed"],
            "files_key": sequence["files_key"],
            "values": values,
            "shares": shares,
            "runs": len(sequence["runs"]),
            "failed": failed,
        }
    return out


def _figure(per_seq: list[list[float]]) -> Figure | None:
    scored = [v for v in per_seq if v]
    if not scored:
        return None
    medians = [float(np.median(v)) for v in scored]
    return Figure(
        float(np.median(medians)),
        min(medians),
        max(medians),
        float(np.median([max(v) - min(v) for v in scored])),
    )


def rows(
    results: dict[str, Any], baseline: dict[str, Any] | None = None, label: str | None = None
) -> list[Row]:
    """The table's rows of ``results``, one per scenario in the benchmark's order, the tracker
    called ``label`` (default: its name with every parameter)."""
    sequences = per_sequence(results)
    base = None
    if baseline is not None:
        check_comparable(results, baseline)
        base = {r.scenario: r for r in rows(baseline)}
    found = []
    for scenario in dict.fromkeys(s["scenario"] for s in sequences.values()):
        mine = [s for s in sequences.values() if s["scenario"] == scenario]
        figures = {(m, s): _figure([q["values"][(m, s)] for q in mine]) for m in METRICS for s in STATISTICS}
        tracked = _figure([q["shares"] for q in mine])
        assert tracked is not None  # every sequence has at least one run
        rho = None
        if base is not None:
            theirs, ours = base[scenario].figures[("ate_m", "rmse")], figures[("ate_m", "rmse")]
            if theirs is not None and ours is not None and theirs.median > 0:
                rho = (theirs.median - ours.median) / theirs.median * 100.0
        found.append(
            Row(
                scenario,
                tracker_label(results) if label is None else label,
                len(mine),
                sum(q["runs"] for q in mine),
                sum(q["failed"] for q in mine),
                figures,
                tracked,
                rho,
            )
        )
    return found


def check_comparable(results: dict[str, Any], baseline: dict[str, Any]) -> None:
    """A baseline scored on other sequences (another benchmark, other bytes) gives no rho."""
    if results["benchmark"] != baseline["benchmark"]:
        raise InputError(
            f"{baseline['_path']}: the baseline scored {baseline['benchmark']}, "
            f"the results {results['benchmark']}"
        )
    theirs = {s["name"]: s["files_key"] for s in baseline["sequences"]}
    for sequence in results["sequences"]:
        if theirs.get(sequence["name"]) != sequence["files_key"]:
            raise InputError(
                f"{baseline['_path']}: its {sequence['name']} is not the one {results['_path']} scored "
                "(missing, or other bytes)"
            )


COLUMNS = [(m, s) for m in METRICS for s in STATISTICS]


def _cell(figure: Figure | None, factor: float, spread: bool, repeats: bool) -> str:
    if figure is None:
        return "-"
    text = f"{figure.median * factor:.1f}" if factor != 1.0 else f"{figure.median:.3f}"
    if spread and figure.high > figure.low:
        lo, hi = figure.low * factor, figure.high * factor
        text += f" ({lo:.1f}-{hi:.1f})" if factor != 1.0 else f" ({lo:.3f}-{hi:.3f})"
    if repeats:
        text += (
            f" ±{figure.repeat_spread * factor / 2:.1f}"
            if factor != 1.0
            else f" ±{figure.repeat_spread / 2:.3f}"
        )
    return text


def _headers(with_rho: bool) -> list[str]:
    heads = ["scenario", "tracker", "seqs x runs"]
    heads += [f"{UNITS[m][0]} {s.upper() if s in ('rmse', 'std') else s} [{UNITS[m][1]}]" for m, s in COLUMNS]
    heads += ["tracked %"] + (["rho %"] if with_rho else [])
    return heads


def _cells(row: Row, with_rho: bool, repeats: bool) -> list[str]:
    runs = f"{row.sequences} x {row.runs // max(row.sequences, 1)}"
    if row.failed:
        runs += f" ({row.failed} failed)"
    cells = [row.scenario, row.tracker, runs]
    cells += [_cell(row.figures[c], UNITS[c[0]][2], True, repeats) for c in COLUMNS]
    cells.append(f"{row.tracked.median * 100:.1f}")
    if with_rho:
        cells.append("-" if row.rho is None else f"{row.rho:.1f}")
    return cells


def markdown(all_rows: list[Row], title: str, repeats: bool, notes: list[str] | None = None) -> str:
    """The table, its reading, and ``notes`` (each tracker's parameters) under it."""
    with_rho = any(r.rho is not None for r in all_rows)
    heads = _headers(with_rho)
    lines = [f"# {title}", "", "| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    lines += ["| " + " | ".join(_cells(r, with_rho, repeats)) + " |" for r in all_rows]
    lines += [
        "",
        "Each cell: the median over seeds of each sequence's median over repeats, (the smallest-largest "
        "sequence)" + (", ±half the median spread between repeats" if repeats else "") + ".",
    ]
    if notes:
        lines += ["", "Parameters:", *(f"- {note}" for note in notes)]
    return "\n".join(lines) + "\n"


def _tex(text: str) -> str:
    return (
        text.replace("\\", "\\textbackslash{}")
        .replace("_", "\\_")
        .replace("%", "\\%")
        .replace("&", "\\&")
        .replace("±", "$\\pm$")
    )


def latex(all_rows: list[Row], title: str, repeats: bool, notes: list[str] | None = None) -> str:
    """A booktabs table: ATE and RPE column groups, as the source papers print them; ``notes``
    (each tracker's parameters) as comments after it."""
    with_rho = any(r.rho is not None for r in all_rows)
    heads = _headers(with_rho)
    spec = "ll" + "r" * (len(heads) - 2)
    groups = " & ".join(
        f"\\multicolumn{{{len(STATISTICS)}}}{{c}}{{{UNITS[m][0]} [{UNITS[m][1]}]}}" for m in METRICS
    )
    lines = [
        "% " + title,
        "\\begin{tabular}{" + spec + "}",
        "\\toprule",
        " & ".join(["", "", "", groups, "", *([""] if with_rho else [])]) + " \\\\",
        " & ".join(
            ["Scenario", "Tracker", "Seqs $\\times$ runs"]
            + [s.upper() if s in ("rmse", "std") else s.capitalize() for _, s in COLUMNS]
            + ["Tracked \\%"]
            + (["$\\rho$ \\%"] if with_rho else [])
        )
        + " \\\\",
        "\\midrule",
    ]
    lines += [" & ".join(_tex(c) for c in _cells(r, with_rho, repeats)) + " \\\\" for r in all_rows]
    lines += ["\\bottomrule", "\\end{tabular}"]
    lines += [f"% {note}" for note in notes or []]
    return "\n".join(lines) + "\n"


def csv_text(results: list[dict[str, Any]], baseline: dict[str, Any] | None) -> str:
    """One line per sequence and results file: every figure's median over repeats, its
    minimum and maximum over repeats, the tracked share and the sequence's own rho."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    stats = [f"{m}_{s}" for m, s in COLUMNS]
    writer.writerow(
        ["benchmark", "tracker", "fingerprint", "scenario", "sequence", "seed", "runs", "failed"]
        + [f"{c}{suffix}" for c in stats for suffix in ("", "_min", "_max")]
        + ["tracked_share", "rho_percent"]
    )
    base = per_sequence(baseline) if baseline is not None else {}
    for r in results:
        if baseline is not None:
            check_comparable(r, baseline)
        for name, q in per_sequence(r).items():
            cells: list[Any] = [
                r["benchmark"],
                tracker_label(r),
                r["tracker"]["fingerprint"],
                q["scenario"],
                name,
                q["seed"],
                q["runs"],
                q["failed"],
            ]
            for c in COLUMNS:
                v = q["values"][c]
                cells += [float(np.median(v)), min(v), max(v)] if v else ["", "", ""]
            cells.append(float(np.median(q["shares"])))
            rho = ""
            theirs = base.get(name, {}).get("values", {}).get(("ate_m", "rmse"))
            mine = q["values"][("ate_m", "rmse")]
            if theirs and mine and np.median(theirs) > 0:
                rho = (float(np.median(theirs)) - float(np.median(mine))) / float(np.median(theirs)) * 100.0
            cells.append(rho)
            writer.writerow(cells)
    return buffer.getvalue()


@dataclass(frozen=True)
class FreshComparison:
    """A tracker's ATE RMSE on the benchmark's seeds beside fresh ones: does its tuning carry
    over? Each fresh sequence is paired with a frozen one of its scenario (the i-th with the
    i-th), so the comparison is within scenarios; the change is the geometric mean of the
    fresh/frozen ratios less 1, with its 95 % bootstrap interval and the one-sided paired
    t-test on the log ratios that the fresh seeds are worse (``paired_change``)."""

    scenarios: list[tuple[str, float | None, float | None]]
    """(scenario, median over its frozen sequences, over its fresh ones) in metres."""
    pairs: int
    change: float | None
    ci_low: float | None
    ci_high: float | None
    p_worse: float | None

    @property
    def carries_over(self) -> bool | None:
        return None if self.p_worse is None else self.p_worse >= 0.05

    def to_dict(self) -> dict[str, Any]:
        return asdict(self) | {"carries_over": self.carries_over}


def fresh_comparison(results: dict[str, Any]) -> FreshComparison | None:
    from depotbench.eval.metrics.statistics import paired_change

    fresh = results.get("fresh")
    if not fresh:
        return None

    def medians(sequences: list[dict[str, Any]]) -> dict[str, list[float | None]]:
        by_scenario: dict[str, list[float | None]] = {}
        for scenario, value in ate_medians(sequences):
            by_scenario.setdefault(scenario, []).append(value)
        return by_scenario

    frozen, drawn = medians(results["sequences"]), medians(fresh["sequences"])
    base: list[float | None] = []
    other: list[float | None] = []
    scenarios = []
    for scenario, theirs in drawn.items():
        ours = frozen.get(scenario, [])
        base += ours[: len(theirs)]
        other += theirs[: len(ours)]

        def median(values: list[float | None]) -> float | None:
            kept = [v for v in values if v is not None]
            return float(np.median(kept)) if kept else None

        scenarios.append((scenario, median(ours), median(theirs)))
    change = paired_change("ate_rmse_m", base, other)
    return FreshComparison(
        scenarios, change.pairs, change.change, change.ci_low, change.ci_high, change.p_worse
    )


def fresh_markdown(comparison: FreshComparison, count: int) -> str:
    lines = [
        f"## Frozen seeds beside {count} fresh seeds a scenario (ATE RMSE, mm)",
        "",
        "| scenario | frozen seeds | fresh seeds |",
        "|---|---|---|",
    ]
    for scenario, ours, theirs in comparison.scenarios:
        show = [("-" if v is None else f"{v * 1000:.1f}") for v in (ours, theirs)]
        lines.append(f"| {scenario} | {show[0]} | {show[1]} |")
    if comparison.change is None:
        verdict = "no pair of scored runs to compare"
    else:
        interval = (
            ""
            if comparison.ci_low is None
            else f" (95 % interval {comparison.ci_low * 100:+.0f} to {comparison.ci_high * 100:+.0f} %)"
        )
        p = "n/a" if comparison.p_worse is None else f"{comparison.p_worse:.3g}"
        verdict = (
            f"fresh seeds {comparison.change * 100:+.0f} %{interval} over {comparison.pairs} pairs, "
            f"p = {p} that they are worse: "
            + (
                "the figures on the frozen seeds do not carry over (tuned to them?)"
                if comparison.carries_over is False
                else "no evidence that the frozen seeds flatter this tracker"
            )
        )
    return "\n".join([*lines, "", verdict]) + "\n"
