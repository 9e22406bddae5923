"""A run's dense map (``depotbench run --map``): written as PLY with the run, scored against the
exact static world, and its ghosts are the walkers' where the strategy kept them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from depotbench.eval.cli.main import main
from depotbench.eval.metrics.map import reference_clouds
from depotbench.eval.report.maps import GHOST, GHOST_RGB, STATIC, placed_map, top_views
from depotbench.eval.run.dense import anchor
from depotbench.eval.trackers.base import TrackerRun
from depotbench.sim.sequence import Sequence
from scipy.spatial.transform import Rotation

from tests.test_output import cli, one_error_line

pytestmark = pytest.mark.render


@pytest.fixture(scope="module")
def walking(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dense") / "walking"
    # The perfect sensor: a program's own map is checked point for point against the bench's.
    # Seed 2: a walker stands in the first frame's view, so a map of that frame holds ghosts
    # (seed 1 has none since --seed draws the walkers' speeds from the seed given).
    args = [
        "generate",
        "walking_static",
        "-o",
        str(out),
        "--frames",
        "30",
        "--seed",
        "2",
        "--sensor",
        "perfect",
    ]
    assert main(args) == 0
    return out


def _map_run(sequence: Path, out: Path, strategy: str) -> dict:
    assert main(["run", str(sequence), "-o", str(out), "--strategy", strategy, "--map"]) == 0
    return json.loads((out / "metrics.json").read_text())["map"]


@pytest.mark.slow  # 32 s; test_map_metrics.py counts ghosts on a synthetic scene by default
def test_the_map_is_written_with_the_run_and_the_walkers_ghosts_are_rejected(walking: Path, tmp_path: Path):
    bare = _map_run(walking, tmp_path / "none", "none")
    cloud = trimesh.load(tmp_path / "none" / "map.ply")
    # readable as the run's other files are (it was written 0600, as a private temporary file)
    assert (tmp_path / "none" / "map.ply").stat().st_mode == (
        tmp_path / "none" / "metrics.json"
    ).stat().st_mode
    assert len(cloud.vertices) == bare["points"] > 10_000 and len(cloud.colors) == bare["points"]
    assert bare["threshold_m"] == 0.05 and len(bare["scores"]) == 3
    # Without rejection the walkers stand in the map, and their ghosts are theirs (persons).
    assert bare["ghost_fraction"] > 0.05
    assert sum(bare["ghosts"].values()) > 0 and all(who.startswith("person") for who in bare["ghosts"])
    rejected = _map_run(walking, tmp_path / "bef", "box_epipolar_flow")
    assert rejected["ghost_fraction"] < bare["ghost_fraction"] / 5
    assert rejected["accuracy"] > bare["accuracy"]
    # accuracy + ghosts + neither is every map point, at each threshold
    for scores in (bare["scores"], rejected["scores"]):
        for s in scores:
            assert s["accuracy"] + s["ghost_fraction"] + s["neither_fraction"] == pytest.approx(1.0)
    # The picture's classes are the figures' (the same placement, threshold and reference).
    reference = reference_clouds(Sequence.open(walking))
    placed = placed_map(tmp_path / "none", reference, "none")
    assert (placed.kinds == GHOST).sum() == sum(bare["ghosts"].values())
    assert (placed.kinds == STATIC).mean() == pytest.approx(bare["accuracy"])
    fig = top_views([placed, placed_map(tmp_path / "bef", reference, "box_epipolar_flow")])
    drawn = [ax.collections[0].get_facecolors()[:, :3] for ax in fig.axes]
    red = [int(np.all(np.isclose(c, GHOST_RGB), axis=1).sum()) for c in drawn]
    assert red == [sum(bare["ghosts"].values()), sum(rejected["ghosts"].values())]


def test_a_static_scene_maps_without_ghosts_and_close_to_the_truth(tmp_path: Path):
    sequence = tmp_path / "static"
    assert main(["generate", "static_depot", "-o", str(sequence), "--frames", "15", "--seed", "2"]) == 0
    found = _map_run(sequence, tmp_path / "run", "none")
    assert found["ghost_fraction"] == 0 and found["ghosts"] == {}
    assert found["accuracy"] > 0.9  # the tracked poses are millimetres off; the default sensor is exact


def test_a_map_needs_the_built_in_tracker(walking: Path, tmp_path: Path, capsys):
    args = [
        "run",
        str(walking),
        "-o",
        str(tmp_path / "r"),
        "--map",
        "--slam",
        "cmd",
        "--command",
        "true {sequence}",
    ]
    code, _, err = cli(capsys, *args)
    assert code == 2
    one_error_line(err, "--map needs a tracker with a map")
    assert not (tmp_path / "r").exists()


def test_the_map_is_placed_by_its_first_keyframe(walking: Path):
    """Estimated keyframe poses that are the true ones seen from another world (a rigid motion
    away) are taken back onto the true ones exactly."""
    sequence = Sequence.open(walking)
    motion = np.eye(4)
    motion[:3, :3] = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()
    motion[:3, 3] = (4.0, -2.0, 0.5)
    indices = (3, 9, 17)
    estimated = {i: motion @ sequence.world_from_camera(i) for i in indices}
    run = TrackerRun(
        timestamps_s=np.zeros(0),
        states=(),
        poses=(),
        track_ms=np.zeros(0),
        keyframes=len(indices),
        total_s=0.0,
        keyframe_poses=estimated,
    )
    placed = anchor(sequence, run)
    for i in indices:
        centre = placed.scale * placed.rotation @ estimated[i][:3, 3] + placed.translation
        np.testing.assert_allclose(centre, sequence.world_from_camera(i)[:3, 3], atol=1e-9)


@pytest.mark.slow  # 45 s; the map of a single run is checked in the default run
def test_a_sweep_with_dense_maps_gives_each_row_the_figures_of_its_run_alone(walking: Path, tmp_path: Path):
    """Rows of a dense_map sweep (tracked once while their decisions agree, then forked; rows
    with the same decisions and reasons shared) carry the map figures the same job gives run
    alone, and gates bound them."""
    from depotbench.eval.sweep.store import ResultStore

    import depotbench

    spec = tmp_path / "maps.yaml"
    spec.write_text(
        f"sweep: maps\nsequences: [{walking}]\ndense_map: true\n"
        "strategies: [none, box_rule, box_epipolar_flow]\n"
        "thresholds: {box_epipolar_flow: {epsilon_px: {grid: [0.5, 1.0, 2.0]}}}\n"
    )
    assert main(["sweep", str(spec), "-o", str(tmp_path / "sw"), "--workers", "2"]) == 0
    with ResultStore(tmp_path / "sw" / "results.sqlite", readonly=True) as store:
        rows = store.records()
    assert len(rows) == 5 and all(r.map_f_score is not None and r.ghost_fraction is not None for r in rows)
    for row in rows:
        settings = json.loads(row.settings)
        alone = depotbench.run(walking, strategy=row.strategy, settings=settings, dense_map=True)
        assert alone.key == row.key
        for name in ("map_f_score", "map_accuracy", "map_completeness", "ghost_fraction", "ate_rmse_m"):
            assert getattr(alone, name) == pytest.approx(getattr(row, name), rel=1e-12, abs=1e-15), name
    by_strategy = {r.strategy: r for r in rows}
    assert by_strategy["none"].ghost_fraction > 0.05 > by_strategy["box_epipolar_flow"].ghost_fraction
    gates = tmp_path / "gates.yaml"
    gates.write_text(
        f"gates: maps\nrun:\n  sequences: [{walking}]\n  dense_map: true\n"
        "  strategies: [none, box_rule, box_epipolar_flow]\n"
        "  thresholds: {box_epipolar_flow: {epsilon_px: {grid: [0.5, 1.0, 2.0]}}}\n"
        "checks:\n"
        "  - {name: clean, strategies: [box_epipolar_flow], budgets: {ghost_fraction: {max: 0.02}}}\n"
        "  - {name: haunted, strategies: [none], budgets: {ghost_fraction: {max: 0.02}}}\n"
    )
    report = depotbench.check(gates, tmp_path / "sw")
    assert [line.split(" [")[0] for line in report.failures] == ["haunted"]
    # The sweep's page sets the best run's map beside its none run's, as method 2's two pictures.
    page = depotbench.report(tmp_path / "sw", tmp_path / "page").read_text()
    assert page.count("<h3>Dense maps</h3>") == 1 and 'alt="dense maps of ' in page


@pytest.mark.slow  # 19 s; test_report.py opens a run page in Chromium by default
def test_the_run_page_shows_the_map_and_names_a_damaged_one(walking: Path, tmp_path: Path, capsys):
    run = tmp_path / "run"
    _map_run(walking, run, "box_rule")
    assert main(["report", str(run), "-o", str(tmp_path / "page")]) == 0
    page = (tmp_path / "page" / "index.html").read_text()
    assert "<h3>Dense map</h3>" in page and 'alt="dense map from above"' in page
    assert page.count("<td>5 cm</td>") == 1
    capsys.readouterr()
    (run / "map.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 9\n")  # cut short
    assert main(["report", str(run), "-o", str(tmp_path / "page2")]) == 0
    page = (tmp_path / "page2" / "index.html").read_text()
    assert "<h3>Dense map</h3>" not in page and "map.ply: cannot be read" in page
    assert "map.ply: cannot be read" in capsys.readouterr().err


@pytest.mark.slow  # 17 s; test_report.py reads a run's recording back by default
def test_the_rerun_recording_holds_the_map_as_a_point_cloud(walking: Path, tmp_path: Path):
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    run = tmp_path / "run"
    _map_run(walking, run, "none")
    path = tmp_path / "run.rrd"
    assert main(["report", str(run), "-o", str(tmp_path / "page"), "--rerun", str(path)]) == 0
    entities = {str(chunk.entity_path) for chunk in RrdReader(str(path)).stream()}
    assert "/world/map" in entities and "/world/estimate" in entities


def test_a_programs_own_map_is_placed_and_scored_like_the_built_in_one(walking: Path, tmp_path: Path):
    """A program that writes {map} (tests/programs/map_slam.py: the first frame's depth in its own
    world, the first camera) is scored like the built-in map: exact depth, exact poses, so every
    point is the static world's or a walker's ghost."""
    import shlex
    import sys

    program = Path(__file__).parent / "programs" / "map_slam.py"
    command = f"{shlex.quote(sys.executable)} {program} {{sequence}} {{trajectory}} {{map}}"
    out = tmp_path / "run"
    assert main(["run", str(walking), "-o", str(out), "--slam", "cmd", "--command", command, "--map"]) == 0
    found = json.loads((out / "metrics.json").read_text())["map"]
    assert found["keyframes"] is None and found["points"] > 10_000
    at_2cm = found["scores"][0]
    assert at_2cm["threshold_m"] == 0.02
    assert at_2cm["accuracy"] + at_2cm["ghost_fraction"] == pytest.approx(1.0, abs=1e-3)
    assert found["ghost_fraction"] > 0 and all(who.startswith("person") for who in found["ghosts"])
    assert len(trimesh.load(out / "map.ply").vertices) == found["points"]
    # A map the program wrote damaged is its failure, named in one line.
    bad = 'sh -c \'echo ply > "$1"; cp "$2/groundtruth.txt" "$3"\' sh {map} {sequence} {trajectory}'
    code = main(
        ["run", str(walking), "-o", str(tmp_path / "bad"), "--slam", "cmd", "--command", bad, "--map"]
    )
    assert code != 0 and (tmp_path / "bad" / "failure.json").is_file()  # kept to debug by
    assert not (tmp_path / "bad" / "map.ply").exists()
