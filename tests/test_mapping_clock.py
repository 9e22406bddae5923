"""ORB-SLAM3's mapping thread on a virtual clock (``depotbench.slam.mapping_clock``).

- On a stub mapper whose steps take fixed times, the order of steps, the skipped fusion and
  adjustment, the interrupted adjustment's iterations and the frame that first sees each
  effect are worked out by hand from ORB-SLAM3's LocalMapping::Run and g2o's stop flag.
- On a generated walking sequence: a clock whose steps take no time is the synchronous
  mapper bit for bit; a slow one is deterministic, skips or interrupts work, and a fork of
  it goes on exactly as the system it was forked from.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pytest
from depotbench.slam import mapping_clock
from depotbench.slam.config import SlamConfig, TrackingConfig
from depotbench.slam.mapping_clock import MappingClock, MappingCosts

FRAME = 1 / 30


@dataclass(frozen=True)
class FixedCosts(MappingCosts):
    """Every step a fixed length (ms), whatever its size."""

    new_points_fixed: float = 10.0
    fusion_fixed: float = 10.0
    iteration_fixed: float = 10.0
    culling_fixed: float = 5.0

    def new_points(self, map_, keyframe_id):
        return self.new_points_fixed

    def fusion(self, map_, targets):
        return self.fusion_fixed

    def iteration(self, window):
        return self.iteration_fixed

    def culling(self, map_, keyframe_id):
        return self.culling_fixed


class StubSolver:
    """LevenbergMarquardt's interface: converges after ``converge_after`` iterations."""

    converge_after = 10

    def __init__(self, problem) -> None:
        self.iterations = 0
        self.stopped = False

    def iterate(self) -> bool:
        self.iterations += 1
        self.stopped = self.iterations >= self.converge_after
        return not self.stopped


@dataclass
class StubMapping:
    """LocalMapping's steps, logged."""

    log: list = field(default_factory=list)
    tc: TrackingConfig = TrackingConfig()

    def create_new_map_points(self, map_, keyframe_id):
        self.log.append(("create", keyframe_id))

    def fusion_targets(self, map_, keyframe_id):
        return []

    def search_in_neighbors(self, map_, keyframe_id):
        self.log.append(("fuse", keyframe_id))

    def local_window(self, map_, keyframe_id):
        return SimpleNamespace(problem=None, keyframe=keyframe_id)

    def apply_adjustment(self, map_, window, solver):
        self.log.append(("adjust", window.keyframe, solver.iterations))

    def keyframe_culling(self, map_, keyframe_id):
        self.log.append(("cull keyframes", keyframe_id))


class StubMap:
    def __init__(self, n_keyframes: int, log: list) -> None:
        self.all_keyframes = [SimpleNamespace(bad=False) for _ in range(n_keyframes)]
        self.log = log

    @property
    def keyframes(self):
        return [kf for kf in self.all_keyframes if not kf.bad]

    def keyframe(self, keyframe_id):
        return self.all_keyframes[keyframe_id]

    def cull(self, keyframe_id, recent):
        self.log.append(("cull points", keyframe_id))


@pytest.fixture
def stub(monkeypatch):
    monkeypatch.setattr(mapping_clock, "LevenbergMarquardt", StubSolver)
    mapping = StubMapping()
    return mapping, StubMap(6, mapping.log)


def test_an_adjustment_stops_before_the_iteration_that_follows_the_next_keyframe(stub):
    """Keyframe 3 is inserted at 0 and keyframe 4 at the next frame (33.3 ms). Keyframe 3's
    new points take 0-10 ms and fusion 10-20; its adjustment's iterations start at 20 and 30
    ms, and the one at 40 ms does not start (the insertion at 33.3 set the abort flag, which
    g2o reads before each iteration). The adjustment (2 iterations) ends at 40 ms, so the frame
    at 33.3 ms tracks without it and the frame at 66.7 ms with it; keyframe culling follows
    (40-45), then keyframe 4: points 45-55, fusion 55-65, and its first iteration at 65 ms."""
    mapping, map_ = stub
    clock = MappingClock(mapping, 1.0, FixedCosts(adjustment_ms=0.0))
    clock.insert(3, 0.0)
    clock.run_until(map_, 0.0, inclusive=True)
    assert mapping.log == [] and not clock.idle
    clock.run_until(map_, FRAME, inclusive=False)
    assert mapping.log == [("cull points", 3), ("create", 3), ("fuse", 3)]
    assert clock.job.solver.iterations == 2  # started at 20 and 30 ms, before the frame
    clock.insert(4, FRAME)
    clock.run_until(map_, FRAME, inclusive=True)
    assert mapping.log[-1] == ("fuse", 3)  # the adjustment ends at 40 ms: not yet
    clock.run_until(map_, 2 * FRAME, inclusive=False)
    assert mapping.log[3:] == [
        ("adjust", 3, 2),
        ("cull keyframes", 3),
        ("cull points", 4),
        ("create", 4),
        ("fuse", 4),
    ]
    assert clock.skipped == {"fusion": 0, "adjustment": 0, "interrupted": 1}
    assert clock.job.keyframe == 4 and clock.job.solver.iterations == 1  # began at 65 ms


def test_a_keyframe_waiting_skips_fusion_adjustment_and_culling(stub):
    """New points take 50 ms; keyframe 4 comes at 33.3 ms, while keyframe 3's are made. At 50
    ms keyframe 4 waits, so keyframe 3 skips SearchInNeighbors and, the queue checked again,
    the adjustment and KeyFrameCulling (LocalMapping::Run); keyframe 4's points then take
    50-100 ms, past the frame at 66.7 ms."""
    mapping, map_ = stub
    clock = MappingClock(mapping, 1.0, FixedCosts(new_points_fixed=50.0))
    clock.insert(3, 0.0)
    clock.run_until(map_, 0.0, inclusive=True)
    clock.run_until(map_, FRAME, inclusive=False)
    assert mapping.log == [] and clock.waiting == 0
    clock.insert(4, FRAME)
    assert clock.waiting == 1
    clock.run_until(map_, 2 * FRAME, inclusive=False)
    assert mapping.log == [("cull points", 3), ("create", 3)]
    assert clock.skipped == {"fusion": 1, "adjustment": 1, "interrupted": 0}
    assert clock.job.keyframe == 4 and clock.waiting == 0
    clock.run_until(map_, 4 * FRAME, inclusive=False)  # points 50-100 ms, fusion 100-110
    assert mapping.log[2:] == [("cull points", 4), ("create", 4), ("fuse", 4)]


def test_an_adjustment_that_converges_ends_early_and_a_slower_scale_stretches_every_step(stub, monkeypatch):
    """Converging after 1 iteration, keyframe 3's adjustment (20-30 ms) and culling (30-35 ms)
    are done before the frame at 33.3 ms at scale 1... but not at scale 2, where the same steps
    take twice as long (the adjustment ends at 60 ms)."""
    monkeypatch.setattr(StubSolver, "converge_after", 1)
    mapping, map_ = stub
    clock = MappingClock(mapping, 1.0, FixedCosts(adjustment_ms=0.0, culling_fixed=3.0))
    clock.insert(3, 0.0)
    clock.run_until(map_, FRAME, inclusive=False)
    assert mapping.log[-2:] == [("adjust", 3, 1), ("cull keyframes", 3)] and clock.idle
    slow_log: list = []
    slow = MappingClock(StubMapping(slow_log), 2.0, FixedCosts(adjustment_ms=0.0, culling_fixed=3.0))
    slow.insert(3, 0.0)
    slow.run_until(StubMap(6, slow_log), FRAME, inclusive=False)
    assert slow_log == [("cull points", 3), ("create", 3)] and not slow.idle


def test_a_copied_clock_goes_on_alone(stub):
    """A fork copies the queue, the job and the adjustment's state: advancing the original
    leaves the copy where it was, and the copy then does what the original did."""
    mapping, map_ = stub
    clock = MappingClock(mapping, 1.0, FixedCosts(adjustment_ms=0.0))
    clock.insert(3, 0.0)
    clock.run_until(map_, FRAME, inclusive=False)
    twin = clock.copy()
    clock.insert(4, FRAME)
    clock.run_until(map_, 2 * FRAME, inclusive=False)
    assert twin.job.solver.iterations == 2 and twin.waiting == 0 and twin.skipped["interrupted"] == 0
    twin_log: list = []
    twin.mapping = StubMapping(twin_log)
    twin.insert(4, FRAME)
    twin.run_until(StubMap(6, twin_log), 2 * FRAME, inclusive=False)
    assert twin_log == mapping.log[3:] and twin.skipped == clock.skipped


# -- on a generated sequence -----------------------------------------------------------


@pytest.fixture(scope="module")
def walking(tmp_path_factory: pytest.TempPathFactory):
    from depotbench.scenes import library
    from depotbench.scenes.schema import to_scenario
    from depotbench.sim.generate import generate
    from depotbench.sim.sequence import Sequence

    spec = library.get("walking_xyz").model_copy(update={"frames": 24, "duration_s": None})
    folder = tmp_path_factory.mktemp("clock") / "walk"
    return Sequence.open(generate(to_scenario(spec), folder, progress=False))


def _run(seq, config: SlamConfig, clock_scale: float | None = None, fork_at: int | None = None):
    """Poses, keyframe poses and the clock's counters of a run (with the clock forced on at
    ``clock_scale``); with ``fork_at``, also the run of a fork taken before that frame."""
    from depotbench.eval.run.harness import camera_of
    from depotbench.slam.system import Slam
    from depotbench.slam.types import Frame

    camera = camera_of(seq)
    slam = Slam(config, camera)
    if clock_scale is not None:
        slam.tracking.clock = MappingClock(slam.tracking.mapping, clock_scale)
    systems = [slam]
    for i in range(len(seq)):
        if i == fork_at:
            systems.append(slam.fork(config))
        for system in systems:
            system.process(Frame(seq.frames[i].timestamp_s, seq.rgb(i), seq.depth_m(i), camera))
    return [_digest(system) for system in systems]


def _digest(slam) -> tuple:
    clock = slam.tracking.clock
    return (
        [pose.tobytes() for _, pose in slam.trajectory],
        [kf.world_from_camera.tobytes() for kf in slam.map.keyframes],
        None if clock is None else dict(clock.skipped),
    )


def test_a_clock_whose_steps_take_no_time_is_the_synchronous_mapper_bit_for_bit(walking):
    """Scale 0: every step ends when its keyframe is inserted, so each keyframe is mapped
    before the next frame, as ``LocalMapping.map_keyframe`` maps it."""
    (synchronous,) = _run(walking, SlamConfig())
    (clocked,) = _run(walking, SlamConfig(), clock_scale=0.0)
    assert len(synchronous[1]) >= 4  # keyframes enough for adjustments and culling
    assert clocked[:2] == synchronous[:2]
    assert clocked[2] == {"fusion": 0, "adjustment": 0, "interrupted": 0}


def test_a_slow_mapper_is_deterministic_skips_work_and_forks_exactly(walking):
    """At 20 times the measured costs the mapper falls behind: keyframes skip fusion or the
    adjustment, or have it interrupted, and the trajectory differs from the synchronous one.
    Run twice, it is the same bytes; a fork taken at frame 12 (mid-job) goes on exactly as the
    system it was forked from."""
    config = SlamConfig(tracking=TrackingConfig(mapper_time_scale=20.0))
    (synchronous,) = _run(walking, SlamConfig())
    first, forked = _run(walking, config, fork_at=12)
    (second,) = _run(walking, config)
    assert first == second == forked
    assert sum(first[2].values()) > 0
    assert first[0] != synchronous[0]


def test_the_setting_is_range_checked():
    from depotbench.slam.config import ConfigError

    with pytest.raises(ConfigError, match="mapper_time_scale"):
        TrackingConfig(mapper_time_scale=-1.0)
    assert TrackingConfig().mapper_time_scale == 0.0


def test_costs_grow_with_the_window():
    """An iteration's modelled cost is linear in observations, in the sum of squared
    free-keyframe sightings per point and in free keyframes cubed: doubling a window's
    points (same sightings each) doubles its first two terms."""
    costs = MappingCosts()

    def window(points: int, free: int):
        obs_point = np.repeat(np.arange(points), free)
        obs_pose = np.tile(np.arange(free), points)
        problem = SimpleNamespace(
            free=np.ones(free, bool), obs_pose=obs_pose, obs_point=obs_point, points=np.zeros((points, 3))
        )
        return SimpleNamespace(problem=problem)

    small, large = costs.iteration(window(100, 5)), costs.iteration(window(200, 5))
    per_observation, per_block, per_cubed_pose = costs.iteration_ms
    cubed = per_cubed_pose * 125
    assert large - cubed == pytest.approx(2 * (small - cubed))
    assert small == pytest.approx(per_observation * 500 + per_block * 100 * 25 + cubed)
