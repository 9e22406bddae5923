"""Keyframes and map points, held in arrays for vectorised projection, with the covisibility graph.

Beside each point's position and descriptor the map keeps what ORB-SLAM's MapPoint keeps for
the local-map search: its mean viewing direction and the distances at which it can be seen
(``max_distance`` = distance at its reference keyframe times scale^octave, ``min_distance`` =
that over scale^(levels - 1)). Keyframes carry ORB-SLAM's covisibility weights as one
matrix, kept current as observations come and go: ``covisibility[i, j]`` is the number of
points keyframes i and j both see, and two keyframes are neighbours from ``COVISIBILITY_MIN``
(15) shared points. A culled keyframe stays in ``all_keyframes`` (ids are indices) flagged
``bad``; ``keyframes`` lists the live ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from itertools import chain

import numpy as np
from depotbench.slam import kernels
from depotbench.slam.features import FrameFeatures
from depotbench.slam.geometry import POPCOUNT

COVISIBILITY_MIN = 15
"""ORB-SLAM's KeyFrame::UpdateConnections: keyframes sharing at least 15 points are connected
(a keyframe with no such neighbour is connected to the one it shares most with)."""

_NONE: dict[int, int] = {}
"""The observations of a point no keyframe sees (read only)."""

_POINT_ARRAYS = (
    "positions",
    "descriptors",
    "alive",
    "first_keyframe",
    "visible",
    "found",
    "n_observations",
    "observation_weight",
    "normals",
    "max_distance",
    "min_distance",
    "replaced",
)


@dataclass(eq=False)
class KeyFrame:
    id: int
    frame_index: int
    world_from_camera: np.ndarray
    features: FrameFeatures
    usable: np.ndarray
    """Keypoints that passed rejection."""
    point_ids: np.ndarray
    """Map point id per keypoint, -1 where none."""
    bad: bool = False
    """Culled (ORB-SLAM's KeyFrameCulling): kept for its id, seen by no point."""
    parent: int = -1
    """The keyframe it shared most points with when inserted (ORB-SLAM's spanning tree)."""

    @property
    def center(self) -> np.ndarray:
        return self.world_from_camera[:3, 3]


@dataclass(eq=False)
class _KeypointTable:
    """One feature array of every keyframe end to end, so that ``Map.keypoint_values`` is one
    gather: a KeyFrameCulling pass asks ~100 times and a local BA's table names ~200 keyframes
    at TUM's length, where grouping by keyframe cost 0.4 ms a call. Features never change once
    a keyframe is made, so the table only grows (its room doubling)."""

    name: str
    """The ``FrameFeatures`` array it holds (``octaves``, ``descriptors``, ...)."""
    values: np.ndarray
    """(room, ...) the keyframes' values; the first ``rows`` are filled."""
    rows: int
    starts: np.ndarray
    """Each keyframe's first row, for the keyframes taken so far."""

    @classmethod
    def of(cls, name: str, first: KeyFrame) -> _KeypointTable:
        """An empty table of ``first``'s array ``name`` (its dtype and trailing shape)."""
        values = getattr(first.features, name)
        return cls(name, np.empty((0, *values.shape[1:]), values.dtype), 0, np.zeros(0, int))

    def extend(self, keyframes: list[KeyFrame]) -> None:
        """Take the keyframes not in the table yet (ids are indices)."""
        arrays = [getattr(kf.features, self.name) for kf in keyframes[len(self.starts) :]]
        if not arrays:
            return
        lengths = np.array([len(a) for a in arrays])
        starts = self.rows + np.r_[0, np.cumsum(lengths)[:-1]]
        rows = self.rows + int(lengths.sum())
        if rows > len(self.values):
            grown = np.empty((max(rows, 2 * len(self.values)), *self.values.shape[1:]), self.values.dtype)
            grown[: self.rows] = self.values[: self.rows]
            self.values = grown
        for start, values in zip(starts.tolist(), arrays, strict=True):
            self.values[start : start + len(values)] = values
        self.starts = np.r_[self.starts, starts]
        self.rows = rows


@dataclass
class Map:
    """Map points as growable arrays; keyframes by id, in insertion order."""

    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    descriptors: np.ndarray = field(default_factory=lambda: np.zeros((0, 32), np.uint8))
    alive: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    first_keyframe: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    visible: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    found: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    n_observations: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    """Keyframes observing each point (kept equal to len(observations[point]))."""
    observation_weight: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    """ORB-SLAM's MapPoint::Observations(): 2 per keyframe whose keypoint has depth, else 1."""
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """Mean unit direction from the observing keyframes' centres to the point."""
    max_distance: np.ndarray = field(default_factory=lambda: np.zeros(0))
    min_distance: np.ndarray = field(default_factory=lambda: np.zeros(0))
    replaced: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    """The point a fused point was merged into, -1 where none (ORB-SLAM's GetReplaced)."""
    all_keyframes: list[KeyFrame] = field(default_factory=list)
    observations: dict[int, dict[int, int]] = field(default_factory=dict)
    """point id -> {keyframe id: keypoint index}."""
    covisibility: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.int32))
    """(capacity, capacity) shared-point counts between keyframes (the first len(all_keyframes))."""
    _culled: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    """(capacity,) each keyframe's ``bad`` flag as one array (``covisible`` reads it ~30 times a
    frame); ``add_keyframe`` and ``set_bad`` keep the two equal."""
    _keypoint_tables: dict[str, _KeypointTable] = field(default_factory=dict, repr=False, compare=False)
    """``keypoint_values``' tables by feature name (a copy builds its own)."""

    # -- keyframes -------------------------------------------------------------------

    @property
    def keyframes(self) -> list[KeyFrame]:
        """The live keyframes, oldest first."""
        return [kf for kf in self.all_keyframes if not kf.bad]

    def keyframe(self, keyframe_id: int) -> KeyFrame:
        return self.all_keyframes[keyframe_id]

    def add_keyframe(self, keyframe: KeyFrame) -> None:
        """Append a keyframe (its id must be the next one); its observations come after."""
        if keyframe.id != len(self.all_keyframes):
            raise ValueError(f"keyframe id {keyframe.id} is not the next one ({len(self.all_keyframes)})")
        self.all_keyframes.append(keyframe)
        capacity = len(self.covisibility)
        if len(self.all_keyframes) > capacity:
            grown = np.zeros((max(16, 2 * capacity),) * 2, np.int32)
            grown[:capacity, :capacity] = self.covisibility
            self.covisibility = grown
            self._culled = np.r_[self._culled, np.zeros(len(grown) - capacity, bool)]
        self._culled[keyframe.id] = keyframe.bad

    def covisible(self, keyframe_id: int, limit: int | None = None) -> np.ndarray:
        """Live keyframes connected to ``keyframe_id`` (at least ``COVISIBILITY_MIN`` shared
        points, or the one sharing most when none has that many), most shared first, at most
        ``limit`` of them (ORB-SLAM's GetBestCovisibilityKeyFrames / GetVectorCovisibleKeyFrames)."""
        n = len(self.all_keyframes)
        weights = self.covisibility[keyframe_id, :n].copy()
        weights[keyframe_id] = 0
        weights[self._culled[:n]] = 0
        order = np.lexsort((-np.arange(n), -weights))
        order = order[weights[order] > 0]
        connected = order[weights[order] >= COVISIBILITY_MIN]
        if not len(connected):
            connected = order[:1]
        return connected if limit is None else connected[:limit]

    def sightings(self, point_ids: np.ndarray) -> np.ndarray:
        """Per keyframe id, how many of ``point_ids`` it sees, a point listed twice counted
        twice (a frame can hold one point at two keypoints after a fusion, and ORB-SLAM's
        UpdateLocalKeyFrames counts per keypoint). A keyframe's ``point_ids`` hold exactly the
        points whose observations name it (``observe`` and ``forget`` keep the two equal; a
        culled keyframe holds none)."""
        wanted = np.bincount(point_ids, minlength=len(self.positions) + 1)
        wanted[-1] = 0  # the last slot answers -1, no point
        return np.array([wanted[kf.point_ids].sum() for kf in self.all_keyframes], int)

    def points_of(self, keyframe_ids: list[int]) -> np.ndarray:
        """The live points the keyframes see, ascending and each once."""
        seen = np.zeros(len(self.positions) + 1, bool)
        for kf_id in keyframe_ids:
            seen[self.all_keyframes[kf_id].point_ids] = True
        return np.flatnonzero(seen[:-1] & self.alive)

    def children(self, keyframe_id: int) -> list[int]:
        return [kf.id for kf in self.all_keyframes if kf.parent == keyframe_id and not kf.bad]

    def set_bad(self, keyframe_id: int) -> None:
        """Cull a keyframe (ORB-SLAM's KeyFrame::SetBadFlag): its observations are erased, a
        point left seen by at most one keyframe with depth (weight <= 2) is culled, and its
        children take its parent."""
        keyframe = self.all_keyframes[keyframe_id]
        for point in np.unique(keyframe.point_ids[keyframe.point_ids >= 0]):
            self.erase_observation(int(point), keyframe_id)
        keyframe.bad = True
        self._culled[keyframe_id] = True
        for kf in self.all_keyframes:
            if kf.parent == keyframe_id:
                kf.parent = keyframe.parent

    # -- points ----------------------------------------------------------------------

    def add_points(self, positions: np.ndarray, descriptors: np.ndarray, keyframe_id: int) -> np.ndarray:
        start = len(self.positions)
        n = len(positions)
        self.positions = np.vstack([self.positions, positions])
        self.descriptors = np.vstack([self.descriptors, descriptors])
        self.alive = np.r_[self.alive, np.ones(n, bool)]
        self.first_keyframe = np.r_[self.first_keyframe, np.full(n, keyframe_id)]
        self.visible = np.r_[self.visible, np.ones(n, int)]
        self.found = np.r_[self.found, np.ones(n, int)]
        self.n_observations = np.r_[self.n_observations, np.zeros(n, int)]
        self.observation_weight = np.r_[self.observation_weight, np.zeros(n, int)]
        self.normals = np.vstack([self.normals, np.zeros((n, 3))])
        self.max_distance = np.r_[self.max_distance, np.zeros(n)]
        self.min_distance = np.r_[self.min_distance, np.zeros(n)]
        self.replaced = np.r_[self.replaced, np.full(n, -1)]
        return np.arange(start, start + n)

    def _weight(self, keyframe_id: int, keypoints: np.ndarray | int) -> np.ndarray | int:
        """MapPoint::Observations()' share of each observation: 2 where the keypoint has depth."""
        return np.where(self.all_keyframes[keyframe_id].features.depth_m[keypoints] > 0, 2, 1)

    def observe(self, point_id: int, keyframe_id: int, keypoint: int) -> None:
        """Record that ``keyframe_id``'s ``keypoint`` sees ``point_id`` (and set its point id)."""
        self.observe_many(np.array([point_id]), keyframe_id, np.array([keypoint]))

    def observe_many(self, point_ids: np.ndarray, keyframe_id: int, keypoints: np.ndarray) -> None:
        """Record each (point, keypoint) pair of a keyframe in order, the counts and covisibility
        updated at once: a keyframe adds hundreds, and NumPy calls per pair cost ~6 us each."""
        seen_by = self.observations
        others: list[int] = []
        taken_points, taken_keypoints = [], []
        for point, keypoint in zip(point_ids.tolist(), keypoints.tolist(), strict=True):
            seen = seen_by.setdefault(point, {})
            if keyframe_id in seen:
                continue  # one keypoint per point in a keyframe (ORB-SLAM's IsInKeyFrame)
            others += seen
            seen[keyframe_id] = keypoint
            taken_points.append(point)
            taken_keypoints.append(keypoint)
        if not taken_points:
            return
        points, kps = np.array(taken_points), np.array(taken_keypoints)
        shared = np.bincount(np.array(others, int), minlength=len(self.covisibility))
        self.covisibility[keyframe_id] += shared.astype(self.covisibility.dtype)
        self.covisibility[:, keyframe_id] += shared.astype(self.covisibility.dtype)
        self.n_observations[points] += 1
        self.observation_weight[points] += self._weight(keyframe_id, kps)
        self.all_keyframes[keyframe_id].point_ids[kps] = points

    def forget(self, point_id: int, keyframe_id: int) -> None:
        """Drop one observation (an outlier found by bundle adjustment, a culled keyframe)."""
        seen = self.observations.get(point_id, {})
        keypoint = seen.pop(keyframe_id, None)
        if keypoint is not None:
            others = np.fromiter(seen, int, len(seen))
            self.covisibility[keyframe_id, others] -= 1
            self.covisibility[others, keyframe_id] -= 1
            self.n_observations[point_id] -= 1
            self.observation_weight[point_id] -= self._weight(keyframe_id, keypoint)
            self.all_keyframes[keyframe_id].point_ids[keypoint] = -1

    def erase_observation(self, point_id: int, keyframe_id: int) -> None:
        """ORB-SLAM's MapPoint::EraseObservation: drop the observation, and cull the point when
        at most one keyframe with depth sees it still (observation weight <= 2)."""
        self.forget(point_id, keyframe_id)
        if self.alive[point_id] and self.observation_weight[point_id] <= 2:
            self.cull_points(np.array([point_id]))

    def cull_points(self, point_ids: np.ndarray) -> None:
        """Remove points with every observation of them."""
        for point in point_ids:
            seen = self.observations.pop(int(point), {})
            kfs = np.fromiter(seen, int, len(seen))
            if len(kfs) > 1:
                self.covisibility[np.ix_(kfs, kfs)] -= 1
                self.covisibility[kfs, kfs] += 1  # the diagonal was not counted
            for kf_id, keypoint in seen.items():
                self.all_keyframes[kf_id].point_ids[keypoint] = -1
        self.alive[point_ids] = False
        self.n_observations[point_ids] = 0
        self.observation_weight[point_ids] = 0

    def replace_point(self, old: int, new: int) -> None:
        """Merge point ``old`` into ``new`` (ORB-SLAM's MapPoint::Replace): each keyframe that
        saw ``old`` sees ``new`` instead, unless it already does; counts are summed."""
        if old == new:
            return
        seen = self.observations.get(old, {})
        for kf_id, keypoint in list(seen.items()):
            self.forget(old, kf_id)
            if kf_id not in self.observations.get(new, {}):
                self.observe(new, kf_id, keypoint)
        self.visible[new] += self.visible[old]
        self.found[new] += self.found[old]
        self.cull_points(np.array([old]))
        self.replaced[old] = new

    def resolve(self, point_ids: np.ndarray) -> np.ndarray:
        """Point ids with fused points followed to the point they became (CheckReplacedInLastFrame)."""
        out = point_ids.copy()
        for _ in range(len(self.replaced)):
            has = out >= 0
            nxt = np.where(has, self.replaced[np.where(has, out, 0)], -1)
            moved = nxt >= 0
            if not moved.any():
                return out
            out[moved] = nxt[moved]
        return out

    def resolve_one(self, point_id: int) -> int:
        """``resolve`` of one point id, in Python ints: ``_fuse`` asks once a match."""
        replaced = self.replaced
        for _ in range(len(replaced)):
            if point_id < 0:
                return point_id
            following = int(replaced[point_id])
            if following < 0:
                return point_id
            point_id = following
        return point_id

    def observation_table(self, point_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every observation of ``point_ids``: (index into point_ids, keyframe id, keypoint)."""
        get = self.observations.get
        seen = [get(point, _NONE) for point in point_ids.tolist()]
        counts = np.fromiter(map(len, seen), int, len(seen))
        total = int(counts.sum())
        index = np.repeat(np.arange(len(seen)), counts)
        kfs = np.fromiter(chain.from_iterable(seen), int, total)
        kps = np.fromiter(chain.from_iterable(map(dict.values, seen)), int, total)
        return index, kfs, kps

    def keypoint_values(self, name: str, kfs: np.ndarray, kps: np.ndarray) -> np.ndarray:
        """A feature array (``octaves``, ``descriptors``, ...) at keypoints ``kps`` of keyframes ``kfs``."""
        if not len(kfs):
            return np.zeros(0)
        table = self._keypoint_tables.get(name)
        if table is None:
            table = self._keypoint_tables[name] = _KeypointTable.of(name, self.all_keyframes[0])
        table.extend(self.all_keyframes)
        return table.values[table.starts[kfs] + kps]

    def update_points(
        self, point_ids: np.ndarray, scale_factor: float, n_levels: int, descriptors: bool = True
    ) -> None:
        """ORB-SLAM's UpdateNormalAndDepth (and, with ``descriptors``, ComputeDistinctiveDescriptors)
        for ``point_ids``: the normal is the mean direction from the observers; the distances
        come from the reference observer (the keyframe that made the point while it sees it,
        else the oldest): its distance times scale^octave, and that over scale^(levels - 1);
        the descriptor is the observation's with the least median Hamming distance to the
        others (the lower median, as ORB-SLAM sorts and takes element (n - 1) / 2)."""
        point_ids = np.unique(point_ids[point_ids >= 0])
        point_ids = point_ids[self.alive[point_ids]]
        index, kfs, kps = self.observation_table(point_ids)
        if not len(index):
            return
        centers = np.array([kf.center for kf in self.all_keyframes])[kfs]
        rays = self.positions[point_ids][index] - centers
        lengths = np.linalg.norm(rays, axis=1)
        units = rays / np.maximum(lengths, 1e-12)[:, None]
        normal = np.stack(  # bincount adds in np.add.at's order, 3x sooner
            [np.bincount(index, weights=units[:, c], minlength=len(point_ids)) for c in range(3)], axis=1
        )
        normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-12)[:, None]
        has = np.bincount(index, minlength=len(point_ids)) > 0
        self.normals[point_ids[has]] = normal[has]
        not_maker = kfs != self.first_keyframe[point_ids][index]
        order = np.lexsort((kfs, not_maker, index))
        first = order[np.r_[True, np.diff(index[order]) != 0]]
        octaves = self.keypoint_values("octaves", kfs[first], kps[first])
        ref = point_ids[index[first]]
        self.max_distance[ref] = lengths[first] * scale_factor ** octaves.astype(float)
        self.min_distance[ref] = self.max_distance[ref] / scale_factor ** (n_levels - 1)
        if not descriptors:
            return
        order = np.lexsort((kfs, index))
        values = self.keypoint_values("descriptors", kfs[order], kps[order])
        counts = np.bincount(index, minlength=len(point_ids))
        starts = np.r_[0, np.cumsum(counts)[:-1]]
        if kernels.compiled():
            from depotbench.slam.kernels import matching

            best = matching.distinctive(values, starts, counts)
        else:
            best = distinctive(values, starts, counts)
        many = counts >= 2
        self.descriptors[point_ids[many]] = values[starts[many] + best[many]]

    def copy(self) -> Map:
        """An independent copy (features are shared: nothing changes them)."""
        arrays = {name: getattr(self, name).copy() for name in _POINT_ARRAYS}
        keyframes = [
            replace(kf, world_from_camera=kf.world_from_camera.copy(), point_ids=kf.point_ids.copy())
            for kf in self.all_keyframes
        ]
        observations = {point: dict(seen) for point, seen in self.observations.items()}
        return Map(
            **arrays,
            all_keyframes=keyframes,
            observations=observations,
            covisibility=self.covisibility.copy(),
            _culled=self._culled.copy(),
        )

    def cull(self, current_keyframe_id: int, recent_keyframes: int) -> int:
        """ORB-SLAM's MapPointCulling: while a point is recent (its keyframe is at most
        ``recent_keyframes`` old), drop it when found where predicted in under a quarter of
        the frames that should see it, or when two keyframes later at most one keyframe
        with depth (observation weight <= 3) sees it. Older points are never culled here."""
        age = current_keyframe_id - self.first_keyframe
        candidates = np.flatnonzero(self.alive & (age <= recent_keyframes))
        ratio = self.found[candidates] / np.maximum(self.visible[candidates], 1)
        old = age[candidates] >= 2
        bad = (ratio < 0.25) | (old & (self.observation_weight[candidates] <= 3))
        removed = candidates[bad]
        self.cull_points(removed)
        return len(removed)


def distinctive(values: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """ORB-SLAM's ComputeDistinctiveDescriptors for points whose descriptors are
    ``values[starts[p]:starts[p] + counts[p]]``: per point, the index within its own of the
    descriptor with the least median Hamming distance to the others (the lower median; the
    first on a tie), -1 for a point seen fewer than twice. Points are grouped by their
    number of observations, one array operation per group."""
    best = np.full(len(counts), -1)
    for n in np.unique(counts[counts >= 2]):
        which = np.flatnonzero(counts == n)
        group = values[starts[which][:, None] + np.arange(n)]  # (points, n, 32)
        median = np.sort(_pairwise(group), axis=2)[:, :, (n - 1) // 2]
        best[which] = np.argmin(median, axis=1)
    return best


def _pairwise(group: np.ndarray) -> np.ndarray:
    """(points, n, n) Hamming distances within each point's n descriptors."""
    xor = np.bitwise_xor(group[:, :, None, :], group[:, None, :, :])
    return POPCOUNT[xor].sum(axis=3, dtype=np.int32)
