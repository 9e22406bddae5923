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
from depotbench.eval.metrics.figures import (
    FIGURES,
    Baseline,
    ScoredRun,
    configuration_of,
    is_baseline,
    parameters_of,
    with_derived,
)
from depotbench.eval.metrics.record import COMPILATION_NOTE, RunRecord, timing_may_include_compilation
from depotbench.eval.metrics.statistics import SuccessRule, summarize
from depotbench.eval.sweep.family import family_name, family_order, sorted_families


def with_rho(records: list[RunRecord], baseline: Baseline | None = None) -> list[ScoredRun]:
    """The runs with their derived figures (rho against ``baseline``, else each run's own
    ``none``; lost fraction: ``figures.with_derived``)."""
    return with_derived(records, baseline)


def _mean(values: list[float | None]) -> float | None:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else None


def configurations(
    rows: list[RunRecord], rule: SuccessRule | None = None, baseline: Baseline | None = None
) -> list[dict[str, Any]]:
    """Per family and configuration: its runs (the family's sequences, its seeds), how many
    succeeded (``rule``), every figure's statistics over them (``stats``: n, mean, median,
    std, worst, p90, 95 % interval), and the means at the top level, as plots read them."""
    rule = rule or SuccessRule()
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in with_derived(rows, baseline):
        groups[configuration_of(r)].append(r)
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
                **{f.name: _mean([m.get(f.name) for m in members]) for f in FIGURES},
                # Rows written before times excluded compiling: their times are not comparable.
                **({"timing": COMPILATION_NOTE} if any(map(timing_may_include_compilation, members)) else {}),
            }
        )
    return out


def _varied_parameters(rows: list[RunRecord]) -> dict[str, set[str]]:
    """Per tracker, the parameters that take more than one value in these rows: the ones a
    label needs (ORB-SLAM3 has six, and a sweep varies two)."""
    values: dict[str, dict[str, set]] = defaultdict(lambda: defaultdict(set))
    for r in rows:
        for name, value in json.loads(parameters_of(r)).items():
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


MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">")
"""Within a family's colour, one marker per detector and value of the other swept quantities."""
BAND_ALPHA = 0.18
FAILED_COLOUR = "#b91c1c"
LEGEND_FONT = 9
"""Points: a legend is read beside 10 pt axis labels; at 7 pt it was the smallest text."""


def family_colours(families) -> dict[str, Any]:
    """One colour per family, from the sorted names: a family keeps its colour in every panel
    and figure of a sweep (tab10 up to 10 families, tab20 up to 20, then repeating)."""
    import matplotlib

    names = sorted_families(families)
    palette = matplotlib.colormaps["tab10" if len(names) <= 10 else "tab20"].colors
    return {name: palette[i % len(palette)] for i, name in enumerate(names)}


def _interval(c: dict[str, Any], metric: str) -> tuple[float, float]:
    """The 95 % interval of a configuration's mean ``metric`` (``stats``), NaN where there is
    none (one seed, or a summary written before statistics over seeds)."""
    stats = c.get("stats")
    entry = stats.get(metric) if isinstance(stats, dict) else None
    if not isinstance(entry, dict):
        return math.nan, math.nan
    ends = [_number(entry.get(end)) for end in ("ci_low", "ci_high")]
    return tuple(math.nan if v is None or not math.isfinite(v) else v for v in ends)  # type: ignore[return-value]


def _band(ax, xs: list[float], configs: list[dict], metric: str, colour, alpha: float = BAND_ALPHA) -> bool:
    """The shaded 95 % interval of the mean along a curve, where the curve's points have one
    (n >= 2: one seed has no interval); whether anything was drawn."""
    ends = np.array([_interval(c, metric) for c in configs], float).reshape(-1, 2)
    if np.isfinite(ends).all(axis=1).any():
        ax.fill_between(xs, ends[:, 0], ends[:, 1], color=colour, alpha=alpha, lw=0)
        return True
    return False


def _parameters_key(c: dict[str, Any]) -> str:
    return json.dumps(c.get("parameters") or {}, sort_keys=True)


def _none_baselines(configs: list[dict[str, Any]]) -> dict[tuple, dict[str, Any]]:
    """The ``none`` configuration of each (family, tracker with its parameters, detector):
    what a strategy's curve is compared with."""
    return {
        (c["family"], c["tracker"], _parameters_key(c), c["detector"]): c for c in configs if is_baseline(c)
    }


def _legend_columns(labels: list[str], width_in: float) -> int:
    """As many legend columns as the longest label lets fit across the figure."""
    longest = max((len(label) for label in labels), default=10)
    char_px = 0.8 * LEGEND_FONT  # a character's mean width at 100 dpi
    return max(1, min(len(labels), int(width_in * 100 // (longest * char_px + 50))))


def _legend_below(fig, handles: list, width_in: float) -> None:
    """The figure's legend under its panels, outside the data (constrained layout makes room)."""
    labels = [h.get_label() for h in handles]
    fig.legend(
        handles,
        labels,
        loc="outside lower center",
        ncols=_legend_columns(labels, width_in),
        fontsize=LEGEND_FONT,
        frameon=False,
    )


def _legend_height(entries: int, columns: int) -> float:
    """Inches a legend of ``entries`` in ``columns`` takes under the panels."""
    return 0.2 + 0.025 * LEGEND_FONT * math.ceil(entries / max(columns, 1))


def threshold_figures(configs: list[dict[str, Any]]) -> list[tuple[str, Any]]:
    """Per (tracker, strategy, swept threshold or tracker parameter): mean ATE and rejection
    precision/recall against the value, each with its 95 % interval as a band, and each
    family's ``none`` run (same tracker, parameters and detector) as a dashed line. A curve per
    family, detector and value of every other swept quantity, so that a curve varies one
    thing; a family has one colour in every panel and figure, a detector or other value a
    marker. A quantity that takes one value (a default) gets no figure, nor does a panel
    with nothing to draw."""
    plt = pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    colours = family_colours(c["family"] for c in configs)
    baselines = _none_baselines(configs)
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
                (f, k, _shown(v) if isinstance(v, bool) else str(v))  # true, as the spec wrote it
                for f in ("settings", "parameters")
                for k, v in (m.get(f) or {}).items()
            )
            fixed = tuple(item for item in others if item[:2] != (field, name))
            if _number(m[field][name]) is not None:
                lines[(m["family"], m["detector"], fixed)].append((_number(m[field][name]), m))
        rejection = any(m["rejection_precision"] is not None for m in members)
        panels = 2 if rejection else 1
        width = 5.4 * panels
        handles: list = []
        styles: dict[tuple, str] = {}
        drawn_baselines: set = set()
        plotted: list[tuple] = []
        for (family, detector, fixed), pts in sorted(
            lines.items(), key=lambda item: (family_order(item[0][0]), str(item[0][1:]))
        ):
            pts.sort(key=lambda p: p[0])
            varying = " ".join(f"{k}={v}" for _, k, v in fixed if _varies(members, k))
            shown = detector if len({m["detector"] for m in members}) > 1 else ""
            label = " / ".join(part for part in (family_name(family), shown, varying) if part)
            marker = styles.setdefault((detector, fixed), MARKERS[len(styles) % len(MARKERS)])
            plotted.append((family, detector, pts, label, marker))
        extra = 2 + (2 if rejection else 0)
        columns = _legend_columns([p[3] for p in plotted] + ["none (dashed): each family's run"], width)
        height = 3.6 + _legend_height(len(plotted) + extra, columns)
        fig, axes = plt.subplots(1, panels, figsize=(width, height), squeeze=False, layout="constrained")
        ax_ate = axes[0][0]
        banded = False
        several = len({p[1] for p in plotted}) > 1  # detectors: a none line is marked as its detector
        for family, detector, pts, label, marker in plotted:
            colour = colours[family]
            xs = [x for x, _ in pts]
            members_of_line = [m for _, m in pts]
            (line,) = ax_ate.plot(
                xs,
                [m["ate_rmse_m"] for m in members_of_line],
                "-",
                marker=marker,
                ms=4,
                c=colour,
                label=label,
            )
            handles.append(line)
            banded |= _band(ax_ate, xs, members_of_line, "ate_rmse_m", colour)
            if strategy != "none":
                base = [
                    baselines.get((family, m["tracker"], _parameters_key(m), detector))
                    for m in members_of_line
                ]
                values = [None if b is None else b["ate_rmse_m"] for b in base]
                key = (family, detector, tuple(id(b) for b in base))
                if key not in drawn_baselines and any(v is not None for v in values):
                    drawn_baselines.add(key)
                    ends = {"marker": marker, "mfc": "white", "ms": 5} if several else {}
                    if len({id(b) for b in base}) == 1:
                        ax_ate.axhline(values[0], ls="--", lw=1.1, c=colour, **ends)
                    else:  # a tracker parameter is swept: its none run changes with it
                        nones = [math.nan if v is None else v for v in values]
                        ax_ate.plot(xs, nones, "--", lw=1.1, c=colour, **ends)
            if rejection:
                ax = axes[0][1]
                ax.plot(
                    xs,
                    [m["rejection_precision"] for m in members_of_line],
                    "-",
                    marker=marker,
                    ms=4,
                    c=colour,
                )
                ax.plot(
                    xs, [m["rejection_recall"] for m in members_of_line], ":", marker=marker, ms=4, c=colour
                )
                banded |= _band(ax, xs, members_of_line, "rejection_precision", colour, BAND_ALPHA * 0.7)
                banded |= _band(ax, xs, members_of_line, "rejection_recall", colour, BAND_ALPHA * 0.7)
        if drawn_baselines:
            handles.append(Line2D([], [], ls="--", c="0.3", label="none (dashed): each family's run"))
        if banded:  # one seed per point (n = 1) has no interval: no band, no entry
            handles.append(
                Patch(color="0.3", alpha=BAND_ALPHA * 2, lw=0, label="band: 95 % interval of the mean")
            )
        who = strategy if tracker == "builtin" else f"{tracker} · {strategy}"
        ax_ate.set(xlabel=name, ylabel="ATE RMSE (m), mean over runs", title=f"{who}: ATE against {name}")
        _value_ticks(ax_ate, [x for *_, pts, _l, _m in plotted for x, _ in pts])
        _log_when_spread(ax_ate, [v for line in ax_ate.get_lines() for v in line.get_ydata()])
        if rejection:
            ax = axes[0][1]
            ax.set(
                xlabel=name, ylabel="rejection, mean over runs", ylim=(0, 1.05), title="precision / recall"
            )
            _value_ticks(ax, [x for *_, pts, _l, _m in plotted for x, _ in pts])
            handles.append(Line2D([], [], ls="-", c="0.3", label="precision (solid)"))
            handles.append(Line2D([], [], ls=":", c="0.3", label="recall (dotted)"))
        _legend_below(fig, handles, width)
        prefix = strategy if tracker == "builtin" else f"{tracker}-{strategy}"
        figures.append((f"{prefix}-{name}", fig))
    return figures


def _value_ticks(ax, xs: list[float]) -> None:
    """Ticks at the swept values when there are few and they stand apart (a grid of 3 to 8
    values); random samples (1.05 beside 1.12) keep matplotlib's own ticks."""
    values = sorted(set(xs))
    if not 1 < len(values) <= 8:
        return
    if np.diff(values).min() >= 0.06 * (values[-1] - values[0]):
        ax.set_xticks(values, [f"{v:.4g}" for v in values])


def _log_when_spread(ax, values: list[float | None], spread: float = 10.0) -> None:
    """A log scale when the plotted values span more than ``spread`` times: a none run at
    0.115 m flattened curves at 0.003 m to a line on the axis."""
    positive = [v for v in values if v is not None and math.isfinite(v) and v > 0]
    if positive and max(positive) > spread * min(positive):
        ax.set_yscale("log")
        one_label_set(ax.yaxis, min(positive), max(positive))


def one_label_set(axis, low: float, high: float) -> None:
    """One set of tick labels on a log axis spanning ``low`` to ``high``: matplotlib labels
    its minor ticks too on an axis of under two decades ("10⁻²" beside "3×10⁻²", two styles
    that read as two scales). Major ticks at 1, 2 and 5 per decade up to 2.5 decades (at
    least three labels from one decade on), one per decade beyond; minor ticks unlabelled."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    decades = math.log10(high / low) if 0 < low < high else 0.0
    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0) if decades < 2.5 else (1.0,)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _varies(members: list[dict], name: str) -> bool:
    """Whether quantity ``name`` (a setting or a parameter) takes more than one value."""
    seen = {str((m.get("settings") or {}).get(name, (m.get("parameters") or {}).get(name))) for m in members}
    return len(seen) > 1


def _number(value: Any) -> float | None:
    """A swept value as a plot's abscissa; None for text (a parameter may be a word)."""
    if isinstance(value, bool):
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def short_label(c: dict[str, Any], limit: int = 40) -> str:
    """A configuration's label in at most ``limit`` characters (a plot's annotation): a long
    one loses its middle, keeping the strategy's settings at its end."""
    label = str(c.get("label") or configuration_label("builtin", {}, c["strategy"], c.get("settings") or {}))
    if len(label) <= limit:
        return label
    head = limit // 3
    return label[:head] + "…" + label[len(label) - (limit - head - 1) :]


PARETO_LABEL_FONT = 7.5
PARETO_LABEL_STEP_PX = 6.0
PARETO_LABEL_TRIES = 40
"""A Pareto label is raised 6 px at a time, up to 240 px, until its words clear the others'."""


def pareto_figure(configs: list[dict[str, Any]]):
    """Mean ATE against median tracking time per configuration, a colour per family; each
    family's Pareto set ringed and labelled; None if nothing to plot."""
    usable = [c for c in configs if c["ate_rmse_m"] is not None and c["track_ms_median"] is not None]
    if not usable:
        return None
    plt = pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.text import Text

    colours = family_colours(c["family"] for c in configs)
    front = pareto(configs)
    detectors = len({c["detector"] for c in usable}) > 1
    families = sorted_families(c["family"] for c in usable)
    fig, ax = plt.subplots(figsize=(8.6, 4.8), layout="constrained")
    for family in families:
        mine = [c for c in usable if c["family"] == family]
        ax.scatter(
            [c["track_ms_median"] for c in mine],
            [c["ate_rmse_m"] for c in mine],
            s=14,
            color=colours[family],
            alpha=0.55,
            lw=0,
        )
    ax.scatter(
        [c["track_ms_median"] for c in front],
        [c["ate_rmse_m"] for c in front],
        s=44,
        c=[colours[c["family"]] for c in front],
        edgecolors="black",
        linewidths=0.9,
        zorder=3,
    )
    ax.set(xlabel="median tracking ms per frame", ylabel="ATE RMSE (m), mean over runs")
    _log_when_spread(ax, [c["ate_rmse_m"] for c in usable])
    ax.set_title("accuracy against time, per configuration (ringed: a family's Pareto set)")
    handles = [
        Line2D([], [], ls="", marker="o", ms=6, color=colours[f], label=family_name(f)) for f in families
    ] + [Line2D([], [], ls="", marker="o", ms=7, mfc="white", mec="black", label="Pareto set (labelled)")]
    ax.legend(
        handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=LEGEND_FONT, frameon=False
    )
    fig.canvas.draw()  # the scales and the legend are set: labels are placed in pixels,
    fig.set_layout_engine("none")  # which a second layout would move
    renderer = fig.canvas.get_renderer()
    box = ax.get_window_extent()
    placed: list = []  # the pixel boxes of the labels so far
    for c in sorted(front, key=lambda c: (c["ate_rmse_m"], c["track_ms_median"])):
        text = short_label(c) + (f" ({c['detector']})" if detectors else "")
        x, _ = ax.transData.transform((c["track_ms_median"], c["ate_rmse_m"]))
        left = x > box.x0 + 0.6 * box.width  # near the right edge: the label goes left of its point
        for step in range(PARETO_LABEL_TRIES):
            dy = 4.0 + PARETO_LABEL_STEP_PX * step  # raised until it clears every label placed
            note = ax.annotate(
                text,
                (c["track_ms_median"], c["ate_rmse_m"]),
                xytext=(-5 if left else 5, dy * 72 / fig.dpi),
                textcoords="offset points",
                ha="right" if left else "left",
                fontsize=PARETO_LABEL_FONT,
                color="0.15",
                arrowprops={"arrowstyle": "-", "color": "0.6", "lw": 0.5} if step else None,
            )
            extent = Text.get_window_extent(note, renderer).padded(1.0)  # the words, not the leader
            if not any(extent.overlaps(other) for other in placed) or step == PARETO_LABEL_TRIES - 1:
                break
            note.remove()
        placed.append(extent)
    return fig


def _config_key(
    family: str, tracker: str, parameters: Any, detector: str, strategy: str, settings: Any
) -> str:
    return json.dumps([family, tracker, parameters or {}, detector, strategy, settings or {}], sort_keys=True)


def _loads(text: Any) -> Any:
    """A row's JSON column (settings, parameters) as a value; text that is not JSON as is."""
    if not isinstance(text, str):
        return text
    try:
        return json.loads(text)
    except ValueError:
        return text


def runs_of_configurations(
    configs: list[dict[str, Any]], rows: list[RunRecord]
) -> dict[str, list[dict[str, Any]]]:
    """Each configuration's rows (by ``_config_key``), rows of no configuration left out."""
    wanted = {
        _config_key(
            c["family"], c["tracker"], c.get("parameters"), c["detector"], c["strategy"], c.get("settings")
        )
        for c in configs
    }
    out: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        key = _config_key(
            r.get("family"),
            r.get("tracker"),
            _loads(r.get("parameters") or "{}"),
            r.get("detector"),
            r.get("strategy"),
            _loads(r.get("settings") or "{}"),
        )
        if key in wanted:
            out[key].append(r)
    return out


def figure_name(prefix: str, text: str) -> str:
    """A file name from a family's name (``runs-walkers_actors.0.count_1``)."""
    safe = "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in text).strip("._") or "family"
    return f"{prefix}-{safe[:80]}"


def strip_figures(
    configs: list[dict[str, Any]],
    rows: list[RunRecord],
    rule: SuccessRule | None = None,
    only: set[str] | None = None,
) -> list[tuple[str, str, Any]]:
    """Per family, ATE RMSE of every run of every configuration: each seed a point (hollow
    where the run lost track, ``rule``), a failed run a red × at the right edge, the mean and
    its 95 % interval as a black bar, and the family's ``none`` mean as a dashed line.
    (family, file name, figure) triples, families sorted; ``only``: these families (each
    keeps the colour it has among all of ``configs``)."""
    plt = pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.transforms import blended_transform_factory

    rule = rule or SuccessRule()
    colours = family_colours(c["family"] for c in configs)
    runs = runs_of_configurations(configs, rows)
    names: set[str] = set()
    figures = []
    for family in sorted_families(c["family"] for c in configs):
        if only is not None and family not in only:
            continue
        mine = [c for c in configs if c["family"] == family]
        # The none configurations first (the reference), then in the summary's order.
        mine.sort(key=lambda c: c["strategy"] != "none")
        detectors = len({c["detector"] for c in mine}) > 1
        colour = colours[family]
        entries = []
        for c in mine:
            key = _config_key(
                family, c["tracker"], c.get("parameters"), c["detector"], c["strategy"], c.get("settings")
            )
            members = sorted(runs.get(key, []), key=lambda r: (str(r.get("seed")), str(r.get("sequence"))))
            label = short_label(c, 44) + (f" ({c['detector']})" if detectors else "")
            entries.append((c, label, members))
        values = [
            r["ate_rmse_m"]
            for _, _, members in entries
            for r in members
            if not r.get("failure") and _finite(r.get("ate_rmse_m"))
        ]
        width = 8.0
        legend_entries = 3 + any(
            r.get("failure") or not _finite(r.get("ate_rmse_m")) for _, _, m in entries for r in m
        )
        height = 1.1 + 0.34 * len(entries) + _legend_height(legend_entries + 2, 3)
        fig, ax = plt.subplots(figsize=(width, height), layout="constrained")
        positive = bool(values) and min(values) > 0
        log = positive and max(values) / min(values) > 10
        top = (
            (
                max(values) * (1.25 if log else 1.0)
                + (0 if log else 0.08 * (max(values) - min(values) or max(values) or 1.0))
            )
            if values
            else 1.0
        )
        held_at = blended_transform_factory(ax.transAxes, ax.transData)
        failures = lost = 0
        intervals = False
        for y, (c, _, members) in enumerate(entries):
            offsets = np.linspace(-0.22, 0.22, len(members)) if len(members) > 1 else np.zeros(len(members))
            good = [
                (r, o)
                for r, o in zip(members, offsets, strict=True)
                if not r.get("failure") and _finite(r.get("ate_rmse_m"))
            ]
            failed = [(r, o) for r, o in zip(members, offsets, strict=True) if (r, o) not in good]
            held = [(r, o) for r, o in good if rule.holds(r)]
            slipped = [(r, o) for r, o in good if not rule.holds(r)]
            if held:
                ax.scatter(
                    [r["ate_rmse_m"] for r, _ in held],
                    [y + o for _, o in held],
                    s=22,
                    color=colour,
                    lw=0,
                    zorder=3,
                )
            if slipped:
                lost += len(slipped)
                ax.scatter(
                    [r["ate_rmse_m"] for r, _ in slipped],
                    [y + o for _, o in slipped],
                    s=22,
                    facecolors="none",
                    edgecolors=colour,
                    lw=1.1,
                    zorder=3,
                )
            if failed:
                failures += len(failed)
                ax.scatter(
                    [top] * len(failed),
                    [y + o for _, o in failed],
                    s=30,
                    marker="x",
                    color=FAILED_COLOUR,
                    lw=1.3,
                    zorder=4,
                )
            mean = _number(c.get("ate_rmse_m"))
            if mean is not None and math.isfinite(mean):
                low, high = _interval(c, "ate_rmse_m")
                if math.isfinite(low) and math.isfinite(high):
                    intervals = True
                    ax.plot([low, high], [y, y], "-", c="black", lw=1.3, zorder=2)
                ax.plot([mean], [y], "|", c="black", ms=13, mew=1.6, zorder=4)
            successes = sum(rule.holds(r) for r in members)
            ax.text(1.01, y, f"{successes}/{len(members)}", transform=held_at, fontsize=7, va="center")
        ax.text(1.01, -0.75, "held", transform=held_at, fontsize=7, va="center", fontweight="bold")
        nones = [c for c in mine if is_baseline(c) and _finite(c.get("ate_rmse_m"))]
        if len(nones) == 1:
            ax.axvline(nones[0]["ate_rmse_m"], ls="--", lw=1.0, c=colour, zorder=1)
        ax.set_yticks(range(len(entries)), [label for _, label, _ in entries], fontsize=7.5)
        ax.set_ylim(len(entries) - 0.5, -0.5)  # the first configuration on top
        if log:
            ax.set_xscale("log")
            one_label_set(ax.xaxis, min(values), max(values))
        if failures:
            ax.set_xlim(right=top * (1.15 if log else 1.0) + (0 if log else 0.04 * abs(top)))
        ax.grid(axis="x", color="0.9", lw=0.6)
        ax.set_axisbelow(True)
        seeds = sorted({str(r.get("seed")) for _, _, m in entries for r in m if r.get("seed") is not None})
        runs_count = sum(len(m) for _, _, m in entries)
        ax.set(xlabel="ATE RMSE (m) of each run")
        ax.set_title(
            f"{family_name(family)}: every run ({runs_count} runs"
            + (f", seeds {', '.join(seeds)}" if seeds else "")
            + ")",
            fontsize=9,
        )
        handles = [
            Line2D([], [], ls="", marker="o", ms=5, color=colour, label="a run (one seed)"),
            Line2D(
                [],
                [],
                ls="-" if intervals else "",
                marker="|",
                ms=9,
                c="black",
                label="mean and its 95 % interval" if intervals else "mean",
            ),
        ]
        if lost:
            handles.append(
                Line2D(
                    [],
                    [],
                    ls="",
                    marker="o",
                    ms=5,
                    mfc="none",
                    mec=colour,
                    label=f"a run that tracked under {rule.min_tracked_fraction:.0%} of its frames",
                )
            )
        if failures:
            handles.append(
                Line2D(
                    [],
                    [],
                    ls="",
                    marker="x",
                    ms=6,
                    c=FAILED_COLOUR,
                    label="a failed run (no ATE), drawn at the right edge",
                )
            )
        if len(nones) == 1:
            handles.append(Line2D([], [], ls="--", c=colour, label="mean of none"))
        _legend_below(fig, handles, width)
        name = figure_name("runs", family)
        while name in names:
            name += "_"
        names.add(name)
        figures.append((family, name, fig))
    return figures


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def plot(
    configs: list[dict[str, Any]],
    out: Path,
    rows: list[RunRecord] | None = None,
    rule: SuccessRule | None = None,
) -> list[Path]:
    """The threshold curves, the Pareto picture and, given the rows, each family's runs
    (``runs-FAMILY.png``) as PNG files under ``out``."""
    plt = pyplot()
    out.mkdir(parents=True, exist_ok=True)
    figures = threshold_figures(configs)
    if rows is not None:
        figures += [(name, fig) for _, name, fig in strip_figures(configs, rows, rule)]
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
    """Threshold values as ``name=value`` words, as tables and plots show them; a number
    to 6 significant digits (a random sample is 1.0495829065855873; the rows keep it whole)."""
    return " ".join(f"{k}={_shown(v)}" for k, v in settings.items())


def _shown(value: Any) -> str:
    if isinstance(value, bool):  # as the spec wrote it, not Python's True
        return "true" if value else "false"
    if isinstance(value, float) and math.isfinite(value):
        return f"{value:.6g}"
    return str(value)


def format_best(best: dict[str, dict[str, Any]], missing: dict[str, float] | None = None) -> str:
    """The best configuration per family; ``held``: its runs that succeeded, of all. A family
    where no configuration held on enough seeds is a line of its own under the table."""
    from depotbench.core.text_table import Column, cell, render

    rows = []
    for family in sorted_families(best):  # natural order: count=6 before count=12
        c = best[family]
        label = c.get("label") or configuration_label("builtin", {}, c["strategy"], c["settings"])
        rows.append(
            [
                family,
                f"{label} ({c['detector']})",
                f"{c['ate_rmse_m']:.4f}",
                cell(c["rho_percent"], ".1f"),
                cell(c["rejection_precision"], ".3f"),
                cell(c["rejection_recall"], ".3f"),
                f"{c['successes']}/{c['runs']}" if "runs" in c else "-",
            ]
        )
    columns = [Column("family", "left"), Column("best configuration", "left")]
    columns += [Column(h) for h in ("ATE m", "rho %", "prec", "recall", "held")]
    lines = [render(columns, rows)] if rows else []
    for family in sorted_families(missing or {}):
        rate = (missing or {})[family]
        lines.append(f"{family}  (no configuration held on enough seeds: the best held on {rate:.0%})")
    return "\n".join(lines)
