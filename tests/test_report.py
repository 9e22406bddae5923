"""The HTML report: written for a run and a sweep, opened in headless Chromium without console
errors, every plot decoded; plus the Rerun recording."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from depotbench.eval.cli.main import main

pytestmark = pytest.mark.render

BROWSERS = ("chromium", "chromium-browser", "google-chrome")


@pytest.fixture(scope="module")
def walking(tmp_path_factory) -> Path:
    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.generate import generate

    # walking_xyz seed 3: its walkers are in view from the first frames and the camera moves,
    # so a rejection strategy beats none (on 0.8.0's walking_static, 24 frames, none was best).
    update = {"frames": 24, "duration_s": None, "seed": 3}
    scenario = library.get("walking_xyz").model_copy(update=update)
    return generate(to_scenario(scenario), tmp_path_factory.mktemp("walk") / "walking", progress=False)


@pytest.fixture(scope="module")
def run_folder(walking: Path, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run") / "run"
    assert main(["run", str(walking), "-o", str(out), "--strategy", "box_epipolar_flow"]) == 0
    return out


def _open_in_chromium(page_path: Path, screenshot: Path, width: int = 1400, probe: str | None = None) -> dict:
    """Load the page in headless Chromium ``width`` CSS pixels wide; return console errors,
    page errors, image states (natural and rendered sizes, in CSS pixels), the sections
    whose content runs past their own edge (``overflowing``: their headings), and what the
    JavaScript function ``probe`` gives on the page."""
    playwright = pytest.importorskip("playwright.sync_api")
    executable = next((shutil.which(b) for b in BROWSERS if shutil.which(b)), None)
    if executable is None:
        pytest.fail("no Chromium: `make system-deps` installs Debian's chromium package")
    errors: list[str] = []
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=executable, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": width, "height": 1000})
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.on("requestfailed", lambda r: errors.append(f"request failed: {r.url}"))
        requests: list[str] = []
        page.on("request", lambda r: requests.append(r.url))
        page.goto(page_path.as_uri(), wait_until="load")
        images = page.evaluate(
            "() => Array.from(document.images).map(i => ({alt: i.alt, complete: i.complete,"
            " width: i.naturalWidth, height: i.naturalHeight, shownWidth: i.getBoundingClientRect().width,"
            " shownHeight: i.getBoundingClientRect().height, top: i.getBoundingClientRect().top}))"
        )
        headings = page.evaluate("() => Array.from(document.querySelectorAll('h2')).map(h => h.textContent)")
        overflowing = page.evaluate(
            "() => Array.from(document.querySelectorAll('section'))"
            ".filter(s => s.scrollWidth > s.clientWidth)"
            ".map(s => (s.querySelector('h2') || s).textContent.slice(0, 60))"
        )
        page_width = page.evaluate("() => document.documentElement.scrollWidth")
        probed = page.evaluate(probe) if probe is not None else None
        page.screenshot(path=str(screenshot), full_page=True)
        browser.close()
    external = [u for u in requests if not u.startswith(("file:", "data:"))]
    return {
        "errors": errors,
        "images": images,
        "headings": headings,
        "external": external,
        "overflowing": overflowing,
        "page_width": page_width,
        "probe": probed,
    }


def test_run_report_opens_in_chromium_with_its_plots(run_folder: Path, tmp_path: Path):
    assert main(["report", str(run_folder), "-o", str(tmp_path / "report")]) == 0
    page = tmp_path / "report" / "index.html"
    text = page.read_text()
    assert "http://" not in text and "https://" not in text  # self-contained
    assert text.endswith("</html>\n")  # a text file's last line ends
    shown = _open_in_chromium(page, tmp_path / "run.png")
    assert shown["errors"] == [] and shown["external"] == []
    alts = [i["alt"] for i in shown["images"]]
    assert alts == ["trajectory from above", "error over time", "frames with keypoints"]
    assert all(i["complete"] and i["width"] > 100 and i["height"] > 100 for i in shown["images"])
    assert (tmp_path / "run.png").stat().st_size > 20_000  # the screenshot was written


def test_sweep_report_shows_thresholds_pareto_and_the_best_runs(walking: Path, tmp_path: Path):
    spec = tmp_path / "sweep.yaml"
    spec.write_text(
        f"sweep: r\nsequences: [{walking}]\nstrategies: [none, box_epipolar_flow]\n"
        "thresholds: {box_epipolar_flow: {epsilon_px: {grid: [0.5, 2.0]}}}\n"
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sweep"), "--workers", "1"]) == 0
    assert main(["report", str(tmp_path / "sweep"), "-o", str(tmp_path / "report")]) == 0
    shown = _open_in_chromium(tmp_path / "report" / "index.html", tmp_path / "sweep.png")
    assert shown["errors"] == [] and shown["external"] == []
    alts = [i["alt"] for i in shown["images"]]
    assert "box_epipolar_flow-epsilon_px" in alts and "Pareto plot" in alts
    assert alts.count("frames with keypoints") == 2  # the family's best run and its none run
    assert all(i["complete"] and i["width"] > 100 for i in shown["images"])
    assert "Best configuration per family" in shown["headings"]
    assert "Scenario difficulty" in shown["headings"]


def test_report_never_writes_into_someone_elses_folder(run_folder: Path, tmp_path: Path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "index.html").write_text("my own page")
    assert main(["report", str(run_folder), "-o", str(mine)]) == 2
    assert "mine" in capsys.readouterr().err
    assert (mine / "index.html").read_text() == "my own page"
    # Its own report folder is refreshed in place.
    assert main(["report", str(run_folder), "-o", str(tmp_path / "report")]) == 0
    assert main(["report", str(run_folder), "-o", str(tmp_path / "report")]) == 0
    assert (tmp_path / "report" / "index.html").stat().st_size > 100_000


def test_report_refuses_a_folder_that_is_neither(tmp_path: Path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["report", str(tmp_path / "empty"), "-o", str(tmp_path / "out")]) == 2
    assert "neither a run folder" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_rerun_recording_of_a_run(run_folder: Path, tmp_path: Path):
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    path = tmp_path / "run.rrd"
    assert main(["report", str(run_folder), "-o", str(tmp_path / "report"), "--rerun", str(path)]) == 0
    reader = RrdReader(str(path))
    assert [r.application_id for r in reader.recordings()] == ["depotbench"]
    entities = {str(chunk.entity_path) for chunk in reader.stream()}
    assert {
        "/camera/image",
        "/camera/image/decision",
        "/camera/image/truth",
        "/world/groundtruth",
        "/world/estimate",
        "/error_m",
        "/state",
    } <= entities


def test_percentages_in_the_tables_are_shown_to_a_hundredth():
    """The demo's best run on the empty depot matched its reference within micrometres:
    rho was shown as '1.304e-06'; a percentage reads 0 there, and 82.39 elsewhere."""
    from depotbench.eval.report.html import percent
    from depotbench.eval.report.page import Table, table_html

    page = table_html(Table(["rho"], [[percent(1.304e-06)], [percent(82.39431659)], [percent(None)]]))
    assert "e-06" not in page
    assert "<td>0</td>" in page and "<td>82.39</td>" in page and "<td>–</td>" in page
