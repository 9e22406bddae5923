"""Scenario files, the library, sensor models and suites."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from depotbench.eval.cli.main import main
from depotbench.scenes import library
from depotbench.scenes.generation import run_suite
from depotbench.scenes.schema import Scenario, parse_scenario, to_scenario
from depotbench.scenes.suite import load_suite, variations
from depotbench.sim.sensor import kinect_sigma
from depotbench.sim.sequence import Sequence

from tests.conftest import REPO


def small(scenario: Scenario, frames: int, width: int = 96) -> Scenario:
    """The scenario at ``width`` pixels wide, its camera (a TUM analog's fr3 pinhole too) scaled."""
    height = width * 3 // 4
    k = scenario.intrinsics
    s = width / scenario.image.width
    camera = {"fx": k.fx * s, "fy": k.fy and k.fy * s}
    camera |= {name: (c + 0.5) * s - 0.5 for name, c in (("cx", k.cx), ("cy", k.cy)) if c is not None}
    return scenario.model_copy(
        update={
            "frames": frames,
            "duration_s": None,
            "image": scenario.image.model_copy(update={"width": width, "height": height}),
            "intrinsics": k.model_copy(update=camera),
        }
    )


def test_library_has_the_named_scenarios():
    names = set(library.names())
    required = {
        "walking_xyz",
        "walking_static",
        "walking_rpy",
        "walking_halfsphere",
        "sitting_static",
        "sitting_xyz",
        "sitting_halfsphere",
        "dog_and_cat_roaming",
        "pig_pen",
        "chair_pushing",
        "robot_aisle_patrol",
        "crowd",
        "static_depot",
    }
    assert required <= names
    assert set(library.names("tum-like")) == {n for n in required if n.startswith(("walking", "sitting"))}
    assert "smoke" in library.names("smoke")


def _assert_only_instances_move(world, name: str) -> None:
    """Pixels of the static world are given the world body, whose motion (none) is the
    flow's: so no body outside an instance may move; the camera rig, which moves, draws
    nothing."""
    model = world.model
    moves = (model.body_dofnum > 0) | (model.body_mocapid >= 0)
    for body in range(1, model.nbody):  # parents come before their children
        moves[body] |= moves[model.body_parentid[body]]
    for body in np.flatnonzero(moves & (world.body_instance == 0)):
        assert model.body(body).name == "camera_rig" and not (model.geom_bodyid == body).any(), name


@pytest.mark.slow  # 100 s: every library scene; the default run generates each kind of actor elsewhere
@pytest.mark.render
def test_every_library_scenario_generates_and_difficulty_orders_them(tmp_path: Path, monkeypatch):
    """Every library scene generates a sequence that verifies, its difficulty measures
    order the scenes as their names say, and in each only instances move and every
    instance has geoms (checked on the world generate builds, so that no scene is built
    twice)."""
    import depotbench.sim.generate
    from depotbench.scenes.generation import read_difficulty
    from depotbench.sim.generate import generate

    built = []
    build_world = depotbench.sim.generate.build_world

    def recording(spec):
        built.append(build_world(spec))
        return built[-1]

    monkeypatch.setattr(depotbench.sim.generate, "build_world", recording)
    difficulty = {}
    for name in library.names():
        out = generate(to_scenario(small(library.get(name), frames=6)), tmp_path / name, progress=False)
        Sequence.open(out).verify()
        difficulty[name] = read_difficulty(out)
        world = built.pop()
        _assert_only_instances_move(world, name)
        # every instance has geoms: the renderer's pixel counts (RenderedFrame.counts) run to
        # the largest instance id its geoms carry, and ground truth reads one per instance
        drawn = set(world.body_instance[world.model.geom_bodyid].tolist()) - {0}
        assert drawn == set(range(1, len(world.instances) + 1)), name
    fractions = {n: d["dynamic_pixel_fraction_mean"] for n, d in difficulty.items()}
    assert fractions["static_depot"] == 0.0 and difficulty["static_depot"]["dynamic_pixel_fraction_max"] == 0
    assert max(fractions, key=fractions.get) == "crowd"
    assert difficulty["crowd"]["frames_over_half_dynamic"] > 0.5
    walking = np.mean([fractions[n] for n in library.names("walking")])
    sitting = np.mean([fractions[n] for n in library.names("sitting")])
    assert walking > sitting
    assert difficulty["robot_aisle_patrol"]["camera_speed_mps_mean"] == pytest.approx(0.7, rel=0.05)


@pytest.mark.render
@pytest.mark.parametrize("distance", [1.0, 2.0, 3.0, 4.0])
def test_depth_noise_on_a_flat_wall_matches_kinect_sigma(tmp_path: Path, distance: float):
    from depotbench.sim.generate import generate

    wall_y = 5.5
    scenario = parse_scenario(
        {
            "name": "wall",
            "seed": 3,
            "frames": 2,
            "image": {"width": 160, "height": 120},
            "intrinsics": {"fx": 131.25},
            "layout": {"rack_rows": 0, "props": 0, "desk": False},
            "camera": {
                "motion": "static",
                "position_m": [0.0, wall_y - distance, 1.8],
                "target_m": [0.0, wall_y, 1.8],
            },
            "sensor": {"depth_noise": True},
        },
        "test",
    )
    seq = Sequence.open(generate(to_scenario(scenario), tmp_path / "wall", progress=False))
    for i in range(len(seq)):
        clean, noisy = seq.clean_depth_m(i), seq.depth_m(i)
        wall = np.abs(clean - distance) < 0.02 * distance
        assert wall.mean() > 0.5
        measured = float(np.std((noisy - clean)[wall]))
        assert measured == pytest.approx(float(kinect_sigma(np.float64(distance))), rel=0.10)


def test_sensor_models_change_only_what_they_should():
    from depotbench.sim.sensor import SensorModel
    from depotbench.sim.spec import SensorSpec

    rng = np.random.default_rng(0)
    depth = np.full((60, 80), 3.0, np.float32)
    depth[:, 40:] = 1.0  # a depth edge
    depth[0, 0] = 9.0  # beyond range
    rgb = np.full((60, 80, 3), 128, np.uint8)
    model = SensorModel(SensorSpec(depth_range_m=(0.4, 8.0), edge_dropout=1.0), rng)
    out = model.depth(depth)
    assert out[0, 0] == 0.0  # no reading beyond the range
    assert (out[:, 39:41] == 0).all() and (out[:, 10] == 3.0).all()  # edges dropped, flat kept
    quantiser = SensorModel(SensorSpec(disparity_quantisation=True), rng)
    quantised = quantiser.depth(np.full((4, 4), 3.7, np.float32))  # 4.0 m falls on a step exactly
    assert abs(quantised[0, 0] - 3.7) < 0.05 and quantised[0, 0] != np.float32(3.7)
    noisy = SensorModel(SensorSpec(rgb_noise_sigma=5.0), rng).rgb(rgb, None, 30.0)
    assert 4.0 < np.std(noisy.astype(float)) < 6.0
    # Motion blur spreads a bright column along its flow, conserving energy.
    bar = np.zeros((20, 40, 3), np.uint8)
    bar[:, 20] = 255
    flow = np.zeros((20, 40, 2), np.float32)
    flow[..., 0] = 6.0
    blurred = SensorModel(SensorSpec(motion_blur_exposure_s=1 / 30), rng).rgb(bar, flow, 30.0)
    assert (blurred[10, 17:24, 0] > 0).sum() >= 5 and blurred[10, 20, 0] < 255
    assert abs(int(blurred[10].astype(int).sum()) - 255 * 3) < 255 * 3 * 0.1


MALFORMED = {
    "wrong_type_fps.yaml": ("name: a\nfps: fast\n", "fps: Input should be a valid number"),
    "wrong_type_frames.yaml": (
        "name: a\nframes: [1, 2]\n",
        "frames: Input should be a valid integer",
    ),
    "unknown_top_key.yaml": ("name: a\ncolour: red\n", "colour: unknown field"),
    "unknown_nested_key.yaml": (
        "name: a\ncamera: {motion: xyz, zoom: 2}\n",
        "camera.zoom: unknown field",
    ),
    "unknown_actor_key.yaml": (
        "name: a\nactors: [{kind: person, hat: true}]\n",
        "actors.0.hat: unknown field",
    ),
    "negative_count.yaml": ("name: a\nactors: [{kind: dog, count: -2}]\n", "actors.0.count"),
    "negative_frames.yaml": (
        "name: a\nframes: -5\n",
        "frames: Input should be greater than or equal to 1",
    ),
    "unknown_kind.yaml": (
        "name: a\nactors: [{kind: unicorn}]\n",
        "actors.0.kind: Input should be 'person'",
    ),
    "unknown_motion.yaml": ("name: a\ncamera: {motion: drone}\n", "camera.motion"),
    "empty.yaml": ("", "the file is empty"),
    "comment_only.yaml": ("# nothing here\n", "the file is empty"),
    "not_yaml.yaml": ("name: a\nactors: [{kind: person\n", "not valid YAML"),
    "list_top.yaml": ("- name: a\n", "the top level must be a mapping"),
    "huge_frames.yaml": (
        "name: a\nframes: 100000000\n",
        "frames: Input should be less than or equal to 100000",
    ),
    "huge_image.yaml": ("name: a\nimage: {width: 100000}\n", "image.width"),
    "huge_speed.yaml": (
        "name: a\nactors: [{kind: person, speed_mps: 300}]\n",
        "actors.0.speed_mps",
    ),
    "too_many_actors.yaml": (
        "name: a\nactors: [{kind: person, count: 30}, {kind: dog, count: 30}]\n",
        "at most 40 actors",
    ),
    "python_tag.yaml": ("name: !!python/object/apply:os.system ['echo pwned']\n", "not valid YAML"),
    "bad_name.yaml": ("name: 'has spaces/and slashes'\n", "name: String should match pattern"),
    "missing_name.yaml": ("seed: 3\n", "name: Field required"),
    "bad_range.yaml": ("name: a\nsensor: {depth_range_m: [5, 1]}\n", "sensor"),
    "fy_anamorphic.yaml": ("name: a\nintrinsics: {fx: 500, fy: 1500}\n", "intrinsics.fy: fy / fx = 3"),
    "off_image.yaml": ("name: a\nintrinsics: {cx: 700}\n", "intrinsics.cx: 700 px lies off the image"),
    "frames_and_duration.yaml": (
        "name: a\nframes: 10\nduration_s: 2\n",
        "give frames or duration_s",
    ),
    "seated_walker.yaml": ("name: a\nactors: [{kind: person, path: seated}]\n", "path 'seated'"),
    "pusher_without_chair.yaml": (
        "name: a\nactors: [{kind: chair_pusher}]\n",
        "needs at least one chair",
    ),
    "binary.yaml": (b"\xff\xfe\x00name", "not a text file"),
}


@pytest.mark.parametrize("filename", sorted(MALFORMED))
def test_malformed_specs_are_refused_by_name(tmp_path: Path, capsys, filename: str):
    content, expected = MALFORMED[filename]
    path = tmp_path / filename
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert expected in err and str(path) in err
    assert "Traceback" not in err
    out = tmp_path / "out"
    assert main(["generate", str(path), "-o", str(out)]) == 2
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == [filename]


SUITE = """
suite: tiny
description: 24 tiny variations of the smoke scene
base: smoke
overrides: {frames: 2, image: {width: 64, height: 48}, intrinsics: {fx: 52.5}}
grid:
  actors.0.speed_mps: [0.6, 1.4]
  camera.motion: [xyz, static, rpy]
seeds: [0, 1, 2, 3]
"""


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_suite_expands_and_validates_each_variation(tmp_path: Path):
    path = tmp_path / "tiny.yaml"
    path.write_text(SUITE)
    jobs = variations(load_suite(path), path)
    assert len(jobs) == 24
    assert jobs[0][1] == {"actors.0.speed_mps": 0.6, "camera.motion": "xyz", "seed": 0}
    assert {sc.camera.motion for _, _, sc in jobs} == {"xyz", "static", "rpy"}
    bad = tmp_path / "bad.yaml"
    bad.write_text(SUITE.replace("[0.6, 1.4]", "[0.6, 9.0]"))
    with pytest.raises(Exception, match=r"variation tiny-0012.*actors.0.speed_mps"):
        variations(load_suite(bad), bad)
    random_suite = tmp_path / "random.yaml"
    random_suite.write_text(
        "suite: r\nbase: smoke\nrandom: {count: 5, seed: 3, knobs: "
        "{actors.0.count: {int: [1, 3]}, sensor: {choice: [perfect, kinect]}}}\n"
    )
    draws = variations(load_suite(random_suite), random_suite)
    assert len(draws) == 5 and draws == variations(load_suite(random_suite), random_suite)


@pytest.mark.parametrize(
    ("base", "override", "frames"),
    [
        ("sitting_static", "frames: 7", 7),  # the base's duration_s: 10 gives way to frames
        ("smoke", "duration_s: 0.2", 6),  # the base's frames: 10 gives way to 0.2 s x 30 fps
    ],
)
def test_a_suite_that_sets_the_length_one_way_replaces_the_bases_other_way(
    tmp_path: Path, base: str, override: str, frames: int
):
    """A suite overriding frames on a base that sets duration_s was refused with "give frames or
    duration_s, not both"; the override is the length the user wants. Frame counts checked
    against fps x duration_s worked by hand (30 fps in both library scenes)."""
    path = tmp_path / "length.yaml"
    path.write_text(f"suite: length\nbase: {base}\noverrides: {{{override}}}\n")
    ((_, _, scenario),) = variations(load_suite(path), path)
    assert scenario.fps == 30.0 and scenario.n_frames == frames
    knob = tmp_path / "knob.yaml"  # a grid knob over the length does the same, per variation
    knob.write_text(f"suite: knob\nbase: {base}\ngrid: {{{override.split(':')[0]}: [1, 2]}}\n")
    lengths = [sc.n_frames for _, _, sc in variations(load_suite(knob), knob)]
    assert lengths == ([1, 2] if override.startswith("frames") else [30, 60])
    other = "duration_s" if override.startswith("frames") else "frames"
    for order in (f"{override}, {other}: null", f"{other}: null, {override}"):  # the old way round
        path.write_text(f"suite: length\nbase: {base}\noverrides: {{{order}}}\n")
        ((_, _, scenario),) = variations(load_suite(path), path)
        assert scenario.n_frames == frames


@pytest.mark.parametrize(
    ("body", "where"),
    [
        ("overrides: {frames: 7, duration_s: 2}", "overrides"),
        ("grid: {frames: [5], duration_s: [1]}", "knobs"),
    ],
)
def test_a_suite_that_sets_the_length_both_ways_at_once_is_one_line_saying_how(
    tmp_path: Path, capsys, body: str, where: str
):
    path = tmp_path / "both.yaml"
    path.write_text(f"suite: both\nbase: smoke\n{body}\n")
    out = tmp_path / "out"
    assert main(["generate", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert str(path) in lines[0] and f"{where}: give frames or duration_s, not both" in lines[0]
    assert "replaces the base's length" in lines[0]
    assert not out.exists()


@pytest.mark.render
@pytest.mark.slow  # 45 s; suites are also byte-compared across backends (test_sweep) in the default run
def test_suite_twice_gives_identical_files_and_resumes_after_a_kill(tmp_path: Path):
    path = tmp_path / "tiny.yaml"
    path.write_text(SUITE)
    suite = load_suite(path)
    first = run_suite(suite, path, tmp_path / "a", workers=2, progress=False)
    run_suite(suite, path, tmp_path / "b", workers=2, progress=False)
    assert len(first["sequences"]) == 24
    files_a, files_b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert files_a.keys() == files_b.keys()
    differing = [k for k in files_a if files_a[k] != files_b[k]]
    assert differing == []
    # Kill a run midway, then rerun: only the missing sequences are generated.
    out = tmp_path / "c"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "depotbench.eval.cli.main",
            "generate",
            str(path),
            "-o",
            str(out),
            "--workers",
            "2",
        ],
        cwd=REPO,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    while time.time() < deadline and len([p for p in out.glob("tiny-*") if p.is_dir()]) < 4:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = {p.name: p.stat().st_mtime_ns for p in out.glob("tiny-*") if p.is_dir()}
    assert 4 <= len(done_before) < 24
    index = run_suite(suite, path, out, workers=2, progress=False)
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("tiny-*") if p.name in done_before} == done_before
    assert len(index["sequences"]) == 24 and not list(out.glob(".*partial*"))
    files_c = _files(out)
    assert {k: v for k, v in files_c.items() if k != "index.json"} == {
        k: v for k, v in files_a.items() if k != "index.json"
    }
    assert json.loads(files_c["index.json"]) == json.loads(files_a["index.json"])


@pytest.mark.slow  # 27 s
def test_difficultys_mean_flow_on_a_grid_is_within_half_a_percent_of_every_pixels(
    tmp_path: Path, monkeypatch
):
    """Generation takes the moving pixels' mean flow on every 4th row and column (a
    sixteenth of the work); against every moving pixel it stays within 0.5%."""
    import depotbench.sim.generate as generate_module
    from depotbench.scenes.generation import read_difficulty

    spec = to_scenario(
        library.get("walking_halfsphere").model_copy(update={"frames": 20, "duration_s": None})
    )
    means = {}
    for grid in (1, generate_module.FLOW_GRID):
        monkeypatch.setattr(generate_module, "FLOW_GRID", grid)
        out = generate_module.generate(spec, tmp_path / f"grid{grid}", progress=False)
        means[grid] = read_difficulty(out)["dynamic_flow_px_mean"]
    assert means[1] > 1.0
    assert means[generate_module.FLOW_GRID] == pytest.approx(means[1], rel=0.005)


def test_a_seed_given_to_one_scenario_draws_its_ranges_as_a_suites_seed_does(tmp_path: Path):
    """``depotbench generate walking_halfsphere --seed 301`` drew its walkers' speeds (ranges
    in the file) from the file's own seed 14 and then set the seed: 0.64 and 0.85 m/s under
    every --seed, where tum-dyn-1's seed 301 has 0.93 and 0.99, so the one-scenario path made
    other sequences than a suite of the same seed. The reference is the frozen lock's spec key,
    written by the suite path, and the suite path itself for other seeds and a cut length."""
    import dataclasses

    from depotbench.scenes.resolve import resolve
    from depotbench.sim.spec import content_key

    import depotbench

    lock = json.loads((REPO / "assets/benchmarks/tum-dyn-1.lock.json").read_text())
    frozen = {s["name"]: s["spec_key"] for s in lock["sequences"]}
    for name, seed in (("walking_halfsphere-0000", 301), ("walking_xyz-0004", 305)):
        spec = resolve(name.split("-")[0], {"seed": seed})
        assert content_key(dataclasses.replace(spec, name=name)) == frozen[name]
    suite = tmp_path / "suite.yaml"
    suite.write_text("suite: walking_static\nbase: walking_static\nseeds: [7, 8]\noverrides: {frames: 12}\n")
    for name, knobs, scenario in variations(load_suite(suite), suite):
        ours = depotbench.scenario("walking_static", seed=knobs["seed"], frames=12)
        assert dataclasses.replace(ours, name=name) == to_scenario(scenario)
    speeds = {resolve("walking_halfsphere", {"seed": s}).actors[0].speed_mps for s in (1, 2, 3)}
    assert len(speeds) == 3
    command = ["-q", "generate", "walking_xyz", "--seed", "305", "--frames", "2", "-o", str(tmp_path / "s")]
    assert main(command) == 0
    written = json.loads((tmp_path / "s" / "meta.json").read_text())["scenario"]["actors"]
    wanted = resolve("walking_xyz", {"seed": 305}).actors
    assert [a["speed_mps"] for a in written] == [a.speed_mps for a in wanted]
