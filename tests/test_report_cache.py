"""A finished sweep's page is written again from the runs its first page tracked again, kept
in the sweep folder (``eval/report/view_cache.py``): nothing is tracked the second time,
whatever the stage cache holds and wherever the folder was copied, and the page is the same,
byte for byte (a page tracked again differs in its timings only)."""

from __future__ import annotations

from pathlib import Path

import pytest
from depotbench.eval.cli.main import main
from depotbench.eval.report import html


@pytest.fixture(scope="module")
def sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("cached")
    assert main(["generate", "smoke", "-o", str(root / "seq"), "--seed", "2", "--frames", "24"]) == 0
    spec = root / "sweep.yaml"
    spec.write_text(f"sweep: cached\nsequences: [{root / 'seq'}]\nstrategies: [none, box_rule]\n")
    assert main(["sweep", str(spec), "-o", str(root / "sweep"), "--workers", "1"]) == 0
    return root / "sweep"


def test_a_second_page_of_a_finished_sweep_tracks_nothing_and_is_the_same(
    sweep: Path, tmp_path: Path, monkeypatch
):
    calls = []
    track_again = html._track_again
    monkeypatch.setattr(html, "_track_again", lambda *a: calls.append(a) or track_again(*a))
    assert main(["report", str(sweep), "-o", str(tmp_path / "first")]) == 0
    assert len(calls) == 2  # the best run and its none run, tracked again for the first page
    monkeypatch.setattr(html, "_track_again", lambda *a: pytest.fail("tracked again for the second page"))
    assert main(["report", str(sweep), "-o", str(tmp_path / "second")]) == 0
    first = (tmp_path / "first" / "index.html").read_bytes()
    assert first == (tmp_path / "second" / "index.html").read_bytes()
    assert b"trajectory" in first.lower()


def test_a_copied_sweep_with_the_stage_cache_off_tracks_nothing_again(
    sweep: Path, tmp_path: Path, monkeypatch
):
    """The views travel with the sweep. Kept in the stage cache until 2026-12-05, they were
    lost with it: the demo's second page with the cache off tracked its six runs again."""
    import shutil

    assert main(["report", str(sweep), "-o", str(tmp_path / "first")]) == 0  # views kept, if not yet
    copy = tmp_path / "elsewhere" / sweep.name  # the page names the folder
    shutil.copytree(sweep, copy)
    monkeypatch.setenv("DEPOTBENCH_CACHE_STAGES", "off")
    monkeypatch.setattr(html, "_track_again", lambda *a: pytest.fail("tracked again for the copy's page"))
    assert main(["report", str(copy), "-o", str(tmp_path / "second")]) == 0
    first = (tmp_path / "first" / "index.html").read_bytes()
    assert first == (tmp_path / "second" / "index.html").read_bytes()


def test_a_damaged_view_entry_is_tracked_again(sweep: Path, tmp_path: Path, monkeypatch):
    from depotbench.eval.report import view_cache

    cache = view_cache.of_sweep(sweep)
    for entry in (cache.root / view_cache.STAGE).glob("*"):  # other tests' pages' views out
        entry.unlink()
    assert main(["report", str(sweep), "-o", str(tmp_path / "first")]) == 0
    entries = sorted((cache.root / view_cache.STAGE).iterdir())
    assert len(entries) == 2
    for entry in entries:
        data = bytearray(entry.read_bytes())
        data[-100] ^= 0xFF  # a flipped byte: its digest no longer matches
        entry.write_bytes(bytes(data))
    calls = []
    track_again = html._track_again
    monkeypatch.setattr(html, "_track_again", lambda *a: calls.append(a) or track_again(*a))
    assert main(["report", str(sweep), "-o", str(tmp_path / "second")]) == 0
    assert len(calls) == 2  # each damaged entry is a miss: tracked again, and stored again whole
    assert all(cache.get(view_cache.STAGE, entry.name) is not None for entry in entries)


def test_the_views_of_rows_that_prune_stale_removed_go_with_the_next_page(
    sweep: Path, tmp_path: Path, monkeypatch
):
    """Swept again by other code with ``--prune-stale``, a folder's rows of the older code go
    and, at the next page, so do their views; the views of the rows it holds stay. Before,
    they stayed until the folder's 1 GB bound evicted them."""
    import shutil

    from depotbench.eval.report import view_cache
    from depotbench.eval.run import detections, harness, stages
    from depotbench.eval.sweep import engine

    copy = tmp_path / sweep.name
    shutil.copytree(sweep, copy)
    assert main(["report", str(copy), "-o", str(tmp_path / "first")]) == 0
    folder = view_cache.of_sweep(copy).root / view_cache.STAGE
    older = {p.name for p in folder.iterdir()}
    assert len(older) >= 2
    spec = sweep.parent / "sweep.yaml"
    for module in (harness, stages, detections, engine):  # the next release's code, in every key
        monkeypatch.setattr(module, "code_version", lambda: "99.0.0")
    assert main(["sweep", str(spec), "-o", str(copy), "--workers", "1"]) == 0
    assert main(["report", str(copy), "-o", str(tmp_path / "second")]) == 0
    assert older <= {p.name for p in folder.iterdir()}  # kept apart, not pruned: views kept
    assert main(["sweep", str(spec), "-o", str(copy), "--workers", "1", "--prune-stale"]) == 0
    monkeypatch.setattr(html, "_track_again", lambda *a: pytest.fail("the current rows' views were lost"))
    assert main(["report", str(copy), "-o", str(tmp_path / "third")]) == 0
    left = {p.name for p in folder.iterdir()}
    assert len(left) == 2 and not left & older


def test_a_resumed_sweep_with_nothing_new_keeps_its_plots_and_redraws_a_changed_one(sweep: Path):
    spec = sweep.parent / "sweep.yaml"
    plots = sorted((sweep / "plots").glob("*.png"))
    assert plots
    before = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in plots}
    assert main(["sweep", str(spec), "-o", str(sweep), "--workers", "1"]) == 0
    assert {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in plots} == before  # not drawn again
    plots[0].write_bytes(b"not a plot")
    assert main(["sweep", str(spec), "-o", str(sweep), "--workers", "1"]) == 0
    assert plots[0].read_bytes() == before[plots[0].name][1]  # drawn again, the same picture
