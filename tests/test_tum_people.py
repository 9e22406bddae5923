"""People as in TUM fr3's dynamic sequences: walkers who walk about the desk and sit at it
(``path: tum_walk``), and seated people who keep talking and gesturing. Poses are driven
directly, without rendering."""

from __future__ import annotations

import math

import numpy as np
import pytest
from depotbench.scenes.schema import SpecError, parse_scenario
from depotbench.sim.actors import SIT_TRANSITION_S, SittingPerson, TumWalker
from depotbench.sim.layout import DESK_CENTRE, DESK_HALF, plan_layout
from depotbench.sim.spec import ActorSpec, LayoutSpec
from depotbench.sim.world import _make_actor
from scipy.spatial.transform import Rotation

DURATION_S = 40.0
FPS = 30.0
SPEED = 0.8
MATERIALS = {m: f"{m}0" for m in ("top", "legs", "skin", "feet", "hair")}


def tum_walker(seed: int, seat_index: int = 0) -> TumWalker:
    """A walker built as the world builder builds one, in the default hall with its desk."""
    layout = plan_layout(LayoutSpec(), np.random.default_rng(seed))
    spec = ActorSpec(kind="person", speed_mps=SPEED, path="tum_walk")
    rng = np.random.default_rng(seed)
    actor = _make_actor(spec, 0, layout, (), rng, DURATION_S, seat_index, None)
    assert isinstance(actor, TumWalker)
    return actor


TIMES = np.arange(0.0, DURATION_S, 1.0 / FPS)


@pytest.fixture(scope="module", params=[(1, 0), (2, 1)], ids=["seed1-seat0", "seed2-seat1"])
def walker(request) -> TumWalker:
    walker = tum_walker(*request.param)
    walker.seat_index = request.param[1]  # type: ignore[attr-defined]
    return walker


STEP_S = 1.0 / 60.0


@pytest.fixture(scope="module")
def poses(walker: TumWalker) -> np.ndarray:
    """Every part's position at 60 Hz over 40 s, and whether the person is seated."""
    times = np.arange(0.0, DURATION_S, STEP_S)
    return np.array([walker.pose(t)[0] for t in times]), np.array([walker.sitting(t) for t in times])


def test_a_tum_walker_walks_and_sits_down_and_stands_up_again_within_40_s(walker: TumWalker):
    sitting = np.array([walker.sitting(t) for t in TIMES])
    assert 0.05 < sitting.mean() < 0.6, sitting.mean()
    # it sits down and gets up again (a stretch of walking after a sitting one) in 40 s
    whats = [s.what for s in walker.stretches if s.t0 < DURATION_S]
    assert "sit" in whats and whats.index("stand up") < len(whats) - 1
    seated_z = walker.root(next(s.t0 for s in walker.stretches if s.what == "sit") + 0.5)[0][2]
    standing_z = walker.root(0.0)[0][2]
    assert seated_z < standing_z - 0.25  # a seated pelvis is on the seat, not at hip height


def test_a_tum_walker_never_moves_faster_than_its_pace(walker: TumWalker):
    roots = np.array([walker.root(t)[0] for t in TIMES])
    speed = np.linalg.norm(np.diff(roots[:, :2], axis=0), axis=1) * FPS
    assert walker.speed_bound <= SPEED * 1.15 + 1e-9
    assert speed.max() <= walker.speed_bound * 1.001, speed.max()
    # and a walker walks: most of its walking time near its pace, not creeping
    walking = np.array([not walker.sitting(t) for t in TIMES[:-1]])
    assert np.median(speed[walking]) > 0.8 * SPEED * 0.85


def test_no_part_of_a_tum_walker_jumps_between_frames(poses):
    """Sitting down and standing up move every part smoothly: no part goes faster than
    9 m/s from one 60 Hz sample to the next (a swinging foot peaks at about 6.5 m/s at
    this pace, ``Walker`` moving it in 70 % of its swing; a part that jumped to its next
    pose would go 15 m/s or more)."""
    positions, _ = poses
    moved = np.linalg.norm(np.diff(positions, axis=0), axis=2).max(axis=1)
    assert moved.max() < 9.0 * STEP_S, (moved.argmax() * STEP_S, moved.max())


def test_a_tum_walkers_velocity_integrates_to_its_motion(walker: TumWalker):
    """``velocity`` (what ground truth records for the actor) summed over each frame
    interval (midpoint rule, 16 steps: a path's heading turns in small steps) gives how
    far the root moved and turned in it, at every sixth frame."""
    n = 16
    for t in TIMES[:-1:6]:
        dt = 1.0 / FPS / n
        mids = t + dt * (np.arange(n) + 0.5)
        linear = sum(walker.velocity(float(m))[0] for m in mids) * dt
        angular = sum(walker.velocity(float(m))[1] for m in mids) * dt
        (p0, r0), (p1, r1) = walker.root(t), walker.root(t + 1.0 / FPS)
        assert np.linalg.norm(linear - (p1 - p0)) < 2e-3, t
        turned = Rotation.from_matrix(r1 @ r0.T).as_rotvec()
        assert np.linalg.norm(angular - turned) < 0.01, t


def test_a_tum_walker_keeps_out_of_the_desk_while_on_its_feet(poses):
    (x, y), (hx, hy) = DESK_CENTRE, DESK_HALF
    clearance = 0.1
    positions, sitting = poses
    for xy in positions[~sitting][:, :, :2]:
        inside = (
            (xy[:, 0] > x - hx - clearance)
            & (xy[:, 0] < x + hx + clearance)
            & (xy[:, 1] > y - hy - clearance)
            & (xy[:, 1] < y + hy + clearance)
        )
        assert not inside.any(), xy[inside]


def test_a_tum_walker_sits_on_its_own_seat_facing_the_desk(walker: TumWalker):
    seat_x, seat_y, yaw = plan_layout(LayoutSpec(), np.random.default_rng(0)).seats[walker.seat_index]
    sit = next(s for s in walker.stretches if s.what == "sit")
    position, rotation = walker.root(sit.t0 + 1.0)
    assert np.allclose(position[:2], (seat_x, seat_y))
    assert math.isclose(math.degrees(math.atan2(rotation[1, 0], rotation[0, 0])), yaw, abs_tol=1e-6)
    assert math.isclose(
        sit.t0 - next(s for s in walker.stretches if s.what == "sit down").t0, SIT_TRANSITION_S
    )


def test_a_tum_walker_is_the_same_for_the_same_seed_and_differs_for_another():
    a, b, c = tum_walker(5), tum_walker(5), tum_walker(6)
    for t in (0.0, 7.3, 19.1, 33.3):
        assert np.array_equal(a.pose(t)[0], b.pose(t)[0]) and np.array_equal(a.pose(t)[1], b.pose(t)[1])
    assert any(not np.allclose(a.pose(t)[0], c.pose(t)[0]) for t in (0.0, 7.3, 19.1, 33.3))


def test_seated_people_keep_talking_and_gesturing_for_40_s():
    """Over every 8 s of 40, each hand rises at least 8 cm (a gesture), the head turns
    at least 15 degrees and the torso leans at least 3 degrees."""
    person = SittingPerson((0.45, 2.25, -120.0), 1.0, MATERIALS, np.random.default_rng(4))
    times = np.arange(0.0, DURATION_S, 0.1)
    poses = [person.pose(t) for t in times]
    forearms = np.array([p[0][5:7, 2] for p in poses])
    heads = np.array([math.atan2(p[1][2][1, 0], p[1][2][0, 0]) for p in poses])
    leans = np.array([math.degrees(math.acos(min(1.0, p[1][1][2, 2]))) for p in poses])
    for start in np.arange(0.0, DURATION_S - 8.0, 2.0):
        window = (times >= start) & (times < start + 8.0)
        rise = forearms[window].max(axis=0) - forearms[window].min(axis=0)
        assert (rise > 0.08).all(), (start, rise)
        assert math.degrees(np.ptp(np.unwrap(heads[window]))) > 15.0, start
        assert np.ptp(leans[window]) > 3.0, start


@pytest.mark.parametrize(
    ("actor", "layout", "message"),
    [
        ({"kind": "dog", "path": "tum_walk"}, {}, "path 'tum_walk' does not go with kind 'dog'"),
        ({"kind": "person", "path": "tum_walk"}, {"desk": False}, "layout.desk: path 'tum_walk' sits"),
    ],
)
def test_tum_walk_is_for_people_and_needs_the_desk(actor, layout, message):
    data = {"name": "k", "actors": [actor], "layout": layout}
    with pytest.raises(SpecError, match=message):
        parse_scenario(data, "k.yaml")
    parse_scenario({"name": "k", "actors": [{"kind": "person", "path": "tum_walk"}]}, "k.yaml")
