"""The report's plots as a reader sees them (issue 54, item 5): images at their own aspect
ratio in Chromium, legends that list what is drawn, outside the data, at 9 pt or more, one set
of labels on a log axis, no band without an interval, no overlapping labels, and families in
natural order under readable names.

Figures are built from views and rows made here (no simulation, no rendering of frames); the
page is the run page of such a view, opened in headless Chromium."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from depotbench.eval.metrics.trajectory import Trajectory
from depotbench.eval.report.html import Notes, RunView, error_figure, run_page, trajectory_figure
from depotbench.eval.sweep.family import family_name, sorted_families
from depotbench.eval.sweep.summary import (
    configurations,
    pareto_figure,
    pyplot,
    strip_figures,
    threshold_figures,
)
from matplotlib.collections import PolyCollection
from matplotlib.text import Text

from tests.records import record
from tests.test_report import _open_in_chromium

STATES = ("not_initialized", "ok", "ok", "ok", "lost", "ok", "ok", "ok", "ok", "ok", "ok", "ok")
"""A run that never relocalised: the legend must not offer "relocalized"."""


def _view(positions_m: np.ndarray, states: tuple[str, ...] = STATES) -> RunView:
    """A run whose estimate is its ground truth plus 2 cm of noise (the sequence a stand-in
    holding only what the figures read)."""
    n = len(positions_m)
    times = 1.0 + np.arange(n) / 30.0
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    truth = SimpleNamespace(timestamps_s=times, positions_m=positions_m, quats_xyzw=quats)
    noisy = positions_m + np.random.default_rng(0).normal(0, 0.02, positions_m.shape)
    sequence = SimpleNamespace(groundtruth=truth, root=Path("seq"), meta={})
    return RunView(
        title="test",
        metrics={},
        timestamps_s=times,
        states=states,
        estimate=Trajectory.from_quaternions(times, noisy, quats, "estimate"),
        sequence=sequence,  # type: ignore[arg-type]
        diagnostics=None,
    )


def _walk(n: int = len(STATES), across_m: float = 3.0, along_m: float = 2.0) -> np.ndarray:
    s = np.linspace(0, 1, n)
    return np.c_[across_m * s, along_m * np.sin(3 * s), np.full(n, 1.2)]


def _legend_texts(legend) -> list[str]:
    return [t.get_text() for t in legend.get_texts()]


def _outside(fig, legend) -> bool:
    fig.canvas.draw()
    box = legend.get_window_extent()
    return all(not box.overlaps(ax.get_window_extent()) for ax in fig.axes)


def _legends(fig) -> list:
    return [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]


# -- the run's plots ----------------------------------------------------------------------------


def test_the_error_legend_lists_the_states_that_occur_outside_the_axes():
    fig = error_figure(_view(_walk()))
    (ax,) = fig.axes
    legend = ax.get_legend()
    shaded = {s for s in STATES if s != "ok"}  # ok frames are not shaded
    assert sorted(_legend_texts(legend)) == sorted(shaded)
    assert _outside(fig, legend)
    pyplot().close(fig)
    # A run that tracked every frame shades nothing and has no legend to read.
    fig = error_figure(_view(_walk(), ("ok",) * len(STATES)))
    assert fig.axes[0].get_legend() is None
    pyplot().close(fig)


def test_run_legends_are_at_least_9_pt_and_outside_the_axes():
    view = _view(_walk(across_m=6.0, along_m=0.4)[:, [1, 0, 2]])
    for fig in (trajectory_figure(view), error_figure(view)):
        for legend in _legends(fig):
            assert min(t.get_fontsize() for t in legend.get_texts()) >= 9
            assert _outside(fig, legend)
        pyplot().close(fig)


def _overlapping(labels) -> list[tuple[str, str]]:
    """Pairs of texts whose words share a pixel (an annotation's leader line left out)."""
    boxes = [(t.get_text(), Text.get_window_extent(t)) for t in labels if t.get_visible() and t.get_text()]
    return [(a, b) for i, (a, ba) in enumerate(boxes) for b, bb in boxes[i + 1 :] if ba.overlaps(bb)]


def test_a_narrow_trajectory_keeps_its_tick_labels_apart():
    """0.4 m across, 6 m along: equal axes leave the x axis about an inch for its labels."""
    fig = trajectory_figure(_view(_walk(across_m=6.0, along_m=0.4)[:, [1, 0, 2]]))
    fig.canvas.draw()
    (ax,) = fig.axes
    labels = [t for t in ax.get_xticklabels() if t.get_text()]
    assert len(labels) >= 2 and _overlapping(labels) == []
    pyplot().close(fig)


@pytest.mark.render
def test_images_keep_their_aspect_ratio_in_chromium(tmp_path: Path):
    """The trajectory (4.6 × 4.2 in) beside the error plot (7 × 3 in) in one flex row: the row's
    default ``align-items: stretch`` drew the error plot 41 % taller than it is."""
    page = tmp_path / "index.html"
    page.write_text(run_page(_view(_walk()), Notes()))
    shown = _open_in_chromium(page, tmp_path / "page.png")
    assert shown["errors"] == []
    images = shown["images"]
    assert [i["alt"] for i in images] == ["trajectory from above", "error over time"]
    assert images[0]["top"] == images[1]["top"]  # side by side: the case that stretched
    for image in images:
        natural = image["width"] / image["height"]
        rendered = image["shownWidth"] / image["shownHeight"]
        assert rendered == pytest.approx(natural, rel=0.02), image


# -- the sweep's plots --------------------------------------------------------------------------

COUNTS = (0, 12, 6)
FAMILIES = tuple(f"demo actors.0.count={c}" for c in COUNTS)


def _rows(seeds: tuple[int, ...], families: tuple[str, ...] = FAMILIES, spread: float = 1.0) -> list:
    """Every family with none and prior_flow at three k, ATE rising with the family's count;
    ``spread``: how many times the largest ATE is the smallest."""
    rows = []
    for f, family in enumerate(families):
        for seed in seeds:
            base = 0.02 * (1 + f * (spread - 1) / max(len(families) - 1, 1)) + 0.0007 * seed**1.5
            for strategy, settings, factor in [("none", {}, 1.3)] + [
                ("prior_flow", {"k": k}, 1 + 0.05 * k) for k in (1.5, 2.5, 3.5)
            ]:
                rows.append(
                    record(
                        key=f"{family}-{seed}-{strategy}-{json.dumps(settings)}",
                        family=family,
                        sequence=f"seq-{family}-{seed}",
                        seed=seed,
                        knobs=json.dumps({"seed": seed}),
                        strategy=strategy,
                        settings=json.dumps(settings),
                        ate_rmse_m=base * factor,
                        rejection_precision=None if strategy == "none" else 0.5 + 0.01 * seed,
                        rejection_recall=None if strategy == "none" else 0.8,
                        tracked_fraction=1.0,
                        track_ms_median=5.0 + (0 if strategy == "none" else 0.3 * settings["k"]) + 0.1 * seed,
                    )
                )
    return rows


def test_families_sort_by_number_and_read_as_names():
    assert sorted_families(FAMILIES) == [f"demo actors.0.count={c}" for c in (0, 6, 12)]
    assert family_name("demo actors.0.count=12") == "demo: actors[0].count = 12"
    assert family_name("walkers actors.0.speed_mps=1.5 sensor=kinect") == (
        "walkers: actors[0].speed_mps = 1.5, sensor = kinect"
    )
    assert family_name("walking_static") == "walking_static"  # a sequence folder's name: as it is


def test_sweep_plots_show_families_in_natural_order_under_their_names():
    configs = configurations(_rows((1, 2, 3)))
    shown = [family_name(f"demo actors.0.count={c}") for c in (0, 6, 12)]
    (fig,) = [fig for name, fig in threshold_figures(configs) if name == "prior_flow-k"]
    assert _legend_texts(fig.legends[0])[:3] == shown
    pyplot().close(fig)
    fig = pareto_figure(configs)
    assert _legend_texts(fig.axes[0].get_legend())[:3] == shown
    pyplot().close(fig)
    strips = strip_figures(configs, _rows((1, 2, 3)))
    assert [family for family, _, _ in strips] == sorted_families(FAMILIES)
    assert [fig.axes[0].get_title().split(":")[:2] for _, _, fig in strips] == [
        name.split(":") for name in shown
    ]
    for _, _, fig in strips:
        pyplot().close(fig)


def test_sweep_legends_are_at_least_9_pt():
    rows = _rows((1, 2, 3))
    configs = configurations(rows)
    figures = [fig for _, fig in threshold_figures(configs)] + [pareto_figure(configs)]
    figures += [fig for _, _, fig in strip_figures(configs, rows)]
    for fig in figures:
        legends = _legends(fig)
        assert legends
        for legend in legends:
            assert min(t.get_fontsize() for t in legend.get_texts()) >= 9
        pyplot().close(fig)


def _band_entries(fig) -> list[str]:
    return [t for legend in _legends(fig) for t in _legend_texts(legend) if "interval" in t]


def test_one_seed_draws_no_band_and_names_none():
    """n = 1 has no 95 % interval: neither a band nor its legend entry; with n = 3 both."""
    for seeds, expected in (((1,), False), ((1, 2, 3), True)):
        rows = _rows(seeds)
        configs = configurations(rows)
        (fig,) = [fig for name, fig in threshold_figures(configs) if name == "prior_flow-k"]
        bands = [c for ax in fig.axes for c in ax.collections if isinstance(c, PolyCollection)]
        assert bool(bands) is expected and bool(_band_entries(fig)) is expected, seeds
        pyplot().close(fig)
        for _, _, fig in strip_figures(configs, rows):
            assert bool(_band_entries(fig)) is expected, seeds
            pyplot().close(fig)


def _label_sets(axis) -> tuple[list[str], list[str]]:
    major = [t.get_text() for t in axis.get_majorticklabels() if t.get_text()]
    minor = [t.get_text() for t in axis.get_minorticklabels() if t.get_text()]
    return major, minor


def test_a_log_axis_carries_one_set_of_labels():
    """ATE over 40× (log axes) and over 3× (the Pareto plot's, which was log whatever the
    spread, and labelled its minor ticks as 3×10⁻² beside its major 10⁻¹)."""
    for spread, log in ((40.0, True), (3.0, False)):
        rows = _rows((1, 2, 3), spread=spread)
        configs = configurations(rows)
        figures = [fig for _, fig in threshold_figures(configs)] + [pareto_figure(configs)]
        figures += [fig for _, _, fig in strip_figures(configs, rows)]
        scales = []
        for fig in figures:
            fig.canvas.draw()
            for ax in fig.axes:
                for axis, scale in ((ax.xaxis, ax.get_xscale()), (ax.yaxis, ax.get_yscale())):
                    scales.append(scale)
                    if scale == "log":
                        major, minor = _label_sets(axis)
                        assert minor == [] and len(major) >= 2, (spread, major, minor)
            pyplot().close(fig)
        assert ("log" in scales) is log, spread


def _pareto_rows(points: list[tuple[float, float]], one_family: bool) -> list:
    return [
        record(
            key=f"k{i}",
            family="demo actors.0.count=6" if one_family else f"demo actors.0.count={i}",
            strategy="box_epipolar_flow",
            settings=json.dumps({"epsilon_px": 1 + i / 4, "flow_sigma_factor": 2.0 + i / 10}),
            ate_rmse_m=ate,
            track_ms_median=ms,
            tracked_fraction=1.0,
        )
        for i, (ms, ate) in enumerate(points)
    ]


@pytest.mark.parametrize(
    "points, one_family",
    [
        # Two families' fronts at one ATE, 2.1 ms (about 170 px) apart: a 40-character label
        # is wider than the 160 px the placement once assumed, and the next sat on it.
        ([(5.0, 0.030), (7.1, 0.030), (11.0, 0.010)], False),
        # Twelve configurations of one family, all on its front.
        ([(5.0 + 0.4 * i, 0.05 - 0.002 * i - 0.0001 * i * i) for i in range(12)], True),
    ],
)
def test_pareto_labels_do_not_overlap(points, one_family):
    fig = pareto_figure(configurations(_pareto_rows(points, one_family)))
    fig.canvas.draw()
    (ax,) = fig.axes
    assert len(ax.texts) == len(points)
    assert _overlapping(ax.texts) == []
    pyplot().close(fig)


def test_the_page_is_its_templates_output_with_every_text_escaped():
    """Issue 54 item 5: the page comes from the Jinja2 templates with autoescaping, its CSS
    from its own file; a title, a sequence path and a note that hold markup reach the page as
    text, never as tags."""
    from importlib import resources

    hostile = '<script>alert("x")</script>'
    view = _view(_walk())
    view = RunView(**{**view.__dict__, "title": hostile, "metrics": {"sequence": f"seq/{hostile}"}})
    notes = Notes()
    notes.add(f"a note naming {hostile}")
    page = run_page(view, notes)
    assert "<script" not in page and page.count("&lt;script&gt;") == 5  # title, h1, subtitle, run, note
    css = resources.files("depotbench.eval.report.templates").joinpath("report.css").read_text()
    assert css.strip() in page and "align-items: flex-start" in css
    assert page.index("Left out") < page.index("<h2>Run</h2>")  # what is left out comes first


def test_a_table_wider_than_the_window_scrolls_inside_its_section(tmp_path: Path):
    """The sweep page's best-configuration table has ten columns (about 1000 px): at the
    README screenshot's 832 px it ran past its section, two columns cut off at the edge.
    Every page writes its tables with one macro; here the compare page's template."""
    from depotbench.eval.report.page import Table, render

    wide = Table(
        header=["family", "configuration", *(f"figure {i}" for i in range(10))],
        rows=[["demo: actors[0].count = 12", "box_epipolar_flow epsilon_px=0.5", *(1234.5678,) * 10]],
    )
    page = tmp_path / "wide.html"
    sections = [{"heading": "Wide", "table": wide}]
    page.write_text(render("compare_page.html.j2", title="t", subtitle="", notes=[], sections=sections))
    shown = _open_in_chromium(page, tmp_path / "wide.png", width=700)
    assert shown["errors"] == [] and shown["overflowing"] == [] and shown["page_width"] <= 700


def test_words_are_set_flush_left_and_figures_flush_right_under_their_headers(tmp_path: Path):
    """Issue 54: every cell but the first column's was right-aligned, so a column of
    detector names was ragged on its left under a header set right. A column whose every
    filled cell is words is now flush left with its header; figures, and strings that read
    as figures ("19/20", "-3.1 %"), stay flush right. Read from Chromium's computed style."""
    from depotbench.eval.report.page import Table, render

    table = Table(
        header=["configuration", "detector", "ATE (m)", "tracked", "change", "note"],
        rows=[
            ["none", "groundtruth", 0.0123, "19/20", "-3.1 %", None],
            ["box_rule k=2", "yolox-nano+faults", 0.5, "20/20", "+12 %", "lost at frame 4"],
        ],
    )
    assert table.words == [False, True, False, False, False, True]  # the first column: the stylesheet's
    page = tmp_path / "aligned.html"
    page.write_text(
        render(
            "compare_page.html.j2",
            title="t",
            subtitle="",
            notes=[],
            sections=[{"heading": "T", "table": table}],
        )
    )
    probe = (
        "() => Array.from(document.querySelectorAll('table tr')).map(r => "
        "Array.from(r.children).map(c => getComputedStyle(c).textAlign))"
    )
    shown = _open_in_chromium(page, tmp_path / "aligned.png", width=1000, probe=probe)
    assert shown["errors"] == []
    columns = ["left", "left", "right", "right", "right", "left"]
    assert shown["probe"] == [columns] * 3, shown["probe"]
