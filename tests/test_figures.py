"""People and animals as continuous bodies cut into rigid parts (sim/figures.py)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from depotbench.sim.figures import AnimalLook, Look, person_bind, person_surfaces
from depotbench.sim.ground_truth import boxes_and_counts
from depotbench.sim.memo import MEMOS
from depotbench.sim.mujoco_env import mujoco
from depotbench.sim.render import HIDDEN_GROUP, FrameRenderer
from depotbench.sim.simulation import Simulation
from depotbench.sim.spec import ActorSpec, CameraSpec, ChairSpec, LayoutSpec, ScenarioSpec
from depotbench.sim.world import build_world
from scipy.spatial.transform import Rotation


@pytest.fixture
def carved_here():
    """The bodies carved in this test, not taken from an earlier one's (sim/memo.py), for a
    test that watches or changes the carving; and nothing it carved is kept for later tests,
    which would otherwise be handed its patched pieces under the same key."""
    for memo in MEMOS.values():
        memo.clear()
    yield
    for memo in MEMOS.values():
        memo.clear()


def _edges_shared_twice(faces: np.ndarray) -> bool:
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool((counts == 2).all())


def _volume(mesh) -> float:
    a, b, c = (mesh.vertices[mesh.faces[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def _assert_closed_and_outward(named_meshes, reach: float | None = None) -> None:
    """Every mesh watertight (each edge shared by two faces) with positive volume, and
    within ``reach`` of its part's frame origin (a wrong frame would fling it away)."""
    for name, meshes in named_meshes:
        assert meshes, name
        for mesh in meshes:
            assert _edges_shared_twice(mesh.faces), name
            assert _volume(mesh) > 0, name
            if reach is not None:
                assert np.linalg.norm(mesh.vertices, axis=1).max() < reach, name


def _meshes(surfaces) -> list:
    """The meshes of ``surfaces`` and of their far versions."""
    return [m for s in surfaces for m in (s.mesh, s.far and s.far.mesh) if m is not None]


def _part_meshes(parts) -> list:
    return [(part.name, _meshes(part.surfaces)) for part in parts]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_piece_is_a_closed_outward_mesh_near_its_part(seed):
    """Each drawn piece (and its far version) is watertight (every edge shared by two faces)
    with positive volume, and lies near its own part's frame origin (a wrong frame would
    fling it away)."""
    look = Look.draw(np.random.default_rng(seed))
    drawn = person_surfaces(1.0, look)
    frames, _ = person_bind(1.0)
    assert set(drawn) == set(frames)
    _assert_closed_and_outward([(part, _meshes(surfaces)) for part, surfaces in drawn.items()], 0.45)


def test_looks_vary_with_the_seed_and_repeat_with_it():
    looks = [Look.draw(np.random.default_rng(s)) for s in range(20)]
    assert len({(lk.top, lk.hair, lk.boots) for lk in looks}) > 8
    assert Look.draw(np.random.default_rng(3)) == looks[3]
    assert AnimalLook.draw(np.random.default_rng(0), "cat").ears == "erect"


def _quadruped(kind: str, seed: int):
    from depotbench.sim import actor_registry
    from depotbench.sim.actors import Quadruped
    from depotbench.sim.paths import Path

    look = AnimalLook.draw(np.random.default_rng(seed), kind)
    path = Path(np.array([[-2.0, 0.0], [2.0, 0.0]]))
    return Quadruped(actor_registry.get(kind).body, path, 0.8, 0.0, look, {"coat": "coat0"})


@pytest.mark.parametrize("kind", ["dog", "cat", "pig"])
def test_every_animal_piece_is_a_closed_outward_mesh(kind):
    """As for people: every drawn piece of a dog, cat or pig is watertight with positive
    volume and lies near its own part's frame."""
    _assert_closed_and_outward(_part_meshes(_quadruped(kind, 1).parts), 0.7)


@pytest.mark.parametrize("kind, seed", [("person", 0), ("person", 4), ("dog", 3), ("pig", 2)])
def test_every_piece_keeps_a_fifth_of_its_marching_cubes_triangles(carved_here, monkeypatch, kind, seed):
    """Decimation reaches its share on every piece, closed (twice it where a handle
    closes up below that). fast-simplification's default aggressiveness opened a piece of
    each of these figures, which was then drawn whole: five times the triangles, in every
    render pass."""
    import depotbench.sim.shapes as shapes

    kept: list[tuple[int, object]] = []
    decimate = shapes.decimate

    def recording(mesh, keep=None):
        out = decimate(mesh, keep)
        if keep is None:  # not a far version's
            kept.append((len(mesh.faces), out))
        return out

    monkeypatch.setattr(shapes, "decimate", recording)
    if kind == "person":
        person_surfaces(1.0, Look.draw(np.random.default_rng(seed)))
    else:
        _quadruped(kind, seed)
    decimated = [(n, out) for n, out in kept if int(n * shapes.KEEP_FACES) >= shapes.MIN_FACES]
    assert len(decimated) > 10
    for n, out in decimated:
        assert len(out.faces) <= 2 * int(n * shapes.KEEP_FACES), (n, len(out.faces))
        assert _edges_shared_twice(out.faces) and _volume(out) > 0


@pytest.mark.parametrize(
    ("kind", "seed", "step"),
    [  # 3 s each: one cat and one dog by default
        ("cat", 1, 0.004),
        pytest.param("cat", 2, 0.004, marks=pytest.mark.slow),
        pytest.param("cat", 3, 0.004, marks=pytest.mark.slow),
        ("dog", 1, 0.013),
        pytest.param("dog", 4, 0.013, marks=pytest.mark.slow),
    ],
)
def test_a_curved_tail_meshed_in_its_own_box_is_the_tail_of_the_bones_whole_box(
    carved_here, monkeypatch, kind, seed, step
):
    """A cat's or dog's tail is meshed in a box around its curve, not in the cube its
    bone's reach would give (a fifth of the build time): the same tail, to the grid's
    alignment (``step``: about one step of the tail's grid, 0.3 of its root radius)."""
    import depotbench.sim.figures as figures

    boxed = [s.mesh for p in _quadruped(kind, seed).parts if p.name == "tail" for s in p.surfaces]
    carve = figures.carve
    monkeypatch.setattr(
        figures,
        "carve",
        lambda body, bones, *rest, **kw: carve(
            body, [dataclasses.replace(b, box=None) for b in bones], *rest, **kw
        ),
    )
    whole = [s.mesh for p in _quadruped(kind, seed).parts if p.name == "tail" for s in p.surfaces]
    assert len(boxed) == len(whole) == 1
    assert _volume(boxed[0]) == pytest.approx(_volume(whole[0]), rel=0.005)  # not cut by the box
    assert np.ptp(boxed[0].vertices, axis=0) == pytest.approx(np.ptp(whole[0].vertices, axis=0), abs=step)


def test_a_union_remembers_the_box_only_of_points_that_cannot_change():
    """``smooth_union`` skips members far from the points asked, by the points' box; the
    box is remembered for the grid's read-only points. Points changed in place between
    two calls get a fresh box (a stale one would skip the member they now lie on)."""
    from depotbench.sim.shapes import Grid, ellipsoid, smooth_union

    body = smooth_union(
        [ellipsoid((0.0, 0.0, 0.0), (0.1, 0.1, 0.1)), ellipsoid((1.0, 0.0, 0.0), (0.1, 0.1, 0.1))], 0.05
    )
    near_first = np.array([[0.02, 0.0, 0.0], [0.05, 0.0, 0.0]])
    assert (body(near_first) < 0).all()
    moved = near_first.copy()
    assert (body(moved) < 0).all()
    moved += [1.0, 0.0, 0.0]  # now on the second member, far from the first
    assert body(moved) == pytest.approx(body(near_first + [1.0, 0.0, 0.0]))
    assert (body(moved) < 0).all()

    grid = Grid.around(np.array([-0.2, -0.2, -0.2]), np.array([1.2, 0.2, 0.2]), 0.02)
    assert not grid.points.flags.writeable
    once, again = body(grid.points), body(grid.points)
    fresh = body(grid.points.copy())  # writeable: its box is computed anew
    assert np.array_equal(once, again) and np.array_equal(once, fresh)


def test_a_dogs_tail_leaves_the_rump_level_and_sweeps_up():
    """The dog's tail (its ``tail_bends``) starts out nearly level behind the rump and ends
    steeply up, thick at the root: a straight stick at the tail's rise was called cow
    or person (docs/recognition.md); the curve's shape, not the bone's rise, carries that."""
    from depotbench.sim import actor_registry
    from depotbench.sim.figures import _tail_curve

    bends = actor_registry.get("dog").body.tail_bends
    curve = _tail_curve(np.zeros(3), np.array([-0.3, 0.0, 0.0]), bends)
    steps = np.diff(curve, axis=0)
    rise = np.degrees(np.arctan2(steps[:, 2], -steps[:, 0]))
    assert rise[0] < 15 and rise[-1] > 60 and (np.diff(rise) > 0).all()
    assert curve[-1, 2] > 0.6 * 0.3  # the tip well above the root
    tail = [s.mesh for p in _quadruped("dog", 1).parts if p.name == "tail" for s in p.surfaces][0]
    assert np.ptp(tail.vertices, axis=0).min() > 0.06  # over 6 cm across at its widest


@pytest.mark.parametrize(("kind", "raised"), [("dog", True), ("cat", True), ("pig", False)])
def test_dogs_and_cats_carry_their_heads_above_the_back(kind, raised):
    """A dog's or cat's neck carries the head's top well above the withers (head at the
    back's height read as a table or a horse to a detector); a pig's head stays low."""
    animal = _quadruped(kind, 2)
    positions, rotations = animal.bind()
    top = {}
    for j, part in enumerate(animal.parts[:2]):
        vertices = np.concatenate([s.mesh.vertices for s in part.surfaces if s.mesh is not None])
        top[part.name] = float((vertices @ rotations[j].T + positions[j])[:, 2].max())
    margin = top["head"] - top["body"]
    hy = animal.animal.half_m[1]
    assert margin > 1.2 * hy if raised else margin < 0.9 * hy, margin


def _scene(kind: str, speed: float) -> ScenarioSpec:
    return ScenarioSpec(
        frames=1,
        width=320,
        height=240,
        focal_px=262.5,
        layout=LayoutSpec(rack_rows=0, floor_props=0, desk=False),
        actors=(ActorSpec(kind, speed_mps=speed, waypoints=((-2.5, 0.0), (2.5, 0.0))),),
        chairs=(ChairSpec((0.0, 0.5)),) if kind == "chair_pusher" else (),
        camera=CameraSpec(position_m=(0.0, -3.0, 1.0), target_m=(0.0, 0.0, 0.7)),
    )


@pytest.mark.render
@pytest.mark.parametrize(
    ("kind", "speed"), [("person", 1.4), ("chair_pusher", 0.9), ("dog", 1.6), ("cat", 0.6), ("pig", 0.6)]
)
def test_moving_bodies_stay_in_one_piece(kind, speed):
    """A physical check of the cut: while legs swing and knees bend, the parts of a body
    seen alone render as one connected region (a joint opening would split the mask),
    and the part meshes cover the body's collision stand-ins' extent."""
    world = build_world(_scene(kind, speed))
    sim = Simulation(world)
    geom_instance = world.body_instance[world.model.geom_bodyid]
    world.model.geom_group[np.isin(world.model.geom_bodyid, world.chair_bodies)] = HIDDEN_GROUP  # alone
    renderer = FrameRenderer(world.model, world.spec.width, world.spec.height, geom_instance)
    seen = 0
    try:
        for k in range(12):
            sim.advance_to(0.25 + k / 6.0)
            geom_ids = renderer.render(sim.data, world.camera_id).geom_ids
            mask = np.where(geom_ids >= 0, geom_instance[np.maximum(geom_ids, 0)], 0) == 1
            if mask.sum() < 300:
                continue
            seen += 1
            count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
            assert (stats[1:, cv2.CC_STAT_AREA] >= 3).sum() == 1, (kind, k)
    finally:
        renderer.close()
    assert seen >= 6


@pytest.mark.render
def test_far_versions_stand_in_beyond_far_m_and_keep_the_silhouette(monkeypatch):
    """A person 5 m away is drawn by its pieces' far versions (two fifths of the triangles),
    one 2 m away by the full pieces, never both; and at 5 m the far silhouette is the full
    one's to within a few pixels in a hundred."""
    import depotbench.sim.render as render
    from depotbench.sim.render import FAR_M, FAR_SUFFIX

    checked = []
    for distance in (2.0, 5.0):
        camera = CameraSpec(position_m=(0.0, -distance, 1.0), target_m=(0.0, 0.0, 0.9))
        spec = dataclasses.replace(_scene("person", 1.4), camera=camera)
        world = build_world(spec)
        model = world.model
        names = [model.geom(g).name for g in range(model.ngeom)]
        far = {g for g, name in enumerate(names) if name.endswith(FAR_SUFFIX)}
        with_far = {names.index(names[g].removesuffix(FAR_SUFFIX)) for g in far}
        assert len(far) > 10
        assert sum(model.mesh_facenum[model.geom_dataid[g]] for g in far) < 0.5 * sum(
            model.mesh_facenum[model.geom_dataid[g]] for g in with_far
        )
        geom_instance = world.body_instance[model.geom_bodyid]
        renderer = FrameRenderer(model, spec.width, spec.height, geom_instance)
        sim = Simulation(world)
        try:
            for k in range(8):
                sim.advance_to(k / 2)
                frame = renderer.render(sim.data, world.camera_id)
                shown = set(np.unique(frame.geom_ids[frame.geom_ids >= 0]).tolist())
                if len(shown) < 10:
                    continue  # out of view
                if distance > FAR_M:
                    assert shown & far and not shown & with_far, k
                    monkeypatch.setattr(render, "FAR_M", np.inf)
                    full = renderer.render(sim.data, world.camera_id).instances == 1
                    monkeypatch.undo()
                    mask = frame.instances == 1
                    assert (mask ^ full).sum() < 0.05 * full.sum(), k
                else:
                    assert shown & with_far and not shown & far, k
                checked.append(distance)
        finally:
            renderer.close()
    assert checked.count(2.0) >= 2 and checked.count(5.0) >= 4, checked


@pytest.mark.render
def test_people_are_drawn_by_their_meshes_not_their_stand_ins():
    """The collision primitives are never drawn: every actor pixel belongs to a mesh
    geom or a face primitive (eyes, brows, mouth) of a drawn part."""
    world = build_world(_scene("person", 1.2))
    sim = Simulation(world)
    sim.advance_to(1.0)
    geom_instance = world.body_instance[world.model.geom_bodyid]
    renderer = FrameRenderer(world.model, 320, 240, geom_instance)
    try:
        geom_ids = renderer.render(sim.data, world.camera_id).geom_ids
    finally:
        renderer.close()
    actor = geom_ids[(geom_ids >= 0) & (geom_instance[np.maximum(geom_ids, 0)] == 1)]
    assert actor.size > 500
    assert (world.model.geom_contype[actor] == 0).all()
    boxes, counts = boxes_and_counts(np.where(geom_ids >= 0, geom_instance[np.maximum(geom_ids, 0)], 0), 1)
    assert counts[1] == actor.size


def test_seated_people_keep_their_knees_under_the_desk_between_its_legs():
    """Seats turn their people towards each other (a 3/4 view, as two people talking sit):
    the shins must still hang under the desk top, inside its footprint and clear of its
    legs, at every moment of the sway."""
    from depotbench.sim.actors import SittingPerson
    from depotbench.sim.layout import DESK_CENTRE, DESK_HALF, plan_layout
    from depotbench.sim.world import PERSON_ROLES

    layout = plan_layout(LayoutSpec(), np.random.default_rng(0))
    (cx, cy), (hx, hy) = DESK_CENTRE, DESK_HALF
    legs = np.array([(cx + sx * (hx - 0.05), cy + sy * (hy - 0.05)) for sx in (-1, 1) for sy in (-1, 1)])
    assert len(layout.seats) == 2
    for seat in layout.seats:
        for scale in (0.9, 1.08):
            person = SittingPerson(seat, scale, {m: m for m in PERSON_ROLES}, np.random.default_rng(1))
            for t in np.linspace(0.0, 10.0, 21):
                positions, _ = person.pose(float(t))
                for shin in positions[9:11]:
                    assert abs(shin[0] - cx) < hx - 0.1 and abs(shin[1] - cy) < hy, (seat, t)
                    assert np.linalg.norm(legs - shin[:2], axis=1).min() > 0.2, (seat, t)
                    assert shin[2] < 0.6, (seat, t)


def _bird():
    from depotbench.sim.actors import Bird
    from depotbench.sim.paths import Path

    return Bird(Path(np.array([[-1.0, 0.0], [1.0, 0.0]])), 0.0, 10.0, np.random.default_rng(3))


def _bird_vertices(bird, spread: float, flap: float) -> np.ndarray:
    positions, rotations = bird.place(np.zeros(3), np.eye(3), spread, flap)
    return np.concatenate(
        [
            s.mesh.vertices @ rotations[j].T + positions[j]
            for j, part in enumerate(bird.parts)
            for s in part.surfaces
            if s.mesh is not None
        ]
    )


def test_every_bird_piece_is_a_closed_outward_mesh_and_the_wings_fold():
    """The pigeon's pieces are watertight with positive volume; folded, its wings lie
    along the body (it is no wider than a pigeon's body, 12-15 cm), open they span
    about 40 cm, and a flap raises the tips above the back."""
    bird = _bird()
    _assert_closed_and_outward(_part_meshes(bird.parts))
    folded, spread = _bird_vertices(bird, 0.0, 0.0), _bird_vertices(bird, 1.0, 0.0)
    assert np.ptp(folded[:, 1]) < 0.16
    assert 0.35 < np.ptp(spread[:, 1]) < 0.5
    raised = _bird_vertices(bird, 1.0, np.radians(40.0))
    assert raised[:, 2].max() > 0.13  # the tips above the head's top (9 cm)


@pytest.mark.render
@pytest.mark.parametrize("yaw_deg", [0.0, 60.0, 150.0])
def test_a_bird_stays_in_one_piece_as_its_wings_open_and_flap(yaw_deg):
    """Seen alone from close by, the pigeon renders as one connected region with its
    wings folded, half open, open, and flapping up and down (a joint that opened would
    split the mask)."""
    import mujoco
    from depotbench.sim.actors import yaw_matrix
    from depotbench.sim.conventions import quat_wxyz

    spec = ScenarioSpec(
        frames=1,
        width=320,
        height=240,
        focal_px=262.5,
        layout=LayoutSpec(rack_rows=0, floor_props=0, desk=False),
        actors=(ActorSpec("bird", waypoints=((-0.3, 0.0), (0.3, 0.0))),),
        camera=CameraSpec(position_m=(0.0, -1.0, 0.6), target_m=(0.0, 0.0, 0.15)),
    )
    world = build_world(spec)
    sim = Simulation(world)
    bird, ids = world.actors[0], world.actor_mocap[0]
    geom_instance = world.body_instance[world.model.geom_bodyid]
    renderer = FrameRenderer(world.model, world.spec.width, world.spec.height, geom_instance)
    try:
        for spread, flap_deg in [(0.0, 0.0), (0.5, 0.0), (1.0, 0.0), (1.0, 50.0), (1.0, -50.0)]:
            positions, rotations = bird.place(
                np.array([0.0, 0.0, 0.15]), yaw_matrix(np.radians(yaw_deg)), spread, np.radians(flap_deg)
            )
            sim.data.mocap_pos[ids] = positions
            sim.data.mocap_quat[ids] = quat_wxyz(rotations)
            mujoco.mj_forward(world.model, sim.data)
            geom_ids = renderer.render(sim.data, world.camera_id).geom_ids
            mask = np.where(geom_ids >= 0, geom_instance[np.maximum(geom_ids, 0)], 0) == 1
            assert mask.sum() > 800, (spread, flap_deg)
            count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
            assert (stats[1:, cv2.CC_STAT_AREA] >= 3).sum() == 1, (spread, flap_deg)
    finally:
        renderer.close()


@pytest.mark.render
def test_a_cat_seen_from_the_side_shows_an_eye():
    """A detector knows a cat by its face: walking past the camera side-on, the cat's
    eye (iris and pupil) shows in every frame, not buried under the coat."""
    spec = dataclasses.replace(
        _scene("cat", 0.6),
        width=640,
        height=480,
        focal_px=525.0,
        camera=CameraSpec(position_m=(0.0, -1.5, 0.45), target_m=(0.0, 0.0, 0.2)),
    )
    world = build_world(spec)
    sim = Simulation(world)
    model = world.model
    eye_materials = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MATERIAL, name) for name in ("iris", "eye")]
    eye_geoms = np.flatnonzero(np.isin(model.geom_matid, eye_materials))
    geom_instance = world.body_instance[model.geom_bodyid]
    renderer = FrameRenderer(model, spec.width, spec.height, geom_instance)
    try:
        for k in range(6):
            sim.advance_to(1.5 + k / 10.0)  # crossing the view, head to one side
            geom_ids = renderer.render(sim.data, world.camera_id).geom_ids
            assert np.isin(geom_ids, eye_geoms).sum() >= 15, k  # 28-35 px; buried: 0-1
    finally:
        renderer.close()


def test_cats_wear_the_photographed_fur_in_their_coat_colour():
    """Every cat's coat is the shipped fur photograph (its strands and stripes kept: the
    flanks' luminance correlates with the mirrored photograph's at >= 0.95) in one of the
    cats' coat colours, laid out round the body: it repeats without a seam along and
    round a part, is darker along the back (middle rows) and pales to cream underneath
    (first and last rows); a dog's coat stays drawn."""
    from depotbench.sim import textures

    photo = cv2.imread(str(textures.FUR_PHOTO), cv2.IMREAD_COLOR)[:, :, ::-1].astype(np.float32)
    tile = np.concatenate([photo, photo[:, ::-1]], axis=1)
    tile = np.concatenate([tile, tile[::-1]], axis=0)
    reference_rgb = np.tile(cv2.resize(tile, (128, 128), interpolation=cv2.INTER_AREA), (2, 2, 1))
    reference = reference_rgb.mean(axis=2)
    from depotbench.sim import actor_registry

    coats = actor_registry.get("cat").body.coat.colours
    colours = [np.array(c, float) for c, pattern in coats if pattern == "photo"]
    assert len(colours) == len(coats)
    flank = slice(256 // 4 - 8, 256 // 4 + 8)  # where neither shade nor cream reaches
    # each channel scaled so that the photograph's mean is the coat colour (clipped at
    # 255: the ginger's brightest strands); on the flank, within 5 levels of that (the
    # shading begins at the band's edges)
    scale = reference_rgb.reshape(-1, 3).mean(axis=0)
    tinted = [reference_rgb * (c / scale) for c in colours]
    expected = [np.clip(t[flank], 0, 255).reshape(-1, 3).mean(axis=0) for t in tinted]
    seen = set()
    for seed in range(12):
        image = textures.coat(np.random.default_rng(seed), "cat")
        assert image.shape == (256, 256, 3) and image.dtype == np.uint8
        means = image[flank].reshape(-1, 3).mean(axis=0)
        k = int(np.argmin([np.abs(means - e).max() for e in expected]))
        assert np.abs(means - expected[k]).max() < 5.0, (seed, means, expected[k])
        seen.add(k)
        grey = image.astype(float).mean(axis=2)
        assert np.corrcoef(grey[flank].ravel(), reference[flank].ravel())[0, 1] >= 0.95, seed
        # the back (middle rows) at 0.7 of the flank, against the photograph's own rows;
        # the belly (first and last rows) half way from the tinted photograph to cream
        shade = grey.mean(axis=1) / reference.mean(axis=1)
        assert 0.65 < shade[124:132].mean() / shade[flank].mean() < 0.75, seed
        rows = np.r_[0:4, 252:256]
        fur = tinted[k][rows].reshape(-1, 3).mean(axis=0)
        towards = np.array([235.0, 222.0, 200.0]) - fur
        belly = image[rows].reshape(-1, 3).mean(axis=0)
        assert 0.45 < (belly - fur) @ towards / (towards @ towards) < 0.6, seed
        assert np.abs(grey[:, 0] - grey[:, -1]).mean() < 12 and np.abs(grey[0] - grey[-1]).mean() < 12
    assert len(seen) >= 3  # the seed picks the colour
    dog = textures.coat(np.random.default_rng(0), "dog").mean(axis=2).ravel()
    assert abs(np.corrcoef(dog, reference[::2, ::2].ravel())[0, 1]) < 0.3


def test_a_coat_laid_on_round_a_part_follows_its_axis_and_unwraps_its_seam():
    """``wrapped``'s coordinates against their definition on a closed mesh of a
    capsule along a tilted axis, in a part frame turned and moved off the bind pose:
    u is the distance along the axis in texture widths, v the angle round it from
    ``down``; no face spans more than a few cells of the texture (the seam under the
    body is unwrapped, not squeezed across it)."""
    from depotbench.sim.figures import Surface, wrapped
    from depotbench.sim.shapes import mesh_field, round_cone

    a, b = np.array([0.1, 0.2, 0.3]), np.array([0.5, 0.25, 0.4])
    mesh = mesh_field(round_cone(a, b, 0.06, 0.05), np.minimum(a, b) - 0.07, np.maximum(a, b) + 0.07, 0.006)
    assert mesh is not None
    rotation = Rotation.from_rotvec([0.3, -0.2, 1.1]).as_matrix()
    origin = np.array([0.2, -0.1, 0.05])
    part = Surface("coat", dataclasses.replace(mesh, vertices=(mesh.vertices - origin) @ rotation))
    down = np.array([0.0, 0.0, -1.0])
    texcoord = wrapped(part, a, b, down, (origin, rotation), 0.25).texcoord
    assert texcoord is not None and texcoord.shape == (3 * len(mesh.faces), 2)
    corners = mesh.vertices[mesh.faces].reshape(-1, 3)
    axis = (b - a) / np.linalg.norm(b - a)
    np.testing.assert_allclose(texcoord[:, 0] * 0.25, (corners - a) @ axis, atol=1e-9)
    radial = (corners - a) - np.outer((corners - a) @ axis, axis)
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    below = down - (down @ axis) * axis
    below /= np.linalg.norm(below)
    turned = 2 * np.pi * texcoord[:, 1]
    np.testing.assert_allclose(np.cos(turned), radial @ below, atol=1e-9)
    np.testing.assert_allclose(np.sin(turned), radial @ np.cross(axis, below), atol=1e-9)
    # On the side (not the rounded ends, where every angle meets at the pole), a face
    # covers a few hundredths of the way round
    along = ((corners - a) @ axis).reshape(-1, 3)
    side = (along > 0.0).all(axis=1) & (along < np.linalg.norm(b - a)).all(axis=1)
    spans = np.ptp(texcoord[:, 1].reshape(-1, 3), axis=1)
    assert side.sum() > len(side) / 3 and spans[side].max() < 0.1
    assert texcoord[:, 1].min() >= 0.0 and texcoord[:, 1].max() < 1.5
    assert (texcoord[:, 1] > 1.0).any()  # the seam was crossed and unwrapped


def test_a_missing_fur_photograph_is_named(monkeypatch, tmp_path):
    from depotbench.sim import textures

    monkeypatch.setattr(textures, "FUR_PHOTO", tmp_path / "cat_fur.png")
    textures._fur_photo.cache_clear()
    try:
        with pytest.raises(FileNotFoundError, match="cat_fur.png"):
            textures.coat(np.random.default_rng(0), "cat")
    finally:
        textures._fur_photo.cache_clear()
