"""Compare strategies over sequences as a text table (``benchmarks/strategies.py``)."""

from __future__ import annotations

from typing import Any

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


def format_table(rows: list[dict[str, Any]]) -> str:
    def show(value: Any, fmt: str) -> str:
        width = int(fmt.split(".")[0])
        return "-".rjust(width) if value is None else format(value, fmt)

    header = (
        f"{'sequence':14s} {'strategy':18s} {'ATE rmse m':>11s} {'rho %':>7s} {'tracked':>8s} "
        f"{'precision':>9s} {'recall':>7s} {'track ms':>9s}"
    )
    lines = [header, "-" * len(header)]
    for r in rows:
        lines.append(
            f"{r['sequence']:14s} {r['strategy']:18s} {show(r['ate_rmse_m'], '11.4f')} "
            f"{show(r['rho_percent'], '7.1f')} {r['tracked']:>8s} {show(r['precision'], '9.3f')} "
            f"{show(r['recall'], '7.3f')} {show(r['tracking_ms'], '9.1f')}"
        )
    return "\n".join(lines)
