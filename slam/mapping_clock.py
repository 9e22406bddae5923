"""ORB-SLAM3's local-mapping thread on a virtual clock: the work a mapper that takes time skips.

ORB-SLAM3 maps in a thread of its own. While that thread is busy the tracker's
NeedNewKeyFrame takes a keyframe only when tracking is weak (c1c) or 30 frames have passed
(c1a), interrupts the bundle adjustment (g2o stops before its next iteration) and queues at
most three keyframes; the mapper skips SearchInNeighbors, the adjustment and KeyFrameCulling
while another keyframe waits. How much it skips depends on how long each step takes, so on
a walking analog, where the covisibility window holds 40-70 keyframes, an adjustment run to
its end costs 100-300 ms against a keyframe every 66 ms.

Here the mapper runs in the tracker's thread, so that a run stays deterministic, on a
virtual clock: a frame arrives at its timestamp and takes no time to track; each mapping
step lasts what ``MappingCosts`` says for its size (counts of keyframes, points and
observations, never a measured time), times ``mapper_time_scale``; a step starts when the
step before it ends, and its effect reaches the map before the first frame that arrives
after it ends. The tracker waits for the mapper at two fixed points of each frame: before
tracking it (steps that end by the frame's time) and after its keyframe decision (steps
that could start and end at that instant, which only a scale of 0 gives). A keyframe
inserted, or an interrupt, at a frame's time comes before any step that starts at that time.
At scale 0 every step is instant, the mapper always idle and every keyframe mapped before
the next frame: the synchronous mapper (``LocalMapping.map_keyframe``), bit for bit (tested).

Where this differs from the thread: tracking takes no time (a keyframe is inserted at its
frame's timestamp); ProcessNewKeyFrame's bookkeeping (observations, covisibility, normals)
is done at insertion, so a queued keyframe is already in the covisibility graph; a step is
computed on the map as it stands at the frame where it ends (the adjustment's window when
the adjustment starts), not interleaved with tracking; the thread's 3 ms sleep between
keyframes is left out; and keyframes still queued when the run ends are not mapped.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from depotbench.slam.bundle import LevenbergMarquardt, iteration_limit
from depotbench.slam.local_mapping import (
    MAX_CULLING_CHECKS,
    NEIGHBOURS_TRIANGULATION,
    LocalMapping,
    LocalWindow,
)
from depotbench.slam.map import Map

MAX_QUEUED = 3
"""A busy mapper takes a keyframe from an RGB-D tracker while fewer than 3 wait (ORB-SLAM3)."""


def new_points_terms(map_: Map, keyframe_id: int) -> np.ndarray:
    """MapPointCulling and CreateNewMapPoints: 1 and the covisible keyframes paired (<= 10)."""
    return np.array([1.0, len(map_.covisible(keyframe_id, NEIGHBOURS_TRIANGULATION))])


def fusion_terms(map_: Map, targets: list[int]) -> np.ndarray:
    """SearchInNeighbors: 1, its target keyframes and the points they hold."""
    points = sum(int(np.count_nonzero(map_.keyframe(t).point_ids >= 0)) for t in targets)
    return np.array([1.0, len(targets), points])


def iteration_terms(window: LocalWindow) -> np.ndarray:
    """One Levenberg-Marquardt iteration: its observations (each linearised), the 6x6 blocks
    of the reduced system (over points, the square of the free keyframes seeing it) and the
    free keyframes cubed (the dense solve)."""
    problem = window.problem
    on_free = problem.free[problem.obs_pose]
    seen = np.bincount(problem.obs_point[on_free], minlength=len(problem.points)).astype(float)
    n_free = float(np.count_nonzero(problem.free))
    return np.array([len(problem.obs_pose), float(np.sum(seen**2)), n_free**3])


def culling_terms(map_: Map, keyframe_id: int) -> np.ndarray:
    """KeyFrameCulling: the points of the (at most 100) covisible keyframes it checks."""
    checked = map_.covisible(keyframe_id)[:MAX_CULLING_CHECKS]
    points = sum(int(np.count_nonzero(map_.keyframe(int(k)).point_ids >= 0)) for k in checked)
    return np.array([float(points)])


@dataclass(frozen=True)
class MappingCosts:
    """Milliseconds each local-mapping step takes on one core: coefficients of its terms
    (``*_terms``), so a step's length is a line in its size.

    Fitted by ``benchmarks/mapping_costs.py`` (non-negative least squares, each step timed
    whole, the adjustment with its window and the writing back of its result): 572
    keyframes of seven 150-frame walking clips of tum-dyn-short-1 (walking_static seeds
    301, 302, 304, walking_xyz 302, 304, walking_rpy 301, 303; `none` and
    box_epipolar_flow), one pinned core of the 2-core AMD EPYC development machine,
    2026-12-05, after the mapping's hot spots were made cheaper (the fit of 2026-12-03 gave
    the adjustment a 10.3 ms set-up, 2.5x what it now takes). The adjustment's line fits its
    calls with R^2 0.96 (median error 9 %), SearchInNeighbors' 0.89 (13 %),
    KeyFrameCulling's 0.53 and the new points' 0.14; those two are a tenth of the mapping
    time. Two more fits of the same runs that day gave the adjustment a set-up of 4.0 and
    3.3 ms against 4.7 and 0.17 and 0.22 us an observation against 0.16: the timings'
    noise, which ``mapper_time_scale`` dwarfs."""

    new_points_ms: tuple[float, ...] = (0.0, 0.483)
    fusion_ms: tuple[float, ...] = (1.14, 0.0836, 1.68e-3)
    adjustment_ms: float = 4.72
    """The local bundle adjustment's set-up: its window, the problem, the outlier test and
    writing the result back."""
    iteration_ms: tuple[float, ...] = (1.62e-4, 1.43e-5, 2.2e-5)
    culling_ms: tuple[float, ...] = (2.55e-4,)

    def new_points(self, map_: Map, keyframe_id: int) -> float:
        return float(np.dot(self.new_points_ms, new_points_terms(map_, keyframe_id)))

    def fusion(self, map_: Map, targets: list[int]) -> float:
        return float(np.dot(self.fusion_ms, fusion_terms(map_, targets)))

    def iteration(self, window: LocalWindow) -> float:
        return float(np.dot(self.iteration_ms, iteration_terms(window)))

    def culling(self, map_: Map, keyframe_id: int) -> float:
        return float(np.dot(self.culling_ms, culling_terms(map_, keyframe_id)))


COSTS = MappingCosts()

NEW_POINTS, FUSION, ADJUSTMENT, CULLING = range(4)
"""A keyframe's steps, in ORB-SLAM3's LocalMapping::Run order."""


@dataclass
class _Job:
    """The keyframe the mapper works on: its next step, when that step starts (s), and what
    a step that has begun but not ended keeps (its length, the adjustment's state)."""

    keyframe: int
    step: int
    start: float
    length: float | None = None
    abort_reset: float = 0.0
    """When the adjustment's abort flag was last cleared (before SearchInNeighbors)."""
    window: LocalWindow | None = None
    solver: LevenbergMarquardt | None = None
    setup_s: float = 0.0
    iteration_s: float = 0.0
    finished: bool = False
    """The adjustment has run its last iteration (converged, capped or interrupted)."""


@dataclass
class MappingClock:
    """The mapping thread's queue and clock; ``Tracking`` drives it at each frame."""

    mapping: LocalMapping
    scale: float
    costs: MappingCosts = COSTS
    queue: list[tuple[int, float]] = field(default_factory=list)
    """Keyframes inserted and not yet taken, with their insertion times (s)."""
    job: _Job | None = None
    free_at: float = -np.inf
    """When the mapper finished its last step."""
    interrupts: list[float] = field(default_factory=list)
    """Times of keyframe insertions and InterruptBA calls since the current job began."""
    skipped: dict[str, int] = field(default_factory=lambda: {"fusion": 0, "adjustment": 0, "interrupted": 0})
    """How many keyframes skipped fusion, skipped the adjustment, or had it interrupted."""

    def copy(self) -> MappingClock:
        """An independent copy for a forked tracker; an adjustment under way is copied too
        (its state is a few arrays), and its window, which nothing changes, is shared."""
        twin = copy.copy(self)
        twin.queue, twin.interrupts = list(self.queue), list(self.interrupts)
        twin.skipped = dict(self.skipped)
        if self.job is not None:
            twin.job = copy.copy(self.job)
            if self.job.solver is not None:
                twin.job.solver = copy.copy(self.job.solver)
        return twin

    @property
    def idle(self) -> bool:
        """ORB-SLAM3's AcceptKeyFrames: no keyframe in hand and none waiting."""
        return self.job is None and not self.queue

    @property
    def waiting(self) -> int:
        return len(self.queue)

    def insert(self, keyframe_id: int, time_s: float) -> None:
        """Queue a keyframe (LocalMapping::InsertKeyFrame, which also interrupts the adjustment)."""
        self.queue.append((keyframe_id, time_s))
        self.interrupts.append(time_s)

    def interrupt(self, time_s: float) -> None:
        """InterruptBA: the tracker wanted a keyframe while the mapper was busy."""
        self.interrupts.append(time_s)

    def run_until(self, map_: Map, time_s: float, inclusive: bool) -> None:
        """Run every step that starts before ``time_s`` (or at it, when ``inclusive``: after
        the frame's own insertion) and ends by it."""

        def may_start(start: float) -> bool:
            return start < time_s or (inclusive and start == time_s)

        while True:
            if self.job is None:
                if not self.queue:
                    return
                keyframe, inserted = self.queue[0]
                start = max(self.free_at, inserted)
                if not may_start(start):
                    return
                self.queue.pop(0)
                self.interrupts = [t for t in self.interrupts if t > start]
                if map_.keyframe(keyframe).bad:  # culled by an earlier keyframe's culling
                    self.free_at = start
                    continue
                self.job = _Job(keyframe, NEW_POINTS, start)
            if not self._step(map_, time_s, may_start):
                return

    # -- one step -------------------------------------------------------------------------

    def _queued_by(self, time_s: float) -> bool:
        return any(inserted <= time_s for _, inserted in self.queue)

    def _finish(self, end: float, next_step: int | None) -> None:
        job = self.job
        if next_step is None:
            self.job = None
            self.free_at = end
            return
        job.step, job.start, job.length = next_step, end, None

    def _step(self, map_: Map, time_s: float, may_start) -> bool:
        """Advance the job by one step if that step can end by ``time_s``; False if it must wait."""
        job, mapping = self.job, self.mapping
        if not may_start(job.start):
            return False
        if job.step == NEW_POINTS:

            def new_points() -> None:
                map_.cull(job.keyframe, mapping.tc.recent_point_keyframes)
                mapping.create_new_map_points(map_, job.keyframe)

            return self._timed(time_s, lambda: self.costs.new_points(map_, job.keyframe), new_points, FUSION)
        if job.step == FUSION:
            job.abort_reset = job.start
            if self._queued_by(job.start):  # the next keyframe waits: no fusion, no adjustment
                self.skipped["fusion"] += 1
                self.skipped["adjustment"] += 1
                self._finish(job.start, None)
                return True
            return self._timed(
                time_s,
                lambda: self.costs.fusion(map_, mapping.fusion_targets(map_, job.keyframe)),
                lambda: mapping.search_in_neighbors(map_, job.keyframe),
                ADJUSTMENT,
            )
        if job.step == ADJUSTMENT:
            return self._adjust(map_, time_s, may_start)
        return self._timed(
            time_s,
            lambda: self.costs.culling(map_, job.keyframe),
            lambda: mapping.keyframe_culling(map_, job.keyframe),
            None,
        )

    def _timed(self, time_s: float, cost_ms, work, next_step: int | None) -> bool:
        """A step that runs whole: its length is fixed (from ``cost_ms()``) when first
        looked at; ``work()`` runs once the step can end by ``time_s``."""
        job = self.job
        if job.length is None:
            job.length = self.scale * cost_ms() / 1e3
        if job.start + job.length > time_s:
            return False
        work()
        self._finish(job.start + job.length, next_step)
        return True

    def _adjust(self, map_: Map, time_s: float, may_start) -> bool:
        """The local bundle adjustment, an iteration at a time: iteration i starts at
        s + set-up + i x (one iteration's length) and runs unless an interrupt came before
        it (after the abort flag was cleared); the result reaches the map when the last
        iteration run ends."""
        job, mapping = self.job, self.mapping
        if job.solver is None:  # the adjustment starts
            if self._queued_by(job.start):
                self.skipped["adjustment"] += 1
                self._finish(job.start, None)
                return True
            window = mapping.local_window(map_, job.keyframe) if len(map_.keyframes) > 2 else None
            if window is None:
                self._finish(job.start, CULLING)
                return True
            job.window, job.solver = window, LevenbergMarquardt(window.problem)
            job.setup_s = self.scale * self.costs.adjustment_ms / 1e3
            job.iteration_s = self.scale * self.costs.iteration(window) / 1e3
        solver = job.solver
        limit = iteration_limit(mapping.tc.ba_iterations)
        abort = min((t for t in self.interrupts if t > job.abort_reset), default=np.inf)
        while not job.finished:
            begins = job.start + job.setup_s + solver.iterations * job.iteration_s
            if solver.stopped or solver.iterations >= limit:
                job.finished = True
            elif not begins < abort:
                job.finished = True
                self.skipped["interrupted"] += 1
            elif may_start(begins):
                solver.iterate()
            else:
                return False  # the next iteration starts after this frame: an interrupt may come first
        end = job.start + job.setup_s + solver.iterations * job.iteration_s
        if end > time_s:
            return False
        mapping.apply_adjustment(map_, job.window, solver)
        job.window, job.solver, job.finished = None, None, False
        self._finish(end, CULLING)
        return True
