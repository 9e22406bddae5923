"""The sweep report's plots and page (issue 36, point 6): threshold curves with their 95 %
bands and the ``none`` baseline, a colour per family in every figure, legends outside the
data, every run of every configuration per family, labelled Pareto points, a section per
family (or the page says which it left out) and each sequence's knobs and seed.

The figures are checked on rows built here (no simulation); the page on a tiny sweep."""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.metrics.record import RunRecord
from depotbench.eval.sweep.summary import (
    FAILED_COLOUR,
    configurations,
    family_colours,
    pareto,
    pareto_figure,
    plot,
    pyplot,
    short_label,
    strip_figures,
    threshold_figures,
)
from matplotlib.collections import PathCollection, PolyCollection
from matplotlib.colors import to_rgba

from tests.records import record

FAMILIES = ("fam a", "fam b", "fam c")
"""fam c ran one seed: its curves have no interval."""
SPREAD = {1: 0.003, 2: 0.0005, 3: 0.0071}
"""What a seed adds to a family's ATE (not evenly spaced: a bootstrap interval of evenly
spaced values is degenerate)."""


def _row(family: str, seed: int, strategy: str, settings: dict, ate: float | None, **extra) -> RunRecord:
    return record(
        **(
            {
                "key": f"{family}-{seed}-{strategy}-{json.dumps(settings)}",
                "family": family,
                "sequence": f"seq-{family}-{seed}",
                "seed": seed,
                "knobs": json.dumps({"seed": seed}),
                "tracker": "builtin",
                "parameters": "{}",
                "detector": "groundtruth",
                "strategy": strategy,
                "settings": json.dumps(settings),
                "failure": None,
                "ate_rmse_m": ate,
                "rejection_precision": None if strategy == "none" else 0.4 + 0.01 * seed,
                "rejection_recall": None if strategy == "none" else 0.9,
                "tracked_fraction": 1.0,
                "track_ms_median": 5.0 + (0 if strategy == "none" else 1.0) + 0.1 * seed,
            }
            | extra
        )
    )


def _rows() -> list[RunRecord]:
    rows = []
    for f, family in enumerate(FAMILIES):
        seeds = (1,) if family == "fam c" else (1, 2, 3)
        for seed in seeds:
            base = 0.05 + 0.02 * f + SPREAD[seed]
            rows.append(_row(family, seed, "none", {}, base * 1.5))
            for k in (1.5, 2.5, 3.5):
                rows.append(_row(family, seed, "prior_flow", {"k": k}, base * (1 + 0.1 * k)))
            for eps in (0.5, 2.0):
                rows.append(
                    _row(family, seed, "box_epipolar_flow", {"epsilon_px": eps}, base * (1 + eps / 10))
                )
    # fam b: one seed of one setting failed (an external program's exit), one lost track.
    for i, r in enumerate(rows):
        if r.family == "fam b" and r.strategy == "box_epipolar_flow" and r.seed == 2:
            if json.loads(r.settings) == {"epsilon_px": 0.5}:
                rows[i] = replace(r, failure="exit 3", ate_rmse_m=None)
            else:
                rows[i] = replace(r, tracked_fraction=0.5)
    return rows


@pytest.fixture(scope="module")
def rows() -> list[RunRecord]:
    return _rows()


@pytest.fixture(scope="module")
def configs(rows: list[dict]) -> list[dict]:
    return configurations(rows)


def _outside(fig, legend) -> bool:
    """The legend's box shares no pixel with any panel's box."""
    fig.canvas.draw()
    box = legend.get_window_extent()
    return all(not box.overlaps(ax.get_window_extent()) for ax in fig.axes)


def _line_colour(ax, label_start: str):
    lines = [line for line in ax.get_lines() if line.get_label().startswith(label_start)]
    assert len(lines) == 1, [line.get_label() for line in ax.get_lines()]
    return to_rgba(lines[0].get_color())


def test_threshold_curves_have_bands_baselines_one_colour_per_family_and_a_legend_outside(configs):
    figures = dict(threshold_figures(configs))
    assert sorted(figures) == ["box_epipolar_flow-epsilon_px", "prior_flow-k"]
    colours = {f: to_rgba(c) for f, c in family_colours(FAMILIES).items()}
    assert len(set(colours.values())) == 3
    for name, fig in figures.items():
        ate, rejection = fig.axes
        # A band per family with an interval (n >= 2: fam a, fam b), none for fam c's one seed.
        bands = [c for c in ate.collections if isinstance(c, PolyCollection)]
        assert sorted(to_rgba(b.get_facecolor()[0])[:3] for b in bands) == sorted(
            colours[f][:3] for f in ("fam a", "fam b")
        ), name
        # Each family's curve in its colour, the same in both figures.
        for family in FAMILIES:
            assert _line_colour(ate, family) == colours[family], (name, family)
        # Each family's none run: one horizontal dashed line in the family's colour, at its mean.
        dashed = [line for line in ate.get_lines() if line.get_linestyle() == "--"]
        assert len(dashed) == 3, name
        for family in FAMILIES:
            none = next(c for c in configs if c["family"] == family and c["strategy"] == "none")
            mine = [line for line in dashed if to_rgba(line.get_color()) == colours[family]]
            assert len(mine) == 1
            assert all(y == pytest.approx(none["ate_rmse_m"]) for y in mine[0].get_ydata())
        # The rejection panel keeps the families' colours.
        assert {to_rgba(line.get_color()) for line in rejection.get_lines()} == set(colours.values())
        assert len(fig.legends) == 1 and _outside(fig, fig.legends[0]), name
        pyplot().close(fig)


def test_a_band_spans_the_interval_of_the_mean(configs):
    figures = dict(threshold_figures(configs))
    ate = figures["prior_flow-k"].axes[0]
    colour = to_rgba(family_colours(FAMILIES)["fam a"])
    (band,) = [c for c in ate.collections if to_rgba(c.get_facecolor()[0])[:3] == colour[:3]]
    lows = sorted(
        c["stats"]["ate_rmse_m"]["ci_low"]
        for c in configs
        if c["family"] == "fam a" and c["strategy"] == "prior_flow"
    )
    highs = sorted(
        c["stats"]["ate_rmse_m"]["ci_high"]
        for c in configs
        if c["family"] == "fam a" and c["strategy"] == "prior_flow"
    )
    ys = band.get_paths()[0].vertices[:, 1]
    assert min(ys) == pytest.approx(lows[0]) and max(ys) == pytest.approx(highs[-1])
    for _, fig in figures.items():
        pyplot().close(fig)


def test_every_run_is_a_point_and_failed_runs_are_marked(configs, rows):
    figures = {family: fig for family, _, fig in strip_figures(configs, rows)}
    assert sorted(figures) == list(FAMILIES)
    for family, fig in figures.items():
        (ax,) = fig.axes
        points = [c for c in ax.collections if isinstance(c, PathCollection)]
        assert sum(len(c.get_offsets()) for c in points) == sum(r["family"] == family for r in rows)
        labels = [t.get_text() for t in ax.get_yticklabels()]
        assert labels[0] == "none" and "prior_flow k=2.5" in labels and len(labels) == 6
        failed = [c for c in points if to_rgba(c.get_edgecolor()[0]) == to_rgba(FAILED_COLOUR)]
        legend = " ".join(t.get_text() for t in fig.legends[0].get_texts())
        if family == "fam b":
            # The failed run: a red x at the right edge, on its configuration's row; the
            # run that lost track: a hollow point; and the legend says what each is.
            (marks,) = failed
            (x, y), others = marks.get_offsets()[0], [c for c in points if c is not marks]
            assert x > max(o[0] for c in others for o in c.get_offsets())
            assert labels[round(y)] == "box_epipolar_flow epsilon_px=0.5"
            assert "failed run" in legend and "tracked under 90%" in legend
            held = {t.get_text() for t in ax.texts}
            assert {"2/3", "3/3"} <= held
        else:
            assert failed == [] and "failed" not in legend
        assert _outside(fig, fig.legends[0])
        pyplot().close(fig)


def test_pareto_points_are_labelled_and_the_legend_is_outside(configs):
    fig = pareto_figure(configs)
    (ax,) = fig.axes
    front = pareto(configs)
    assert sorted(t.get_text() for t in ax.texts) == sorted(short_label(c) for c in front)
    legend = ax.get_legend()
    assert {t.get_text() for t in legend.get_texts()} >= set(FAMILIES)
    assert _outside(fig, legend)
    pyplot().close(fig)


def test_plot_writes_each_familys_runs(configs, rows, tmp_path: Path):
    written = {p.name for p in plot(configs, tmp_path / "plots", rows)}
    assert written == {
        "runs-fam_a.png",
        "runs-fam_b.png",
        "runs-fam_c.png",
        "pareto.png",
        "prior_flow-k.png",
        "box_epipolar_flow-epsilon_px.png",
    }


# -- the page of a sweep with four families -------------------------------------------------------

COUNTS = (1, 2, 3)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("families")
    (root / "suite.yaml").write_text(
        f"suite: walkers\nbase: smoke\noverrides: {{frames: 6}}\ngrid:\n  actors.0.count: {list(COUNTS)}\n"
        "seeds: [1, 2]\n"
    )
    (root / "spec.yaml").write_text(
        "sweep: families\nsuite: suite.yaml\nstrategies: [none, prior_flow]\n"
        "thresholds: {prior_flow: {k: {grid: [1.5, 3.0]}}}\n"
    )
    assert main(["sweep", str(root / "spec.yaml"), "-o", str(root / "sw")]) == 0
    return root / "sw"


def _section(page: str, heading: str) -> str:
    start = page.index(f"<h2>{heading}</h2>")
    return page[start : page.index("</section>", start)]


def _family(count: int) -> str:
    return f"walkers actors.0.count={count}"


def _shown(count: int) -> str:
    """The family as the page names it (its key stays in gate files)."""
    return f"walkers: actors[0].count = {count}"


@pytest.fixture(scope="module")
def page(sweep: Path, tmp_path_factory) -> str:
    out = tmp_path_factory.mktemp("page")
    assert main(["report", str(sweep), "-o", str(out)]) == 0
    return (out / "index.html").read_text()


@pytest.mark.render
def test_the_sweep_writes_each_familys_runs_plot(sweep: Path):
    """The sweep itself (not only the report) draws every family's runs across seeds."""
    written = {p.name for p in (sweep / "plots").glob("runs-*.png")}
    assert len(written) == len(COUNTS), written


@pytest.mark.render
def test_every_family_gets_its_section_with_every_run_and_its_best_run(page: str):
    """Each family shows its best run, and beside it the baseline (none) run unless the best
    run is that one (which of none and prior_flow wins a 10-frame family is the tracker's
    business: at 0.5.2 none wins two of the four)."""
    baselines = 0
    for count in COUNTS:
        family = _family(count)
        assert f"<h2>Family: {_shown(count)}</h2>" in page and f"<code>{family}</code>" in page
        assert f'alt="runs of {family}"' in page
        best = re.search(rf"<h2>{re.escape(_shown(count))}: best — builtin · (\w+)", page)
        assert best, family
        shown = f"<h2>{_shown(count)}: baseline (none) — builtin · none · groundtruth" in page
        assert shown == (best.group(1) != "none"), family
        baselines += shown
    assert baselines >= 1
    assert "Left out" not in page
    assert "http://" not in page and "https://" not in page and "<script" not in page


@pytest.mark.slow  # 12 s
@pytest.mark.render
def test_featured_runs_tracked_again_in_two_workers_equal_those_tracked_here(sweep: Path, monkeypatch):
    """``--workers``: the runs a page tracks again are shared among processes (here from 0
    frames, not 300), and come back with the same trajectories, states and keypoint decisions,
    in the families' order."""
    import depotbench.eval.report.html as html
    from depotbench.eval.report import view_cache

    seen: dict[int, list] = {1: [], 2: []}
    view_of = html.view_of
    for workers in (1, 2):

        def capture(title, tracked, sequence, into=seen[workers]):
            view = view_of(title, tracked, sequence)
            into.append((title, view.estimate, view.states, view.diagnostics))
            return view

        monkeypatch.setattr(html, "view_of", capture)
        monkeypatch.setattr(html, "PARALLEL_FRAMES", 0)
        monkeypatch.setattr(view_cache, "load", lambda cache, key: None)  # tracked, not read back
        html.sweep_page(sweep, html.Notes(), workers=workers)
    assert len(seen[1]) >= len(COUNTS) and [s[0] for s in seen[1]] == [s[0] for s in seen[2]]
    for (_, estimate1, states1, kept1), (_, estimate2, states2, kept2) in zip(seen[1], seen[2], strict=True):
        assert states1 == states2
        np.testing.assert_array_equal(estimate1.positions_m, estimate2.positions_m)
        np.testing.assert_array_equal(estimate1.rotations, estimate2.rotations)
        assert kept1.keys() == kept2.keys()
        for name in kept1.keys() - {"stage_ms"}:  # stage_ms: each run's own timings
            np.testing.assert_array_equal(kept1[name], kept2[name], err_msg=name)


@pytest.mark.render
def test_a_family_whose_every_run_failed_keeps_its_section(sweep: Path, monkeypatch):
    """Such a family has no run to track again, but its section still says why (a rename in
    the page's code once left it out, with its runs' strip)."""
    import depotbench.eval.report.html as html

    failed = _family(COUNTS[0])
    featured = html._featured_configuration

    def none_for_one(family, configs, best):
        return None if family == failed else featured(family, configs, best)

    monkeypatch.setattr(html, "_featured_configuration", none_for_one)
    page = html.sweep_page(sweep, html.Notes())
    section = _section(page, f"Family: {_shown(COUNTS[0])}")
    assert "Every run of every configuration failed" in section and f'alt="runs of {failed}"' in section
    assert f"<h2>Family: {_shown(COUNTS[1])}</h2>" in page


@pytest.mark.render
def test_tables_show_the_interval_n_and_the_runs_held(page: str):
    best = _section(page, "Best configuration per family")
    assert "<th>runs held</th>" in best and best.count("<td>2/2</td>") == len(COUNTS)
    assert best.count("n=2</small>") >= len(COUNTS)
    assert re.search(r"<td>\d\.\d+<br><small>\[\d\.\d+, \d\.\d+\] n=2</small></td>", best)


@pytest.mark.render
def test_the_difficulty_table_lists_each_sequences_knobs_and_seed(page: str):
    table = _section(page, "Scenario difficulty")
    # the knobs are words, set flush left under a header that is too; the seed is a figure
    assert '<th>seed</th><th class="words">knobs</th>' in table
    rows = re.findall(r'<tr><td>(walkers-\d+)</td><td>(\d+)</td><td class="words">([^<]*)</td>', table)
    assert sorted((int(seed), knobs) for _, seed, knobs in rows) == sorted(
        (seed, f"actors.0.count={count}") for count in COUNTS for seed in (1, 2)
    )


@pytest.mark.render
def test_families_past_the_bound_are_named_in_the_notes(sweep: Path):
    from depotbench.eval.report.html import Notes, sweep_page

    notes = Notes()
    text = sweep_page(sweep, notes, featured=2)
    assert text.count("<h2>Family: ") == 2 and f"<h2>Family: {_shown(3)}</h2>" not in text
    (note,) = [n for n in notes.items if "families" in n]
    assert "1 of 3 families" in note and "at most 2" in note and note.endswith(_shown(3))
    assert _shown(3) in _section(text, "Left out")


@pytest.mark.render
def test_a_family_where_nothing_held_is_named_and_still_shown(sweep: Path, tmp_path: Path, capfd):
    copy = tmp_path / "sw"
    shutil.copytree(sweep, copy)  # its sequences inside it: a copied sweep folder is the sweep
    summary = json.loads((copy / "summary.json").read_text())
    family = _family(2)
    del summary["best"][family]
    summary["unqualified"] = {family: 0.5}
    (copy / "summary.json").write_text(json.dumps(summary))
    assert main(["report", str(copy), "-o", str(tmp_path / "out")]) == 0
    assert "warning" not in capfd.readouterr().err
    page = (tmp_path / "out" / "index.html").read_text()
    best = _section(page, "Best configuration per family")
    assert "No configuration held on enough runs in 1 family" in best
    assert f"<li>{family}: the best held on 50% of its runs</li>" in best
    assert f"<h2>{_shown(2)}: most reliable (held on 2/2; none held on enough runs)" in page


def test_random_samples_are_shown_short_and_a_wide_spread_of_ate_is_drawn_on_a_log_scale():
    """detector_faults.yaml draws prior_flow's k at random: labels carried 1.0495829065855873,
    ticks at 1.0496 and 1.1229 overlapped, and a none run at 0.115 m flattened curves at
    0.003 m onto the axis."""
    ks = [1.0495829065855873, 1.1229205718085842, 2.910885061964363]
    rows = []
    for seed in (1, 2, 3):
        rows.append(_row("fam a", seed, "none", {}, 0.115 + SPREAD[seed]))
        rows += [_row("fam a", seed, "prior_flow", {"k": k}, 0.003 + SPREAD[seed] / 10) for k in ks]
    configs = configurations(rows)
    labels = {c["label"] for c in configs}
    assert "prior_flow k=1.04958" in labels and "prior_flow k=2.91089" in labels
    (fig,) = [fig for name, fig in threshold_figures(configs) if name == "prior_flow-k"]
    ate = fig.axes[0]
    assert ate.get_yscale() == "log"
    fig.canvas.draw()
    ticks = [t.get_text() for t in ate.get_xticklabels()]
    samples = {f"{k:{form}}" for k in ks for form in ("g", ".4g")}
    assert ticks and not samples & set(ticks), ticks  # matplotlib's own ticks, not the samples
    pyplot().close(fig)
    grid = [_row("fam a", 1, "prior_flow", {"k": k}, 0.05 + k / 100) for k in (1.5, 2.5, 3.5)]
    (fig,) = [fig for _, fig in threshold_figures(configurations(grid))]
    fig.canvas.draw()
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["1.5", "2.5", "3.5"]
    assert fig.axes[0].get_yscale() == "linear"
    pyplot().close(fig)
