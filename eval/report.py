"""Compare strategies over sequences: a table, machine-readable JSON and a plot."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from eval.metrics import improvement_rate
from sim.files import dumps_json
from sim.output import write_text_atomic


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


def plot(rows: list[dict[str, Any]], path: Path) -> bool:
    """Bar chart of ATE per sequence and strategy; False when matplotlib is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    sequences = list(dict.fromkeys(r["sequence"] for r in rows))
    strategies = list(dict.fromkeys(r["strategy"] for r in rows))
    fig, ax = plt.subplots(figsize=(8, 4))
    width = 0.8 / len(strategies)
    for k, strategy in enumerate(strategies):
        values = [
            next(
                (r["ate_rmse_m"] or 0.0 for r in rows if r["sequence"] == s and r["strategy"] == strategy),
                0.0,
            )
            for s in sequences
        ]
        ax.bar([i + k * width for i in range(len(sequences))], values, width, label=strategy)
    ax.set_xticks([i + 0.4 - width / 2 for i in range(len(sequences))], sequences)
    ax.set_ylabel("ATE RMSE (m)")
    ax.set_yscale("log")
    ax.set_title("Dynamic-feature rejection: ATE per sequence")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def write_report(rows: list[dict[str, Any]], out_dir: Path) -> None:
    """report.json, report.txt and ate.png, each replaced whole (never seen half-written)."""
    write_text_atomic(out_dir / "report.json", dumps_json(rows) + "\n")
    write_text_atomic(out_dir / "report.txt", format_table(rows) + "\n")
    staged = out_dir / ".ate.png.tmp.png"
    if plot(rows, staged):
        os.replace(staged, out_dir / "ate.png")
