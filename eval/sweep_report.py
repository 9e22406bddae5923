"""What a sweep shows: rho per run, the best configuration per family, the
accuracy/time Pareto set, and curves of ATE and rejection precision/recall
against each swept threshold.

A configuration is (tracker with its parameters, detector, strategy, settings); its
score in a family is the mean over the family's sequences. rho compares each run with
the ``none`` run of the same sequence, tracker (and parameters) and detector. A failed
run (an external program's exit, time limit or unreadable output) is counted, never
averaged: a configuration with one is not the best of its family.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from eval.aggregate import SuccessRule, summarize
from eval.metrics import improvement_rate


def _parameters(row: dict[str, Any]) -> str:
    return row.get("parameters") or "{}"


def with_rho(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    baseline = {
        (r["sequence"], r["tracker"], _parameters(r), r["detector"]): r["ate_rmse_m"]
        for r in rows
        if r["strategy"] == "none" and r["settings"] == "{}"
    }
    out = []
    for r in rows:
        base = baseline.get((r["sequence"], r["tracker"], _parameters(r), r["detector"]))
        rho = None
        if base is not None and r["ate_rmse_m"] is not None and base > 0:
            rho = improvement_rate(base, r["ate_rmse_m"])
        out.append({**r, "rho_percent": rho})
    return out


def _mean(values: list[float | None]) -> float | None:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else None


def configurations(rows: list[dict[str, Any]], rule: SuccessRule | None = None) -> list[dict[str, Any]]:
    """Per family and configuration: its runs (the family's sequences, its seeds), how many
    succeeded (``rule``), every figure's statistics over them (``stats``: n, mean, median,
    std, worst, p90, 95 % interval), and the means at the top level, as plots read them."""
    rule = rule or SuccessRule()
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in with_rho(rows):
        r = r | {"lost_fraction": 1.0 - r["tracked_fraction"]} if r.get("tracked_fraction") is not None else r
        groups[
            (r["family"], r["tracker"], _parameters(r), r["detector"], r["strategy"], r["settings"])
        ].append(r)
    varied = _varied_parameters(rows)
    out = []
    for (family, tracker, parameters, detector, strategy, settings), members in sorted(groups.items()):
        shown = {k: v for k, v in json.loads(parameters).items() if k in varied.get(tracker, set())}
        out.append(
            {
                "family": family,
                "tracker": tracker,
                "parameters": json.loads(parameters),
                "label": configuration_label(tracker, shown, strategy, json.loads(settings)),
                "detector": detector,
                "strategy": strategy,
                "settings": json.loads(settings),
                "sequences": len(members),
                **summarize(members, rule),
                "ate_rmse_m": _mean([m["ate_rmse_m"] for m in members]),
                "rho_percent": _mean([m["rho_percent"] for m in members]),
                "rejection_precision": _mean([m["rejection_precision"] for m in members]),
                "rejection_recall": _mean([m["rejection_recall"] for m in members]),
                "tracked_fraction": _mean([m["tracked_fraction"] for m in members]),
                "track_ms_median": _mean([m["track_ms_median"] for m in members]),
            }
        )
    return out


def _varied_parameters(rows: list[dict[str, Any]]) -> dict[str, set[str]]:
    """Per tracker, the parameters that take more than one value in these rows: the ones a
    label needs (ORB-SLAM3 has six, and a sweep varies two)."""
    values: dict[str, dict[str, set]] = defaultdict(lambda: defaultdict(set))
    for r in rows:
        for name, value in json.loads(_parameters(r)).items():
            values[r["tracker"]][name].add(value)
    return {tracker: {n for n, seen in names.items() if len(seen) > 1} for tracker, names in values.items()}


def configuration_label(
    tracker: str, parameters: dict[str, Any], strategy: str, settings: dict[str, Any]
) -> str:
    """How tables name a configuration: an external tracker and the parameters its sweep
    varies, then the strategy and its settings (``orb3 ThDepth=80 · mask``)."""
    head = "" if tracker == "builtin" else f"{tracker} {settings_text(parameters)}".rstrip() + " · "
    return f"{head}{strategy} {settings_text(settings)}".rstrip()


def best_per_family(
    configs: list[dict[str, Any]], min_success_rate: float = 1.0
) -> dict[str, dict[str, Any]]:
    """Per family, the lowest mean ATE among the configurations that succeeded on at least
    ``min_success_rate`` of their runs (all, by default): a configuration that lost track on
    one seed of four is not the best over one that held on all four, however low its ATE
    where it held."""
    best: dict[str, dict[str, Any]] = {}
    for c in configs:
        if (
            c["ate_rmse_m"] is None
            or (c.get("success_rate") if "success_rate" in c else 1.0) < min_success_rate
        ):
            continue
        current = best.get(c["family"])
        if current is None or c["ate_rmse_m"] < current["ate_rmse_m"]:
            best[c["family"]] = c
    return best


def unqualified(configs: list[dict[str, Any]], best: dict[str, dict[str, Any]]) -> dict[str, float]:
    """Families with no configuration that held often enough, and the best success rate seen."""
    out: dict[str, float] = {}
    for c in configs:
        if c["family"] not in best:
            out[c["family"]] = max(out.get(c["family"], 0.0), c.get("success_rate") or 0.0)
    return out


def pareto(configs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per family, the configurations no other beats on both mean ATE and tracking time."""
    out = []
    by_family: dict[str, list[dict]] = defaultdict(list)
    for c in configs:
        if c["ate_rmse_m"] is not None and c["track_ms_median"] is not None:
            by_family[c["family"]].append(c)
    for members in by_family.values():
        for c in members:
            dominated = any(
                o["ate_rmse_m"] <= c["ate_rmse_m"]
                and o["track_ms_median"] <= c["track_ms_median"]
                and (o["ate_rmse_m"] < c["ate_rmse_m"] or o["track_ms_median"] < c["track_ms_median"])
                for o in members
            )
            if not dominated:
                out.append(c)
    return sorted(out, key=lambda c: (c["family"], c["ate_rmse_m"]))


def pyplot():
    """matplotlib's pyplot on the Agg backend (no display; plots are files or inlined PNGs)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def threshold_figures(configs: list[dict[str, Any]]) -> list[tuple[str, Any]]:
    """Per (tracker, strategy, swept threshold or tracker parameter): mean ATE and rejection
    precision/recall against the value. A curve per family, detector and value of every
    other swept quantity, so that a curve varies one thing; a quantity that takes one value
    (a default) gets no figure, nor does a panel with nothing to draw."""
    plt = pyplot()
    swept: dict[tuple[str, str, str, str], list[dict]] = defaultdict(list)
    for c in configs:
        for field in ("settings", "parameters"):
            for name in c.get(field) or {}:
                swept[(c["tracker"], c["strategy"], field, name)].append(c)
    figures = []
    for (tracker, strategy, field, name), members in sorted(swept.items()):
        if len({_number(m[field][name]) for m in members} - {None}) < 2:
            continue  # one value (a default) or words: nothing is swept here
        lines: dict[tuple, list] = defaultdict(list)
        for m in members:
            others = sorted(
                (f, k, str(v)) for f in ("settings", "parameters") for k, v in (m.get(f) or {}).items()
            )
            fixed = tuple(item for item in others if item[:2] != (field, name))
            if _number(m[field][name]) is not None:
                lines[(m["family"], m["detector"], fixed)].append((_number(m[field][name]), m))
        rejection = any(m["rejection_precision"] is not None for m in members)
        panels = 2 if rejection else 1
        fig, axes = plt.subplots(1, panels, figsize=(5.5 * panels, 3.8), squeeze=False)
        ax_ate = axes[0][0]
        for (family, detector, fixed), pts in sorted(lines.items(), key=lambda item: str(item[0])):
            pts.sort(key=lambda p: p[0])
            varying = " ".join(f"{k}={v}" for _, k, v in fixed if _varies(members, k))
            label = " / ".join(part for part in (family, detector, varying) if part)
            xs = [x for x, _ in pts]
            ax_ate.plot(xs, [m["ate_rmse_m"] for _, m in pts], "o-", label=label)
            if rejection:
                axes[0][1].plot(
                    xs, [m["rejection_precision"] for _, m in pts], "o-", label=f"{label} precision"
                )
                axes[0][1].plot(xs, [m["rejection_recall"] for _, m in pts], "s--", label=f"{label} recall")
        who = strategy if tracker == "builtin" else f"{tracker} · {strategy}"
        ax_ate.set(xlabel=name, ylabel="mean ATE RMSE (m)", title=f"{who}: ATE against {name}")
        ax_ate.legend(fontsize=6)
        if rejection:
            axes[0][1].set(xlabel=name, ylabel="rejection", ylim=(0, 1.05), title="precision / recall")
            axes[0][1].legend(fontsize=5)
        fig.tight_layout()
        prefix = strategy if tracker == "builtin" else f"{tracker}-{strategy}"
        figures.append((f"{prefix}-{name}", fig))
    return figures


def _varies(members: list[dict], name: str) -> bool:
    """Whether quantity ``name`` (a setting or a parameter) takes more than one value."""
    seen = {str((m.get("settings") or {}).get(name, (m.get("parameters") or {}).get(name))) for m in members}
    return len(seen) > 1


def _number(value: Any) -> float | None:
    """A swept value as a plot's abscissa; None for text (a parameter may be a word)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def pareto_figure(configs: list[dict[str, Any]]):
    """Mean ATE against median tracking time, the Pareto set marked; None if nothing to plot."""
    usable = [c for c in configs if c["ate_rmse_m"] is not None and c["track_ms_median"] is not None]
    if not usable:
        return None
    plt = pyplot()
    front = pareto(configs)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.scatter(
        [c["track_ms_median"] for c in usable], [c["ate_rmse_m"] for c in usable], s=12, c="0.6", label="all"
    )
    ax.scatter(
        [c["track_ms_median"] for c in front], [c["ate_rmse_m"] for c in front], s=30, c="C3", label="Pareto"
    )
    positive = all(c["ate_rmse_m"] > 0 for c in usable)
    ax.set(
        xlabel="median tracking ms per frame",
        ylabel="mean ATE RMSE (m)",
        yscale="log" if positive else "linear",
    )
    ax.set_title("accuracy against time, per configuration and family")
    ax.legend()
    fig.tight_layout()
    return fig


def plot(configs: list[dict[str, Any]], out: Path) -> list[Path]:
    """The threshold curves and the Pareto picture as PNG files under ``out``."""
    plt = pyplot()
    out.mkdir(parents=True, exist_ok=True)
    figures = threshold_figures(configs)
    front = pareto_figure(configs)
    if front is not None:
        figures.append(("pareto", front))
    written = []
    for name, fig in figures:
        path = out / f"{name}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def settings_text(settings: dict[str, Any]) -> str:
    """Threshold values as ``name=value`` words, as tables and plots show them."""
    return " ".join(f"{k}={v}" for k, v in settings.items())


def format_best(best: dict[str, dict[str, Any]], missing: dict[str, float] | None = None) -> str:
    """The best configuration per family; ``held``: its runs that succeeded, of all."""
    lines = [
        f"{'family':24s}{'best configuration':52s}{'ATE m':>9s}{'rho %':>8s}{'prec':>7s}{'recall':>7s}"
        f"{'held':>7s}"
    ]
    for family, c in sorted(best.items()):
        label = c.get("label") or configuration_label("builtin", {}, c["strategy"], c["settings"])
        name = f"{label} ({c['detector']})"
        rho = "-" if c["rho_percent"] is None else f"{c['rho_percent']:.1f}"
        prec = "-" if c["rejection_precision"] is None else f"{c['rejection_precision']:.3f}"
        rec = "-" if c["rejection_recall"] is None else f"{c['rejection_recall']:.3f}"
        held = f"{c['successes']}/{c['runs']}" if "runs" in c else "-"
        lines.append(
            f"{family:24s}{name[:51]:52s}{c['ate_rmse_m']:9.4f}{rho:>8s}{prec:>7s}{rec:>7s}{held:>7s}"
        )
    for family, rate in sorted((missing or {}).items()):
        lines.append(f"{family:24s}(no configuration held on enough seeds: the best held on {rate:.0%})")
    return "\n".join(lines)
