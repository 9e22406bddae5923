"""Seeded, smooth camera motions: TUM-style hand-held moves and a ground robot.

Each rig is a function of time returning ``world_from_camera`` (4x4, optical
frame). All motions are sums of sinusoids or arc-length paths, so velocity is
continuous.

A spec that sets ``mean_speed_mps`` or ``mean_angular_speed_dps`` is calibrated: the
rig scales its deliberate motion so that the whole motion, hand-held jitter included,
sampled at the sequence's frame times, has exactly those means (TUM's per-sequence
statistics, ``depotbench.sim.motion_stats``). Without them the motions are today's,
fixed-amplitude ones.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial

import numpy as np
from depotbench.sim.conventions import look_at
from depotbench.sim.motion_stats import SPEED_WINDOW_S, WINDOW_TOLERANCE_S, window_speeds
from depotbench.sim.paths import Path
from depotbench.sim.products import product
from depotbench.sim.spec import CameraSpec
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

CALIBRATION_MIN_S = 2.0
"""A speed target is met over at least this span (and two of the motion's periods): twice
the 1 s that TUM's speeds are taken over."""
ROBOT_LOOP = np.array([[-2.6, -2.0], [2.6, -2.0], [2.6, 2.95], [-2.6, 2.95]])
ROBOT_CAMERA_HEIGHT_M = 0.45

HAND_JITTER_SPEED_MPS = 0.012
HAND_JITTER_ANGULAR_DPS = 1.388
"""The hand-held jitter's default size: a camera held still by hand moves like TUM's in
fr3/walking_static, whose motion capture measured 0.012 m/s and 1.388 deg/s mean speed
(TUM RGB-D dataset list, ``depotbench.sim.motion_stats.TUM_MOTION``)."""
JITTER_BAND_HZ = (0.05, 3.0)
"""A hand's slow drift (20 s) to its physiological tremor's low edge (3 Hz). The low edge is
below the usual 0.2 Hz of body sway because TUM's static sequences' path length is their
mean speed over 1 s times their duration (0.282 m = 0.0114 m/s x 24.83 s against 0.012 m/s):
a still hand's motion lives mostly where a 1 s window sees all of it."""
JITTER_TERMS = 5
"""Sinusoids per axis, one in each of five log-spaced bands: no visible period in 40 s."""
JITTER_FALL = 3.0
"""Position amplitude falls as f^-3 (velocity as f^-2): the slow drift carries the speed,
the tremor shakes the image without moving the camera far."""
MAX_STILL_JITTER = 10.0
"""A ``static`` camera's targets may ask for at most 10x TUM's still hand: faster is a
deliberate motion (xyz, rpy), not a camera held still."""
MAX_EXCURSION_M = 1.0
"""Cap of a calibrated xyz/rpy translation's amplitude per axis (TUM's xyz moves stay
within about +-0.5 m of their centre)."""
MAX_TURN_DEG = 45.0
"""Cap of a calibrated deliberate rotation's amplitude per axis (TUM's rpy turns stay
within about +-30 deg)."""
MAX_AZIMUTH_DEG = 90.0
"""Cap of a calibrated half sphere's azimuth amplitude: it sweeps a half sphere at most."""
MAX_ELEVATION_DEG = 80.0
"""A half sphere's camera stays below this elevation: above it, looking at the target
turns the image about its axis ever faster (at the pole, without bound)."""
TRANSLATION_WEIGHTS = np.array([1.0, 0.6, 0.8])
"""Per-axis share of a deliberate translation (camera x, y, z): mostly sideways and depth."""
ROTATION_WEIGHTS = np.array([0.6, 1.0, 0.5])
"""Per-axis share of a deliberate rotation (pitch, yaw, roll about camera x, y, z)."""
PERIOD_SPREAD = (0.8, 1.25)
"""A calibrated motion's axes run at period_s over 0.8-1.25 (the fixed-amplitude motions'
0.6-1.4 would let a seed's amplitudes, and so its excursion, differ 2.3x for one speed)."""
SCALE_TOLERANCE = 1e-12
"""How closely a scale is solved: far below any statistic's rounding (1e-12 m, 1e-12 deg)."""
PROBE = 1e-6
"""The jitter scale its rotation's speed per unit scale is measured at (small: linear)."""


class CameraRig:
    def __init__(
        self,
        spec: CameraSpec,
        rng: np.random.Generator,
        *,
        duration_s: float | None = None,
        fps: float = 30.0,
    ) -> None:
        """``duration_s`` and ``fps`` give the frame times a calibrated spec (one with a
        mean speed target) is calibrated at; other specs do not use them."""
        self.spec = spec
        self.freqs = rng.uniform(0.6, 1.4, (3, 3)) * 2 * math.pi / spec.period_s
        self.phases = rng.uniform(0, 2 * math.pi, (3, 3))
        self.jitter_freqs = rng.uniform(0.4, 1.6, (2, 3)) * 2 * math.pi
        self.jitter_phases = rng.uniform(0, 2 * math.pi, (2, 3))
        robot = spec.motion == "robot"
        # The robot drives its own loop: its spec's position and target are not used (and
        # not validated), so it gets no base pose, which they might not define.
        self.base = None if robot else look_at(np.array(spec.position_m), np.array(spec.target_m))
        self.path = Path(ROBOT_LOOP, smoothing_m=1.2) if robot else None
        self.calibrated: CalibratedMotion | None = None
        if spec.mean_speed_mps is not None or spec.mean_angular_speed_dps is not None:
            if robot:
                raise ValueError(
                    "camera.mean_speed_mps: the robot drives at speed_mps; speed targets are "
                    "for the hand-held motions"
                )
            if duration_s is None:
                raise ValueError("camera.mean_speed_mps: a speed target needs the sequence's duration")
            assert self.base is not None
            # Calibrated at the frame times; a shorter sequence moves as the start of one
            # CALIBRATION_MIN_S or two periods long at its rate (speeds are taken over 1 s,
            # and a fraction of a period cannot reach a speed its whole swing does).
            span = max(CALIBRATION_MIN_S, 2 * spec.period_s)
            frames = max(round(duration_s * fps), math.ceil(span * fps) + 1)
            self.calibrated = CalibratedMotion(spec, self.base, rng, np.arange(frames) / fps)

    def _wave(self, row: int, t: float) -> np.ndarray:
        return np.sin(self.freqs[row] * t + self.phases[row])

    def poses(self, times_s: np.ndarray) -> np.ndarray:
        """``world_from_camera`` (N, 4, 4) at many times (a calibrated motion's in one go)."""
        times = np.asarray(times_s, dtype=np.float64)
        if self.calibrated is not None:
            return self.calibrated.poses(times)
        return np.array([self.world_from_camera(float(t)) for t in times]).reshape(-1, 4, 4)

    def _jitter(self, t: float, metres: float, degrees: float) -> np.ndarray:
        pose = np.eye(4)
        pose[:3, 3] = metres * np.sin(self.jitter_freqs[0] * t + self.jitter_phases[0])
        rotvec = math.radians(degrees) * np.sin(self.jitter_freqs[1] * t + self.jitter_phases[1])
        pose[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
        return pose

    def world_from_camera(self, t: float) -> np.ndarray:
        s = self.spec
        motion = s.motion
        if motion == "robot":
            return self._robot(t)
        if self.calibrated is not None:
            return self.calibrated.poses(np.array([float(t)]))[0]
        assert self.base is not None
        if motion == "static":
            return product(self.base, self._jitter(t, 0.002, 0.2))
        if motion == "xyz":
            pose = self.base.copy()
            pose[:3, 3] += product(
                self.base[:3, :3], s.amplitude_m * np.array([1.0, 0.6, 0.8]) * self._wave(0, t)
            )
            return product(pose, self._jitter(t, 0.0, 0.3))
        if motion == "rpy":
            pose = self.base.copy()
            rotvec = math.radians(s.amplitude_deg) * np.array([0.6, 1.0, 0.5]) * self._wave(1, t)
            pose[:3, :3] = product(pose[:3, :3], Rotation.from_rotvec(rotvec).as_matrix())
            return product(pose, self._jitter(t, 0.002, 0.0))
        if motion == "halfsphere":
            target = np.array(s.target_m)
            offset = np.array(s.position_m) - target
            radius = float(np.linalg.norm(offset))
            azimuth = math.atan2(offset[1], offset[0]) + math.radians(s.amplitude_deg) * self._wave(2, t)[0]
            elevation = math.asin(offset[2] / radius) + math.radians(0.5 * s.amplitude_deg) * (
                0.5 + 0.5 * self._wave(2, t)[1]
            )
            eye = target + radius * np.array(
                [
                    math.cos(elevation) * math.cos(azimuth),
                    math.cos(elevation) * math.sin(azimuth),
                    math.sin(elevation),
                ]
            )
            return product(look_at(eye, target), self._jitter(t, 0.0, 0.3))
        raise ValueError(f"camera.motion: unknown motion {motion!r}")

    def _robot(self, t: float) -> np.ndarray:
        """A ground robot's camera: along its loop at a constant speed, looking ahead."""
        assert self.path is not None
        arc = self.spec.speed_mps * t
        xy = self.path.point(arc)
        heading = self.path.tangent(arc)
        eye = np.array([xy[0], xy[1], ROBOT_CAMERA_HEIGHT_M + 0.004 * math.sin(9.0 * t)])
        target = eye + np.array([heading[0], heading[1], -0.08])
        return look_at(eye, target)


class CalibratedMotion:
    """A hand-held motion with set mean speeds: a deliberate motion, scaled, plus jitter.

    The camera centre is ``base + R_base (move * pattern(t) + jitter(t))`` (a half sphere:
    a point on its sphere plus jitter), and its orientation ``R_look(t) R(turn * pattern'(t))
    R_jitter(t)``: a rotation about the optical centre moves no centre, so the translation
    scale ``move`` is solved first, on positions alone, and the rotation scale ``turn``
    after it. Each is solved (Brent's method) until its mean over the frames, taken as TUM
    takes it (over 1 s, ``motion_stats``), equals its target.
    The jitter is band-limited sway (``JITTER_TERMS`` sinusoids per axis in
    ``JITTER_BAND_HZ``) of ``HAND_JITTER_SPEED_MPS`` and ``HAND_JITTER_ANGULAR_DPS``; a
    ``static`` camera has no deliberate motion, so its targets set the jitter's size.
    """

    def __init__(
        self, spec: CameraSpec, base: np.ndarray, rng: np.random.Generator, times: np.ndarray
    ) -> None:
        self.spec, self.base, self.times = spec, base, times
        ends = np.searchsorted(times, times + SPEED_WINDOW_S - WINDOW_TOLERANCE_S)
        starts = np.flatnonzero(ends < len(times))
        if not len(starts):
            raise ValueError(
                f"camera.mean_speed_mps: a speed target needs a sequence longer than {SPEED_WINDOW_S:g} s "
                "(TUM's speeds are taken over 1 s)"
            )
        self._window_speeds = partial(window_speeds, times, starts=starts, ends=ends[starts])
        self._still_positions = np.zeros((len(times), 3))
        self._still_rotations = np.broadcast_to(np.eye(3), (len(times), 3, 3))
        self.freqs = rng.uniform(*PERIOD_SPREAD, (2, 3)) * 2 * math.pi / spec.period_s
        self.phases = rng.uniform(0, 2 * math.pi, (2, 3))
        # One term per band, the bands log-spaced over JITTER_BAND_HZ, so every draw has a
        # slow sway and a fast tremor; amplitudes fall as f^-JITTER_FALL.
        edges = np.geomspace(*JITTER_BAND_HZ, JITTER_TERMS + 1)
        self.jitter_freqs = rng.uniform(edges[:-1], edges[1:], (2, 3, JITTER_TERMS)) * 2 * math.pi
        self.jitter_phases = rng.uniform(0, 2 * math.pi, (2, 3, JITTER_TERMS))
        self.jitter_gains = self.jitter_freqs**-JITTER_FALL
        offset = np.array(spec.position_m) - np.array(spec.target_m)
        self.radius = float(np.linalg.norm(offset))
        self.azimuth0 = math.atan2(offset[1], offset[0])
        self.elevation0 = math.asin(offset[2] / self.radius)
        self.jitter_m = self.jitter_rad = 0.0
        self.move, self.turn = self._default_scales()
        self._calibrate()

    def _default_scales(self) -> tuple[float, float]:
        """(move, turn) of an uncalibrated axis: the spec's amplitude where the motion has one."""
        motion, spec = self.spec.motion, self.spec
        move = {"xyz": spec.amplitude_m, "halfsphere": spec.amplitude_deg}.get(motion, 0.0)
        turn = spec.amplitude_deg if motion == "rpy" else 0.0
        return move, turn

    def _calibrate(self) -> None:
        spec, still = self.spec, self.spec.motion == "static"
        unit = self._speed(self._positions(0.0, jitter_m=1.0))
        speed_target = spec.mean_speed_mps if still and spec.mean_speed_mps else HAND_JITTER_SPEED_MPS
        if still and speed_target > MAX_STILL_JITTER * HAND_JITTER_SPEED_MPS:
            raise ValueError(_still_error("mean_speed_mps", speed_target, HAND_JITTER_SPEED_MPS))
        self.jitter_m = speed_target / unit  # positions are linear in the jitter's scale
        angular_target = (
            spec.mean_angular_speed_dps if still and spec.mean_angular_speed_dps else HAND_JITTER_ANGULAR_DPS
        )
        if still and angular_target > MAX_STILL_JITTER * HAND_JITTER_ANGULAR_DPS:
            raise ValueError(_still_error("mean_angular_speed_dps", angular_target, HAND_JITTER_ANGULAR_DPS))
        # The speed per unit scale, probed small: at scale 1 the slow terms' radians wrap.
        unit_deg = self._angular_speed(self._rotations(0.0, 0.0, jitter_rad=PROBE)) / PROBE
        self.jitter_rad = _bisect(
            lambda scale: self._angular_speed(self._rotations(0.0, 0.0, jitter_rad=scale)),
            angular_target,
            4.0 * angular_target / unit_deg,
        )
        if still:
            return
        if spec.mean_speed_mps is not None:
            self.move = _solve(
                lambda move: self._speed(self._positions(move)),
                spec.mean_speed_mps,
                self._move_cap(),
                "mean_speed_mps",
                "m/s",
            )
        if spec.mean_angular_speed_dps is not None:
            self.turn = _solve(
                lambda turn: self._angular_speed(self._rotations(self.move, turn)),
                spec.mean_angular_speed_dps,
                (MAX_TURN_DEG, "deg"),
                "mean_angular_speed_dps",
                "deg/s",
            )

    def _move_cap(self) -> tuple[float, str]:
        """The largest translation scale and its unit (a half sphere's is its azimuth's)."""
        if self.spec.motion != "halfsphere":
            return MAX_EXCURSION_M, "m"
        # Elevation rises by up to half the azimuth amplitude (as the uncalibrated half sphere).
        room = 2.0 * (MAX_ELEVATION_DEG - math.degrees(self.elevation0))
        if room <= 0:
            raise ValueError(
                f"camera.position_m: a half sphere starts below {MAX_ELEVATION_DEG:g} deg elevation "
                "over its target"
            )
        return min(MAX_AZIMUTH_DEG, room), "deg of azimuth"

    def _speed(self, positions: np.ndarray) -> float:
        return self._window_speeds(positions, self._still_rotations)[0]

    def _angular_speed(self, rotations: np.ndarray) -> float:
        return self._window_speeds(self._still_positions, rotations)[1]

    def _jitter(self, row: int, t: np.ndarray) -> np.ndarray:
        """Unit-scale sway (N, 3) of row 0 (translation) or 1 (rotation vector)."""
        waves = np.sin(self.jitter_freqs[row] * t[:, None, None] + self.jitter_phases[row])
        return np.sum(self.jitter_gains[row] * waves, axis=2)

    def _wave(self, row: int, t: np.ndarray) -> np.ndarray:
        return np.sin(self.freqs[row] * t[:, None] + self.phases[row])

    def _eyes(self, move: float, t: np.ndarray) -> np.ndarray:
        """Camera centres before jitter: a half sphere's point, or the base's offset."""
        if self.spec.motion == "halfsphere":
            wave = self._wave(0, t)
            azimuth = self.azimuth0 + math.radians(move) * wave[:, 0]
            elevation = self.elevation0 + math.radians(0.5 * move) * (0.5 + 0.5 * wave[:, 1])
            direction = np.stack(
                [
                    np.cos(elevation) * np.cos(azimuth),
                    np.cos(elevation) * np.sin(azimuth),
                    np.sin(elevation),
                ],
                axis=1,
            )
            return np.array(self.spec.target_m) + self.radius * direction
        offsets = move * TRANSLATION_WEIGHTS * self._wave(0, t)
        return self.base[:3, 3] + offsets @ self.base[:3, :3].T

    def _positions(
        self, move: float, t: np.ndarray | None = None, jitter_m: float | None = None
    ) -> np.ndarray:
        t = self.times if t is None else t
        scale = self.jitter_m if jitter_m is None else jitter_m
        return self._eyes(move, t) + (scale * self._jitter(0, t)) @ self.base[:3, :3].T

    def _rotations(
        self, move: float, turn: float, t: np.ndarray | None = None, jitter_rad: float | None = None
    ) -> np.ndarray:
        t = self.times if t is None else t
        scale = self.jitter_rad if jitter_rad is None else jitter_rad
        if self.spec.motion == "halfsphere":
            look = _look_at_rotations(self._eyes(move, t), np.array(self.spec.target_m))
        else:
            look = np.broadcast_to(self.base[:3, :3], (len(t), 3, 3))
        turned = Rotation.from_rotvec(math.radians(turn) * ROTATION_WEIGHTS * self._wave(1, t))
        shaken = Rotation.from_rotvec(scale * self._jitter(1, t))
        return look @ (turned * shaken).as_matrix()

    def poses(self, t: np.ndarray) -> np.ndarray:
        """``world_from_camera`` (N, 4, 4) at times ``t``."""
        poses = np.tile(np.eye(4), (len(t), 1, 1))
        poses[:, :3, :3] = self._rotations(self.move, self.turn, t)
        poses[:, :3, 3] = self._positions(self.move, t)
        return poses


def _look_at_rotations(eyes: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``look_at``'s rotation (world +z up) for many eyes at once; no eye is straight above
    or below the target (elevation stays under ``MAX_ELEVATION_DEG``)."""
    z = target - eyes
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def _bisect(measure: Callable[[float], float], target: float, high: float) -> float:
    """The scale in [0, high] where ``measure`` (rising through ``target``) equals it
    (Brent's method: about ten evaluations where bisection takes forty)."""
    return float(brentq(lambda scale: measure(scale) - target, 0.0, high, xtol=SCALE_TOLERANCE, rtol=1e-12))


def _solve(
    measure: Callable[[float], float], target: float, cap: tuple[float, str], field: str, unit: str
) -> float:
    """``_bisect`` over [0, cap], or one line naming the field when no scale reaches the target."""
    floor, reach = measure(0.0), measure(cap[0])
    if target < floor:
        raise ValueError(
            f"camera.{field}: {target:g} {unit} is below the {floor:.3g} {unit} that the hand-held "
            "jitter alone gives"
        )
    if target > reach:
        raise ValueError(
            f"camera.{field}: {target:g} {unit} is beyond the {reach:.3g} {unit} this motion reaches "
            f"at its amplitude cap ({cap[0]:g} {cap[1]}); shorten camera.period_s"
        )
    return _bisect(measure, target, cap[0])


def _still_error(field: str, target: float, hand: float) -> str:
    return (
        f"camera.{field}: {target:g} is more than {MAX_STILL_JITTER:g}x a camera held still "
        f"({hand:g}); use a moving motion (xyz, rpy, halfsphere)"
    )
