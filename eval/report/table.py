"""Compare strategies over sequences as a text table (``benchmarks/strategies.py``)."""

from __future__ import annotations

from typing import Any

from depotbench.core.text_table import Column, cell, render
from depotbench.eval.metrics.accuracy import improvement_rate


def summarise(runs: dict[str, dict[str, dict[str, Any]]]) -> list[dict[str, Any]]:
    """One row per (sequence, strategy) with ATE, rho against 'none', precision and recall."""
    rows = []
    for sequence, by_strategy in runs.items():
        baseline = by_strategy.get("none", {}).get("ate_m", {}).get("rmse")
        for strategy, metrics in by_strategy.items():
            ate = metrics.get("ate_m", {}).get("rmse")
            rejection = metrics.get("rejection", {})
            rho = improvement_rate(baseline, ate) if baseline and ate is not None and baseline > 0 else None
            rows.append(
                {
                    "sequence": sequence,
                    "strategy": strategy,
                    "ate_rmse_m": ate,
                    "rho_percent": rho,
                    "tracked": f"{metrics['tracked_frames']}/{metrics['frames']}",
                    "precision": rejection.get("precision"),
                    "recall": rejection.get("recall"),
                    "tracking_ms": metrics["stage_time"]["tracking_total"]["mean_ms"],
                }
            )
    return rows


COLUMNS = [
    Column("sequence", "left"),
    Column("strategy", "left"),
    Column("ATE rmse m"),
    Column("rho %"),
    Column("tracked"),
    Column("precision"),
    Column("recall"),
    Column("track ms"),
]


def format_table(rows: list[dict[str, Any]]) -> str:
    return render(
        COLUMNS,
        [
            [
                r["sequence"],
                r["strategy"],
                cell(r["ate_rmse_m"], ".4f"),
                cell(r["rho_percent"], ".1f"),
                r["tracked"],
                cell(r["precision"], ".3f"),
                cell(r["recall"], ".3f"),
                cell(r["tracking_ms"], ".1f"),
            ]
            for r in rows
        ],
    )
