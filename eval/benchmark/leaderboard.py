"""A static HTML leaderboard over several results files of one benchmark: one row per
results file (a tracker configuration), a column per scenario, sortable in the browser, with
the spread over seeds. The page is a Jinja2 template (``templates/leaderboard.html.j2``,
autoescaped) and its style sheet beside it, inlined so the page is one file."""

from __future__ import annotations

from importlib import resources
from typing import Any

import numpy as np
from depotbench.core.errors import InputError
from depotbench.eval.benchmark.table import (
    ate_medians,
    check_comparable,
    parameter_text,
    per_sequence,
    rows,
    tracker_label,
    tracker_labels,
)


def _cell(median: float | None, low: float | None = None, high: float | None = None) -> dict[str, Any]:
    if median is None:
        return {"text": "-", "sort": "", "spread": ""}
    spread = "" if low is None or high is None or high <= low else f"{low * 1000:.1f}-{high * 1000:.1f}"
    return {"text": f"{median * 1000:.1f}", "sort": f"{median:.9g}", "spread": spread}


def _overall(results: dict[str, Any]) -> float | None:
    """The median over sequences of each sequence's median ATE RMSE."""
    medians = [m for _, m in ate_medians(results["sequences"]) if m is not None]
    return float(np.median(medians)) if medians else None


def entries(loaded: list[dict[str, Any]], baseline: dict[str, Any] | None) -> tuple[list[str], list[dict]]:
    """The scenarios (columns) and one entry per results file, best overall ATE first."""
    names = {r["benchmark"] for r in loaded}
    if len(names) > 1:
        raise InputError(
            f"the results score different benchmarks ({', '.join(sorted(names))}): one page each"
        )
    scenarios = list(dict.fromkeys(s["scenario"] for r in loaded for s in r["sequences"]))
    base_all = None
    if baseline is not None:
        base_all = _overall(baseline)
    found = []
    for results, label in zip(loaded, tracker_labels(loaded), strict=True):
        if baseline is not None:
            check_comparable(results, baseline)
        by_scenario = {row.scenario: row for row in rows(results)}
        cells = []
        for scenario in scenarios:
            figure = by_scenario[scenario].figures[("ate_m", "rmse")] if scenario in by_scenario else None
            cells.append(_cell(None) if figure is None else _cell(figure.median, figure.low, figure.high))
        sequences = per_sequence(results)
        medians = [m for _, m in ate_medians(results["sequences"]) if m is not None]
        overall = float(np.median(medians)) if medians else None
        rho = (
            None
            if base_all is None or overall is None or base_all <= 0
            else (base_all - overall) / base_all * 100
        )
        found.append(
            {
                "label": label,
                "parameters": parameter_text(results),
                "fingerprint": results["tracker"]["fingerprint"],
                "path": results["_path"],
                "version": results["depotbench"],
                "sequences": len(sequences),
                "repeats": results["repeats"],
                "runs": sum(q["runs"] for q in sequences.values()),
                "failed": sum(q["failed"] for q in sequences.values()),
                "cells": cells,
                "overall": _cell(overall, min(medians, default=None), max(medians, default=None)),
                "overall_value": overall,
                "tracked": float(np.median([s for q in sequences.values() for s in q["shares"]])) * 100,
                "rho": "-" if rho is None else f"{rho:.1f}",
                "rho_sort": "" if rho is None else f"{rho:.6g}",
            }
        )
    found.sort(key=lambda e: (e["overall_value"] is None, e["overall_value"] or 0.0))
    return scenarios, found


def page(loaded: list[dict[str, Any]], baseline: dict[str, Any] | None = None) -> str:
    import jinja2

    scenarios, found = entries(loaded, baseline)
    folder = resources.files("depotbench.eval.benchmark.templates")
    environment = jinja2.Environment(
        autoescape=True, undefined=jinja2.StrictUndefined, keep_trailing_newline=True
    )
    template = environment.from_string(folder.joinpath("leaderboard.html.j2").read_text(encoding="utf-8"))
    label = None if baseline is None else tracker_label(baseline)
    return template.render(
        benchmark=loaded[0]["benchmark"],
        scenarios=scenarios,
        entries=found,
        baseline=label,
        css=folder.joinpath("leaderboard.css").read_text(encoding="utf-8"),
    )
