"""Kinematic actors: walking people, a seated person, quadrupeds and a hopping bird.

Each actor is a set of rigid parts; ``pose(t)`` gives every part's world pose.
Legs use foot placement: a stance foot is pinned to its footprint on the path
while the body passes over it, and the knee follows by two-link inverse
kinematics. So feet do not slide, whatever the speed or the path's curvature.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from depotbench.sim.conventions import frame_along
from depotbench.sim.figures import (
    BIRD_SHOULDER,
    SHOULDER_Y,
    AnimalLook,
    Look,
    Surface,
    bird_surfaces,
    person_surfaces,
    quadruped_surfaces,
)
from depotbench.sim.kinds import QuadrupedBody
from depotbench.sim.paths import OpenPath, Path, Walk
from depotbench.sim.products import product
from scipy.spatial.transform import Rotation

FD_STEP_S = 1e-3
"""Step of the central differences that give an actor's velocity."""

ARM_HANG = math.radians(5.0)
"""Arms hang this far out from the body, clear of the hips."""

SWING_TRAVEL = (0.15, 0.85)
"""Fractions of the swing phase between which a foot moves forward."""


@dataclass(frozen=True)
class Part:
    """One rigid piece: a mocap body with a primitive geom (``size`` is MuJoCo's geom
    size). With ``surfaces``, those are drawn instead and the primitive only collides."""

    name: str
    shape: str
    size: tuple[float, ...]
    material: str
    surfaces: tuple[Surface, ...] = ()


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation about a unit axis."""
    k = np.asarray(axis, dtype=float)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * product(kx, kx)


def two_link_knee(hip: np.ndarray, ankle: np.ndarray, l1: float, l2: float, bend: np.ndarray) -> np.ndarray:
    """Knee position for thigh ``l1`` and shin ``l2``, bending towards ``bend``."""
    d_vec = ankle - hip
    d = min(float(np.linalg.norm(d_vec)), l1 + l2 - 1e-6)
    u = d_vec / max(np.linalg.norm(d_vec), 1e-9)
    a = (l1**2 - l2**2 + d**2) / (2 * d)
    h = math.sqrt(max(l1**2 - a**2, 0.0))
    perp = bend - np.dot(bend, u) * u
    perp /= max(np.linalg.norm(perp), 1e-9)
    return hip + a * u + h * perp


def smoothstep(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3 - 2 * x)


@dataclass(frozen=True)
class Leg:
    hip_body: tuple[float, float, float]
    """Hip in the body frame (x forward, y left, z up), relative to the root."""
    thigh_m: float
    shin_m: float
    phase: float
    knee_forward: bool = True


class Gait:
    """Foot placement along a path: where each foot is at time t."""

    def __init__(
        self, path: Path | OpenPath, speed: float, stride: float, duty: float, lift: float, start_s: float
    ) -> None:
        self.path, self.speed, self.stride, self.duty, self.lift = path, speed, stride, duty, lift
        self.start_s = start_s

    def arc(self, t: float) -> float:
        return self.start_s + self.speed * t

    def foot(self, leg: Leg, t: float, ground_z: float) -> tuple[np.ndarray, float, bool]:
        """(position, heading, in_stance) of a foot at time t."""
        if self.speed <= 0:
            s = self.arc(t) + leg.hip_body[0]
            return self._on_path(s, leg.hip_body[1], ground_z), float(self.path.heading(s)), True
        c = (self.arc(t) - self.start_s) / self.stride - leg.phase
        k = math.floor(c)
        u = c - k

        def plant(index: int) -> float:
            return self.start_s + (index + self.duty / 2 + leg.phase) * self.stride + leg.hip_body[0]

        if u < self.duty:
            s = plant(k)
            return self._on_path(s, leg.hip_body[1], ground_z), float(self.path.heading(s)), True
        x = (u - self.duty) / (1 - self.duty)
        # The foot lifts and lands vertically; it travels only in the middle of the swing.
        w = smoothstep((x - SWING_TRAVEL[0]) / (SWING_TRAVEL[1] - SWING_TRAVEL[0]))
        s = plant(k) + w * self.stride
        position = self._on_path(s, leg.hip_body[1], ground_z)
        position[2] += self.lift * math.sin(math.pi * x) ** 2
        return position, float(self.path.heading(s)), False

    def _on_path(self, s: float, lateral: float, z: float) -> np.ndarray:
        p = self.path.point(s)
        t = self.path.tangent(s)
        normal = np.array([-t[1], t[0]])
        xy = p + lateral * normal
        return np.array([xy[0], xy[1], z])


def natural_stride(speed: float, scale: float) -> float:
    """One gait cycle's travel (two steps) at ``speed`` for a person of ``scale``."""
    return float(np.clip(1.25 * scale * math.sqrt(max(speed, 0.05) / 1.2), 0.4 * scale, 1.5 * scale))


class Actor:
    """Base: an instance made of parts, posed as a function of time. Its class and prior
    are its kind's (``actor_registry``), not the actor's: one body moves several kinds."""

    parts: list[Part]

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """World positions (P, 3) and rotations (P, 3, 3) of every part."""
        raise NotImplementedError

    def root(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        positions, rotations = self.pose(t)
        return positions[0], rotations[0]

    def part_frames(
        self, positions: np.ndarray, rotations: np.ndarray
    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each part's (position, rotation) by name, from a pose (``bind`` for meshing)."""
        return {part.name: (positions[j], rotations[j]) for j, part in enumerate(self.parts)}

    def velocity(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Linear (m/s) and angular (rad/s, world frame) velocity of the root."""
        p0, r0 = self.root(t - FD_STEP_S)
        p1, r1 = self.root(t + FD_STEP_S)
        linear = (p1 - p0) / (2 * FD_STEP_S)
        delta = product(r1, r0.T)
        angle = math.acos(min(1.0, max(-1.0, (np.trace(delta) - 1) / 2)))
        if angle < 1e-12:
            return linear, np.zeros(3)
        axis = np.array([delta[2, 1] - delta[1, 2], delta[0, 2] - delta[2, 0], delta[1, 0] - delta[0, 1]])
        axis /= 2 * math.sin(angle)
        return linear, axis * angle / (2 * FD_STEP_S)


def person_parts(
    s: float, materials: dict[str, str], thigh_half: float, shin_half: float, look: Look | None = None
) -> list[Part]:
    """The 13 parts of a person of scale ``s``, in the order ``pose`` fills them. With a
    ``look``, each part is drawn as its piece of a continuous clothed body (figures.py);
    ``materials`` maps that look's roles (skin, hair, top, ...) to material names."""
    shirt, pants, skin, shoes = (materials[k] for k in ("top", "legs", "skin", "feet"))
    parts = [
        Part("pelvis", "box", (0.1 * s, 0.16 * s, 0.08 * s), pants),
        Part("torso", "box", (0.11 * s, 0.19 * s, 0.25 * s), shirt),
        Part("head", "sphere", (0.11 * s,), skin),
        Part("upper_arm_l", "capsule", (0.05 * s, 0.14 * s), shirt),
        Part("upper_arm_r", "capsule", (0.05 * s, 0.14 * s), shirt),
        Part("forearm_l", "capsule", (0.04 * s, 0.14 * s), skin),
        Part("forearm_r", "capsule", (0.04 * s, 0.14 * s), skin),
        Part("thigh_l", "capsule", (0.07 * s, thigh_half), pants),
        Part("thigh_r", "capsule", (0.07 * s, thigh_half), pants),
        Part("shin_l", "capsule", (0.055 * s, shin_half), pants),
        Part("shin_r", "capsule", (0.055 * s, shin_half), pants),
        Part("foot_l", "box", (0.12 * s, 0.05 * s, 0.04 * s), shoes),
        Part("foot_r", "box", (0.12 * s, 0.05 * s, 0.04 * s), shoes),
    ]
    if look is None:
        return parts
    return dressed(parts, person_surfaces(s, look), materials)


def dressed(
    parts: list[Part], drawn: dict[str, tuple[Surface, ...]], materials: dict[str, str]
) -> list[Part]:
    """``parts`` drawn as ``drawn``'s surfaces, their material roles (skin, coat, ...)
    named through ``materials`` (a role not in it is a shared material's own name)."""
    return [
        dataclasses.replace(
            part,
            surfaces=tuple(
                dataclasses.replace(f, material=materials.get(f.material, f.material))
                for f in drawn[part.name]
            ),
        )
        for part in parts
    ]


class Walker(Actor):
    """A person: pelvis, torso, head, arms, legs, feet; walks a path with swinging arms."""

    def __init__(
        self,
        path: Path | OpenPath,
        speed: float,
        scale: float,
        materials: dict[str, str],
        start_s: float,
        push: bool = False,
        look: Look | None = None,
        stride: float | None = None,
    ) -> None:
        self.scale = s = scale
        self.push = push
        self.l_thigh, self.l_shin, self.ankle_h = 0.45 * s, 0.45 * s, 0.08 * s
        self.stride = stride or natural_stride(speed, s)
        duty = 0.62
        reach = 0.985 * (self.l_thigh + self.l_shin)
        offset = duty / 2 * self.stride
        self.hip_z = min(0.9 * s, math.sqrt(reach**2 - offset**2) + self.ankle_h)
        self.legs = [
            Leg((0.0, 0.1 * s, 0.0), self.l_thigh, self.l_shin, 0.0),
            Leg((0.0, -0.1 * s, 0.0), self.l_thigh, self.l_shin, 0.5),
        ]
        self.gait = Gait(path, speed, self.stride, duty, 0.1 * s, start_s)
        self.parts = person_parts(s, materials, self.l_thigh / 2, self.l_shin / 2, look)

    def root(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s = self.gait.arc(t)
        xy = self.gait.path.point(s)
        bob = 0.015 * self.scale * math.cos(4 * math.pi * (s - self.gait.start_s) / self.stride)
        return np.array([xy[0], xy[1], self.hip_z + bob]), yaw_matrix(float(self.gait.path.heading(s)))

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s = self.scale
        pelvis, body = self.root(t)
        fwd, left, up = body[:, 0], body[:, 1], body[:, 2]
        positions, rotations = [pelvis], [body]
        lean = product(axis_rotation(left, math.radians(4.0)), body)
        torso = pelvis + product(lean, np.array([0.0, 0.0, 0.33 * s]))
        positions.append(torso)
        rotations.append(lean)
        positions.append(pelvis + product(lean, np.array([0.0, 0.0, 0.72 * s])))
        rotations.append(lean)
        phase = 2 * math.pi * (self.gait.arc(t) - self.gait.start_s) / self.gait.stride
        swing_amp = math.radians(25.0) * min(1.0, self.gait.speed / 1.2)
        arms = {}
        for side, sign in (("l", 1.0), ("r", -1.0)):
            shoulder = pelvis + product(lean, np.array([0.0, sign * SHOULDER_Y * s, 0.52 * s]))
            if self.push:
                upper_angle, elbow = math.radians(30.0), math.radians(45.0)
            else:
                upper_angle = sign * swing_amp * math.sin(phase)
                elbow = math.radians(15.0) + 0.5 * max(0.0, upper_angle)
            down = product(
                product(axis_rotation(fwd, sign * ARM_HANG), axis_rotation(left, -upper_angle)), -up
            )
            elbow_pos = shoulder + 0.3 * s * down
            fore_dir = product(
                product(axis_rotation(fwd, sign * ARM_HANG), axis_rotation(left, -(upper_angle + elbow))), -up
            )
            hand = elbow_pos + 0.3 * s * fore_dir
            arms[side] = (shoulder, elbow_pos, hand)
        for side in ("l", "r"):
            a, b, _ = arms[side]
            positions.append((a + b) / 2)
            rotations.append(frame_along(b - a, fwd))
        for side in ("l", "r"):
            _, b, c = arms[side]
            positions.append((b + c) / 2)
            rotations.append(frame_along(c - b, fwd))
        legs = []
        for leg in self.legs:
            hip = pelvis + product(body, np.array(leg.hip_body))
            foot, heading, _ = self.gait.foot(leg, t, 0.0)
            ankle = foot + np.array([0.0, 0.0, self.ankle_h])
            knee = two_link_knee(hip, ankle, leg.thigh_m, leg.shin_m, fwd)
            legs.append((hip, knee, ankle, foot, heading))
        for hip, knee, _, _, _ in legs:
            positions.append((hip + knee) / 2)
            rotations.append(frame_along(hip - knee, fwd))
        for _, knee, ankle, _, _ in legs:
            positions.append((knee + ankle) / 2)
            rotations.append(frame_along(knee - ankle, fwd))
        for _, _, _, foot, heading in legs:
            r = yaw_matrix(heading)
            positions.append(foot + product(r, np.array([0.05 * s, 0.0, 0.04 * s])))
            rotations.append(r)
        return np.array(positions), np.array(rotations)


GESTURE_S = (1.0, 2.5)
"""How long one hand gesture lasts (raise, hold, lower)."""
GESTURE_GAP_S = (1.5, 6.0)
"""Pause between one hand's gestures: TUM's sitting people 'talk to each other and
gesture a little', so each hand rises every few seconds, for as long as the sequence."""
GESTURE_HORIZON_S = 600.0
"""Gestures are drawn for this long and then repeat (a sequence's 36,000 frames at 60 fps)."""


def _gestures(rng: np.random.Generator) -> np.ndarray:
    """(start, end) of one hand's gestures over ``GESTURE_HORIZON_S``."""
    events, t = [], float(rng.uniform(0.0, GESTURE_GAP_S[1]))
    while t < GESTURE_HORIZON_S:
        span = float(rng.uniform(*GESTURE_S))
        events.append((t, t + span))
        t += span + float(rng.uniform(*GESTURE_GAP_S))
    return np.array(events)


class SittingPerson(Actor):
    """A person seated at the desk, talking: torso sway and lean, head turns, hands that
    type and now and then rise to gesture."""

    def __init__(
        self,
        seat: tuple[float, float, float],
        scale: float,
        materials: dict[str, str],
        rng: np.random.Generator,
        look: Look | None = None,
    ) -> None:
        self.scale = s = scale
        self.seat = seat
        self.phases = rng.uniform(0, 2 * math.pi, 6)
        self.rates = rng.uniform(0.6, 1.4, 6)
        self.gestures = (_gestures(rng), _gestures(rng))
        self.parts = person_parts(s, materials, 0.21 * s, 0.2 * s, look)

    def gesture(self, hand: int, t: float) -> float:
        """How far hand 0 (left) or 1 (right) is raised in a gesture at t: 0 resting, 1 up
        (a third of the gesture's time to rise, a third held, a third to come down)."""
        events = self.gestures[hand]
        t %= GESTURE_HORIZON_S
        k = int(np.searchsorted(events[:, 0], t, side="right")) - 1
        if k < 0 or t >= events[k, 1]:
            return 0.0
        t0, t1 = events[k]
        x = 3 * (t - t0) / (t1 - t0)
        return smoothstep(x) if x < 1.5 else smoothstep(3 - x)

    def _wave(self, k: int, t: float, amplitude: float) -> float:
        return amplitude * math.sin(self.rates[k] * t + self.phases[k])

    def root(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        x, y, yaw = self.seat
        return np.array([x, y, 0.56 * self.scale]), yaw_matrix(math.radians(yaw))

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s = self.scale
        pelvis, body = self.root(t)
        fwd, left, up = body[:, 0], body[:, 1], body[:, 2]
        raised = max(self.gesture(0, t), self.gesture(1, t))
        sway = product(
            product(
                axis_rotation(left, math.radians(6.0 + 2.0 * raised) + self._wave(0, t, math.radians(4.0))),
                axis_rotation(fwd, self._wave(1, t, math.radians(3.0))),
            ),
            body,
        )
        positions = [pelvis, pelvis + product(sway, np.array([0.0, 0.0, 0.33 * s]))]
        head_turn = product(axis_rotation(sway[:, 2], self._wave(2, 0.7 * t, math.radians(30.0))), sway)
        positions.append(pelvis + product(sway, np.array([0.0, 0.0, 0.72 * s])))
        rotations = [body, sway, head_turn]
        uppers, fores = [], []
        for hand, (k, sign) in enumerate(((3, 1.0), (4, -1.0))):
            shoulder = pelvis + product(sway, np.array([0.0, sign * SHOULDER_Y * s, 0.52 * s]))
            # A gesture lifts the upper arm 25 degrees and the forearm 45: the hand rises
            # from the desk to chest height (0.3 m higher), and never dips below it.
            g = self.gesture(hand, t)
            lift = math.radians(35.0 + 25.0 * g) + self._wave(k, 2.5 * t, math.radians(8.0))
            down = product(axis_rotation(left, -lift), -sway[:, 2])
            elbow = shoulder + 0.3 * s * down
            fore = product(axis_rotation(left, -(lift + math.radians(55.0 + 20.0 * g))), -sway[:, 2])
            hand = elbow + 0.3 * s * fore
            uppers.append(((shoulder + elbow) / 2, frame_along(elbow - shoulder, fwd)))
            fores.append(((elbow + hand) / 2, frame_along(hand - elbow, fwd)))
        for p, r in uppers + fores:
            positions.append(p)
            rotations.append(r)
        thighs, shins, feet = [], [], []
        for sign in (1.0, -1.0):
            hip = pelvis + product(body, np.array([0.0, sign * 0.1 * s, -0.02 * s]))
            knee = hip + fwd * 0.42 * s
            ankle = np.array([knee[0], knee[1], 0.08 * s]) + fwd * 0.05 * s
            thighs.append(((hip + knee) / 2, frame_along(knee - hip, up)))
            shins.append(((knee + ankle) / 2, frame_along(knee - ankle, fwd)))
            feet.append((np.array([ankle[0], ankle[1], 0.04 * s]) + fwd * 0.05 * s, body))
        for p, r in thighs + shins + feet:
            positions.append(p)
            rotations.append(r)
        return np.array(positions), np.array(rotations)


SIT_TRANSITION_S = 1.2
"""Sitting down or standing up: about a second for an unhurried adult (sit-to-stand
takes 1.0-1.5 s in gait labs)."""
WALK_RAMP_S = 0.6
"""Starting off from standing, or coming to a stop: about one step's time."""
DOUBLE_STANCE = (0.06, 0.56)
"""Gait cycles (mod 1) at which both feet of ``Walker``'s legs are planted (phases 0 and
0.5, duty 0.62): a stretch of walking is made to end on one, so the person stops
standing on both feet."""


def _ramped_arc(t: float, length: float, speed: float, ramp_in: float, ramp_out: float) -> float:
    """Distance walked at t along a stretch of ``length``: up to ``speed`` over
    ``ramp_in`` s and down to rest over ``ramp_out`` s (smoothstep velocities, whose
    integral x^3 - x^4/2 covers half a ramp's time at full speed)."""
    cruise = (length - speed * (ramp_in + ramp_out) / 2) / speed
    end = ramp_in + cruise + ramp_out
    t = min(max(t, 0.0), end)
    if t < ramp_in:
        x = t / ramp_in
        return speed * ramp_in * (x**3 - x**4 / 2)
    if t > ramp_in + cruise and ramp_out > 0:
        x = (end - t) / ramp_out
        return length - speed * ramp_out * (x**3 - x**4 / 2)
    return speed * ramp_in / 2 + speed * (t - ramp_in)


def _blend(
    a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], w: float
) -> tuple[np.ndarray, np.ndarray]:
    """Every part from pose ``a`` towards pose ``b`` by ``w``: positions along a line,
    rotations along the shortest arc (slerp)."""
    ra = Rotation.from_matrix(a[1].reshape(-1, 3, 3))
    rb = Rotation.from_matrix(b[1].reshape(-1, 3, 3))
    rotations = (ra * Rotation.from_rotvec(w * (ra.inv() * rb).as_rotvec())).as_matrix()
    return a[0] + w * (b[0] - a[0]), rotations.reshape(a[1].shape)


@dataclass(frozen=True)
class _Stretch:
    """One segment of a TUM walker's time line, from ``t0`` to ``t1``."""

    t0: float
    t1: float
    what: str
    """'walk', 'sit down', 'sit' or 'stand up'."""
    walker: Walker | None = None
    length: float = 0.0
    ramps: tuple[float, float] = (0.0, 0.0)


class TumWalker(Actor):
    """A person who walks as TUM fr3's walkers do (``path: tum_walk``): errands across the
    view near the desk, out of the view and back, and to a seat at the desk to sit a few
    seconds and stand up again (``paths.plan_errands``). Walking is ``Walker``'s gait on
    each stretch, seated is ``SittingPerson``'s talking and gesturing; between them the
    parts move from one pose to the other over ``SIT_TRANSITION_S``."""

    def __init__(
        self,
        walks: list[Walk],
        seat: tuple[float, float, float],
        scale: float,
        materials: dict[str, str],
        rng: np.random.Generator,
        look: Look | None = None,
    ) -> None:
        self.scale = scale
        self.speed_bound = max(w.speed_mps for w in walks)
        """No part of a stretch is walked faster than this (m/s)."""
        self.sitter = SittingPerson(seat, scale, materials, rng)
        self.stretches: list[_Stretch] = []
        t = 0.0
        for k, walk in enumerate(walks):
            path = OpenPath(walk.waypoints)
            ramps = (WALK_RAMP_S if k > 0 else 0.0, WALK_RAMP_S if walk.sit_s > 0 else 0.0)
            stride = natural_stride(walk.speed_mps, scale)
            if walk.sit_s > 0:
                # Round the stretch to end on a double stance (half a cycle at most off).
                cycles = max(0.5, round((path.length / stride - DOUBLE_STANCE[0]) * 2) / 2)
                stride = path.length / (cycles + DOUBLE_STANCE[0])
            walker = Walker(path, walk.speed_mps, scale, materials, 0.0, stride=stride)
            ramps = (
                min(ramps[0], path.length / walk.speed_mps),
                min(ramps[1], path.length / walk.speed_mps),
            )
            cruise = path.length / walk.speed_mps - (ramps[0] + ramps[1]) / 2
            self.stretches.append(_Stretch(t, t + sum(ramps) + cruise, "walk", walker, path.length, ramps))
            t = self.stretches[-1].t1
            if walk.sit_s > 0:
                for what, span in (
                    ("sit down", SIT_TRANSITION_S),
                    ("sit", walk.sit_s),
                    ("stand up", SIT_TRANSITION_S),
                ):
                    self.stretches.append(_Stretch(t, t + span, what))
                    t += span
        self._starts = [s.t0 for s in self.stretches]
        self.parts = person_parts(scale, materials, 0.225 * scale, 0.225 * scale, look)

    def stretch(self, t: float) -> tuple[int, _Stretch]:
        """The stretch the person is in at t (the first before 0, the last after the end)."""
        k = min(max(bisect.bisect_right(self._starts, t) - 1, 0), len(self.stretches) - 1)
        return k, self.stretches[k]

    def _walk_time(self, stretch: _Stretch, t: float) -> float:
        """The time at which ``stretch.walker`` (walking at constant speed) has got as far."""
        assert stretch.walker is not None
        arc = _ramped_arc(t - stretch.t0, stretch.length, stretch.walker.gait.speed, *stretch.ramps)
        return arc / stretch.walker.gait.speed

    def _at(self, t: float, root: bool) -> tuple[np.ndarray, np.ndarray]:
        k, here = self.stretch(t)
        seated = self.sitter.root(t) if root else self.sitter.pose(t)
        if here.what == "walk":
            assert here.walker is not None
            tw = self._walk_time(here, t)
            return here.walker.root(tw) if root else here.walker.pose(tw)
        if here.what == "sit":
            return seated
        u = smoothstep((t - here.t0) / (here.t1 - here.t0))
        if here.what == "sit down":
            before = self.stretches[k - 1]
            walker, tw = before.walker, self._walk_time(before, before.t1)
            assert walker is not None
            return _blend(walker.root(tw) if root else walker.pose(tw), seated, u)
        walker = self.stretches[k + 1].walker
        assert walker is not None
        return _blend(seated, walker.root(0.0) if root else walker.pose(0.0), u)

    def root(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self._at(t, root=True)

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self._at(t, root=False)

    def sitting(self, t: float) -> bool:
        """Seated, or on the way down or up."""
        return self.stretch(t)[1].what != "walk"


class Quadruped(Actor):
    """A four-legged animal (``QuadrupedBody``): body, head, snout, tail and four
    two-segment legs; walk or trot."""

    def __init__(
        self,
        body: QuadrupedBody,
        path: Path,
        speed: float,
        start_s: float,
        look: AnimalLook | None = None,
        materials: dict[str, str] | None = None,
    ) -> None:
        self.animal = b = body
        hx, hy, hz = b.half_m
        half_leg = b.leg_m / 2
        trot = speed > 0.9 * b.stride_m
        duty = 0.55 if trot else 0.7
        phases = (0.0, 0.5, 0.5, 0.0) if trot else (0.0, 0.5, 0.75, 0.25)
        corners = (
            (0.75 * hx, 0.7 * hy),
            (0.75 * hx, -0.7 * hy),
            (-0.75 * hx, 0.7 * hy),
            (-0.75 * hx, -0.7 * hy),
        )
        self.legs = [
            Leg((cx, cy, -0.5 * hz), half_leg, half_leg, ph, knee_forward=cx < 0)
            for (cx, cy), ph in zip(corners, phases, strict=True)
        ]
        self.paw_r = 0.25 * hy
        reach = 0.985 * b.leg_m
        offset = duty / 2 * b.stride_m
        self.hip_z = min(0.95 * b.leg_m, math.sqrt(reach**2 - offset**2)) + self.paw_r
        self.gait = Gait(path, speed, b.stride_m, duty, 0.25 * b.leg_m, start_s)
        # The primitives only collide (group HIDDEN_GROUP): they wear the animal's own coat.
        coat = (materials or {}).get("coat", "coat")
        self.parts = [
            Part("body", "ellipsoid", (hx, hy, hz), coat),
            Part("head", "ellipsoid", (0.45 * hy + 0.04, 0.8 * hy, 0.75 * hz), coat),
            Part("snout", "capsule", (0.35 * hy, 0.3 * hy), coat),
            Part("tail", "capsule", (0.15 * hy, b.tail_m / 2), coat),
        ]
        for k in range(4):
            self.parts.append(Part(f"upper_leg_{k}", "capsule", (0.3 * hy, half_leg / 2), coat))
        for k in range(4):
            self.parts.append(Part(f"lower_leg_{k}", "capsule", (self.paw_r, half_leg / 2), coat))
        if look is not None:
            self._dress(look, materials or {})

    def _dress(self, look: AnimalLook, materials: dict[str, str]) -> None:
        """Draw the parts as pieces of one furred body (figures.py)."""
        frames = self.part_frames(*self.bind())
        centre, rotation = frames["tail"]
        half = rotation[:, 2] * self.animal.tail_m / 2  # the tail's frame sits mid-tail, z along it
        drawn = quadruped_surfaces(
            self.animal,
            frames,
            [np.array(leg.hip_body) for leg in self.legs],
            self.paw_r,
            (centre - half, centre + half),
            look,
        )
        self.parts = dressed(self.parts, drawn, materials)

    def root(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s = self.gait.arc(t)
        xy = self.gait.path.point(s)
        bob = 0.01 * math.cos(4 * math.pi * (s - self.gait.start_s) / self.gait.stride)
        return np.array([xy[0], xy[1], self.hip_z + 0.5 * self.animal.half_m[2] + bob]), yaw_matrix(
            float(self.gait.path.heading(s))
        )

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        centre, body = self.root(t)
        feet = [self.gait.foot(leg, t, self.paw_r)[0] for leg in self.legs]
        return self.place(centre, body, feet)

    def place(
        self, centre: np.ndarray, body: np.ndarray, feet: list[np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every part's pose for the body at (centre, body) and the paws at ``feet``."""
        hx, hy, hz = self.animal.half_m
        fwd, up = body[:, 0], body[:, 2]
        head = centre + product(body, np.array([hx + 0.3 * hy, 0.0, 0.9 * hz + self.animal.head_rise * hy]))
        snout = head + fwd * (0.9 * hy)
        tail_dir = -fwd + self.animal.tail_rise * up
        tail_len = 2 * self.parts[3].size[1]
        tail = centre - fwd * hx + tail_dir / np.linalg.norm(tail_dir) * (tail_len / 2 + 0.02)
        positions = [centre, head, snout, tail]
        rotations = [body, body, frame_along(fwd, up), frame_along(tail_dir, fwd)]
        uppers, lowers = [], []
        for leg, foot in zip(self.legs, feet, strict=True):
            hip = centre + product(body, np.array(leg.hip_body))
            bend = fwd if leg.knee_forward else -fwd
            knee = two_link_knee(hip, foot, leg.thigh_m, leg.shin_m, bend)
            uppers.append(((hip + knee) / 2, frame_along(hip - knee, fwd)))
            lowers.append(((knee + foot) / 2, frame_along(knee - foot, fwd)))
        for p, r in uppers + lowers:
            positions.append(p)
            rotations.append(r)
        return np.array(positions), np.array(rotations)

    def bind(self) -> tuple[np.ndarray, np.ndarray]:
        """The parts' poses standing still with straight legs, centred at the origin."""
        feet = [np.array(leg.hip_body) - [0.0, 0.0, leg.thigh_m + leg.shin_m] for leg in self.legs]
        return self.place(np.zeros(3), np.eye(3), feet)


class Bird(Actor):
    """A pigeon: hops along its path with its wings folded and now and then makes a
    short flight, wings spread and flapping."""

    HOP_S, HOP_M, PAUSE_S = 0.3, 0.14, 0.2
    TUCK = math.radians(40.0)
    """A folded wing lies swept back along the body, its chord this far down the flank."""

    def __init__(self, path: Path, start_s: float, duration_s: float, rng: np.random.Generator) -> None:
        self.path = path
        events = []  # (t0, t1, s0, s1, height)
        t, s = 0.0, start_s
        while t < duration_s + 2.0:
            if rng.uniform() < 0.12:
                dist, dur, height = float(rng.uniform(1.5, 3.0)), float(rng.uniform(0.9, 1.4)), 0.9
            else:
                dist, dur, height = self.HOP_M, self.HOP_S, 0.05
            events.append((t, t + dur, s, s + dist, height))
            t += dur + self.PAUSE_S
            s += dist
        self.events = np.array(events)
        # The primitives collide only (the meshes of bird_surfaces are drawn).
        self.parts = [
            Part("body", "ellipsoid", (0.12, 0.06, 0.06), "fur_bird"),
            Part("head", "sphere", (0.04,), "fur_bird"),
            Part("beak", "capsule", (0.01, 0.015), "nose"),
            Part("wing_l", "box", (0.045, 0.085, 0.006), "fur_bird"),
            Part("wing_r", "box", (0.045, 0.085, 0.006), "fur_bird"),
            Part("leg_l", "capsule", (0.006, 0.02), "metal_orange"),
            Part("leg_r", "capsule", (0.006, 0.02), "metal_orange"),
        ]
        self.parts = dressed(self.parts, bird_surfaces(self.part_frames(*self.bind())), {})

    def _state(self, t: float) -> tuple[float, float, float, float]:
        """(arc position, height above standing, how far the wings are spread (0 folded,
        1 open), flap angle) at t."""
        k = int(np.searchsorted(self.events[:, 0], t, side="right") - 1)
        k = max(k, 0)
        t0, t1, s0, s1, height = self.events[k]
        if t >= t1:
            return s1, 0.0, 0.0, 0.0
        u = (t - t0) / (t1 - t0)
        w = smoothstep(u)
        if height <= 0.5:  # a hop
            return s0 + (s1 - s0) * w, height * math.sin(math.pi * u), 0.0, 0.0
        spread = smoothstep(min(u, 1.0 - u) / 0.12)  # wings open after take-off, fold to land
        flap = math.radians(50.0) * math.sin(2 * math.pi * 8.0 * (t - t0))
        return s0 + (s1 - s0) * w, height * math.sin(math.pi * w), spread, flap

    def root(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s, z, _, _ = self._state(t)
        xy = self.path.point(s)
        return np.array([xy[0], xy[1], 0.1 + z]), yaw_matrix(float(self.path.heading(s)))

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        _, _, spread, flap = self._state(t)
        centre, body = self.root(t)
        return self.place(centre, body, spread, flap)

    def bind(self) -> tuple[np.ndarray, np.ndarray]:
        """The parts' poses with the wings spread level, centred at the origin."""
        return self.place(np.zeros(3), np.eye(3), 1.0, 0.0)

    def place(
        self, centre: np.ndarray, body: np.ndarray, spread: float, flap: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every part's pose for the body at (centre, body); wings ``spread`` from folded
        (0: swept back along the flanks) to open (1: level, raised ``flap`` rad)."""
        fwd, left, up = body[:, 0], body[:, 1], body[:, 2]
        head = centre + fwd * 0.12 + up * 0.06
        positions = [centre, head, head + fwd * 0.05]
        rotations = [body, body, frame_along(fwd, up)]
        sx, sy, sz = BIRD_SHOULDER
        sweep = (1.0 - spread) * math.pi / 2
        roll = spread * flap - (1.0 - spread) * self.TUCK
        for sign in (1.0, -1.0):
            positions.append(centre + product(body, np.array([sx, sign * sy, sz])))
            rotations.append(
                product(product(axis_rotation(fwd, sign * roll), axis_rotation(up, sign * sweep)), body)
            )
        for sign in (1.0, -1.0):
            positions.append(centre + sign * 0.03 * left - up * 0.075)
            rotations.append(body)
        return np.array(positions), np.array(rotations)
