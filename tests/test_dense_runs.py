"""A run's dense map (``depotbench run --map``): written as PLY with the run, scored against the
exact static world, and its ghosts are the walkers' where the strategy kept them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from depotbench.eval.cli.main import main
from depotbench.eval.run.dense import anchor
from depotbench.eval.trackers.base import TrackerRun
from depotbench.sim.sequence import Sequence
from scipy.spatial.transform import Rotation

from tests.test_output import cli, one_error_line

pytestmark = pytest.mark.render


@pytest.fixture(scope="module")
def walking(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dense") / "walking"
    assert main(["generate", "walking_static", "-o", str(out), "--frames", "30", "--seed", "1"]) == 0
    return out


def _map_run(sequence: Path, out: Path, strategy: str) -> dict:
    assert main(["run", str(sequence), "-o", str(out), "--strategy", strategy, "--map"]) == 0
    return json.loads((out / "metrics.json").read_text())["map"]


def test_the_map_is_written_with_the_run_and_the_walkers_ghosts_are_rejected(walking: Path, tmp_path: Path):
    bare = _map_run(walking, tmp_path / "none", "none")
    cloud = trimesh.load(tmp_path / "none" / "map.ply")
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
    one_error_line(err, "--map needs the built-in tracker")
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
