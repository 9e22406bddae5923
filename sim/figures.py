"""Bodies for the actors: one continuous surface per figure, cut into rigid parts.

A person is a smooth signed-distance body (pelvis, belly, chest, shoulders, neck,
head with jaw, nose and ears, tapered limbs, hands, calves, feet) in a bind pose.
It is cut into the 13 rigid parts the actor animates: each point goes to the bone
it is nearest (distances less the bone's flesh radius), the cut surfaces overlap
a little, and every joint carries a ball in both parts it links, so bending never
opens a gap. Each part is cut again by material (skin, hair, top, sleeves,
trousers, boots), clothes a little thicker than skin, and every piece is meshed
closed. Faces get eyes, brows and mouth; heads get hair, a cap or a hard hat.

Why rigid parts and not MuJoCo's blended ``skin``: a blended vertex moves with
several bones, so a pixel's motion is no longer one rigid motion (exact optical
flow and scene flow are part of the ground truth) and segmentation would report
the skin, not the body part. Rigid parts with overlapping joints keep both exact.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from depotbench.sim import actor_registry
from depotbench.sim.conventions import frame_along
from depotbench.sim.draws import pick
from depotbench.sim.kinds import QuadrupedBody
from depotbench.sim.memo import kept
from depotbench.sim.products import product
from depotbench.sim.shapes import (
    Field,
    Grid,
    Mesh,
    Shape,
    cut,
    ellipsoid,
    far_version,
    mesh_field,
    round_cone,
    segment_distance,
    smooth_union,
    union,
)

ARM_SPREAD_DEG = 14.0
"""Arms of the bind pose hang this far from the body, so they do not melt into it."""

SHOULDER_Y = 0.2
"""Half the distance between the shoulder joints, for a person of scale 1."""


@dataclass(frozen=True)
class Surface:
    """One drawn geom of a part, in the part's frame: a mesh, or a primitive
    (``shape`` and ``size`` as MuJoCo's geom, at ``pos`` with rotation ``quat``)."""

    material: str
    mesh: Mesh | None = None
    shape: str = ""
    size: tuple[float, ...] = ()
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    texcoord: np.ndarray | None = None
    """A mesh's texture coordinates (3F, 2), one per corner of each face in order: set
    where a coat is laid on along the body (``wrapped``), not projected by a cube map."""
    far: Surface | None = None
    """The same mesh piece with fewer triangles, drawn in its place when it is far from
    the camera (``depotbench.sim.render.FAR_M``); None for primitives and small pieces."""


@dataclass(frozen=True)
class Look:
    """How one person looks: body build, clothes and hair (all drawn from a seed)."""

    girth: float
    shoulders: float
    hips: float
    belly: float
    head: float
    bust: bool
    top: str
    """'tshirt', 'shirt', 'jacket', 'vest' (hi-vis over a shirt) or 'overalls' (bib over a shirt)."""
    boots: bool
    hair: str
    """'short', 'long', 'bald', 'cap' or 'hardhat'."""

    @staticmethod
    def draw(rng: np.random.Generator) -> Look:
        return Look(
            girth=float(rng.uniform(0.9, 1.2)),
            shoulders=float(rng.uniform(0.92, 1.06)),
            hips=float(rng.uniform(0.92, 1.12)),
            belly=float(rng.uniform(0.95, 1.25)),
            head=float(rng.uniform(0.95, 1.05)),
            bust=bool(rng.uniform() < 0.35),
            top=pick(rng, ("tshirt", "shirt", "jacket", "vest", "overalls"), p=(0.3, 0.2, 0.2, 0.2, 0.1)),
            boots=bool(rng.uniform() < 0.5),
            hair=pick(rng, ("short", "long", "bald", "cap", "hardhat"), p=(0.4, 0.25, 0.1, 0.1, 0.15)),
        )


@dataclass(frozen=True)
class Bone:
    part: str
    a: np.ndarray
    b: np.ndarray
    radius: float
    """Flesh radius: a point goes to the bone minimising distance less this."""
    step: float
    """Meshing resolution of this part (m)."""
    pad: float
    """How far beyond its flesh radius the part may reach (m): the meshing box."""
    box: tuple[np.ndarray, np.ndarray] | None = None
    """The meshing box (lower, upper corners), where the part's flesh does not lie along
    the bone: a curved tail fills a thin band of the box ``pad`` would give, and meshing
    costs the box's volume in cells (a cat's tail box alone is 1.75 million 3.6 mm cells)."""


def person_bind(s: float) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], dict[str, np.ndarray]]:
    """Frames of the 13 parts in the bind pose, in the pelvis frame, following the rules
    of ``Walker.pose`` (a limb's frame sits mid-segment, its z axis along the segment);
    and the joint positions."""
    fwd = np.array([1.0, 0.0, 0.0])
    joints: dict[str, np.ndarray] = {}
    frames: dict[str, tuple[np.ndarray, np.ndarray]] = {
        "pelvis": (np.zeros(3), np.eye(3)),
        "torso": (np.array([0.0, 0.0, 0.33 * s]), np.eye(3)),
        "head": (np.array([0.0, 0.0, 0.72 * s]), np.eye(3)),
    }
    spread = math.radians(ARM_SPREAD_DEG)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        shoulder = np.array([0.0, sign * SHOULDER_Y * s, 0.52 * s])
        down = np.array([0.0, sign * math.sin(spread), -math.cos(spread)])
        elbow = shoulder + 0.3 * s * down
        hand = elbow + 0.3 * s * down
        joints |= {f"shoulder_{side}": shoulder, f"elbow_{side}": elbow, f"hand_{side}": hand}
        frames[f"upper_arm_{side}"] = ((shoulder + elbow) / 2, frame_along(elbow - shoulder, fwd))
        frames[f"forearm_{side}"] = ((elbow + hand) / 2, frame_along(hand - elbow, fwd))
    for side, sign in (("l", 1.0), ("r", -1.0)):
        hip = np.array([0.0, sign * 0.1 * s, 0.0])
        knee = hip - [0.0, 0.0, 0.45 * s]
        ankle = knee - [0.0, 0.0, 0.45 * s]
        foot = ankle - [0.0, 0.0, 0.08 * s]
        joints |= {f"hip_{side}": hip, f"knee_{side}": knee, f"ankle_{side}": ankle, f"ground_{side}": foot}
        frames[f"thigh_{side}"] = ((hip + knee) / 2, frame_along(hip - knee, fwd))
        frames[f"shin_{side}"] = ((knee + ankle) / 2, frame_along(knee - ankle, fwd))
        frames[f"foot_{side}"] = (foot + np.array([0.05 * s, 0.0, 0.04 * s]), np.eye(3))
    return frames, joints


def _person_body(s: float, look: Look, joints: dict[str, np.ndarray]) -> Shape:
    """The whole body as a field in the bind pose."""
    g, sh = look.girth, look.shoulders

    def e(c: tuple[float, ...], r: tuple[float, ...], axes: np.ndarray | None = None) -> Shape:
        return ellipsoid(np.array(c) * s, np.array(r) * s, axes)

    trunk_parts = [
        e((-0.005, 0.0, 0.0), (0.105 * g, 0.165 * look.hips, 0.11)),
        e((-0.045, 0.065, -0.03), (0.08, 0.08 * look.hips, 0.09)),
        e((-0.045, -0.065, -0.03), (0.08, 0.08 * look.hips, 0.09)),
        e((0.005 + 0.03 * (look.belly - 1), 0.0, 0.18), (0.1 * g * look.belly, 0.145 * g, 0.12)),
        e((0.0, 0.0, 0.37), (0.11 * g, 0.16 * sh, 0.15)),
        e((-0.005, 0.19 * sh, 0.49), (0.06, 0.07, 0.055)),
        e((-0.005, -0.19 * sh, 0.49), (0.06, 0.07, 0.055)),
        round_cone(np.array([-0.01, 0.0, 0.5]) * s, np.array([0.0, 0.0, 0.66]) * s, 0.065 * s, 0.047 * s),
    ]
    if look.bust:
        trunk_parts += [
            e((0.07 * g, 0.06, 0.38), (0.055, 0.06, 0.055)),
            e((0.07 * g, -0.06, 0.38), (0.055, 0.06, 0.055)),
        ]
    h = look.head
    head = smooth_union(
        [
            e((-0.005, 0.0, 0.755), (0.098 * h, 0.077 * h, 0.108 * h)),
            e((0.03, 0.0, 0.685), (0.065, 0.058, 0.05)),
            round_cone(
                np.array([0.088, 0.0, 0.752]) * s, np.array([0.105, 0.0, 0.716]) * s, 0.01 * s, 0.014 * s
            ),
            e((-0.005, 0.079 * h, 0.735), (0.02, 0.012, 0.03)),
            e((-0.005, -0.079 * h, 0.735), (0.02, 0.012, 0.03)),
        ],
        0.02 * s,
    )
    limbs = []
    for side in ("l", "r"):
        shoulder, elbow, hand = joints[f"shoulder_{side}"], joints[f"elbow_{side}"], joints[f"hand_{side}"]
        along = (hand - elbow) / np.linalg.norm(hand - elbow)
        wrist = elbow + 0.25 * s * along
        across = np.cross(along, [1.0, 0.0, 0.0])
        hand_axes = np.stack([[1.0, 0.0, 0.0], across, along], axis=1)
        limbs += [
            round_cone(shoulder, elbow, 0.05 * s * g**0.5, 0.038 * s),
            round_cone(elbow, wrist, 0.037 * s, 0.027 * s),
            ellipsoid(wrist + 0.075 * s * along, np.array([0.045, 0.022, 0.085]) * s, hand_axes),
        ]
        hip, knee, ankle = joints[f"hip_{side}"], joints[f"knee_{side}"], joints[f"ankle_{side}"]
        ground = joints[f"ground_{side}"]
        heel, toe = ground + np.array([-0.03, 0.0, 0.04]) * s, ground + np.array([0.16, 0.0, 0.025]) * s
        foot = round_cone(heel, toe, 0.04 * s, 0.03 * s)
        sole = ground[2]
        limbs += [
            round_cone(hip * [1, 0.95, 1], knee, 0.085 * s * g**0.5, 0.052 * s),
            round_cone(knee, ankle, 0.05 * s, 0.033 * s),
            ellipsoid(knee + np.array([-0.025, 0.0, -0.15]) * s, np.array([0.05, 0.047, 0.12]) * s),
            cut(foot, lambda p, z=sole: z - p[:, 2]),
        ]
    body = smooth_union([smooth_union(trunk_parts, 0.05 * s), head, *limbs], 0.025 * s)
    return body


def _person_bones(s: float, joints: dict[str, np.ndarray]) -> list[Bone]:
    bones = [
        Bone(
            "pelvis",
            np.array([0.0, -0.1, -0.02]) * s,
            np.array([0.0, 0.1, -0.02]) * s,
            0.11 * s,
            0.024 * s,
            0.06 * s,
        ),
        Bone(
            "torso",
            np.array([0.0, 0.0, 0.14]) * s,
            np.array([0.0, 0.0, 0.5]) * s,
            0.14 * s,
            0.024 * s,
            0.06 * s,
        ),
        Bone(
            "head",
            np.array([0.0, 0.0, 0.6]) * s,
            np.array([0.0, 0.0, 0.78]) * s,
            0.08 * s,
            0.01 * s,
            0.06 * s,
        ),
    ]
    for side in ("l", "r"):
        j = {
            k: joints[f"{k}_{side}"] for k in ("shoulder", "elbow", "hand", "hip", "knee", "ankle", "ground")
        }
        bones += [
            Bone(f"upper_arm_{side}", j["shoulder"], j["elbow"], 0.045 * s, 0.016 * s, 0.06 * s),
            Bone(f"forearm_{side}", j["elbow"], j["hand"], 0.035 * s, 0.012 * s, 0.09 * s),
            Bone(f"thigh_{side}", j["hip"], j["knee"], 0.07 * s, 0.02 * s, 0.06 * s),
            Bone(f"shin_{side}", j["knee"], j["ankle"], 0.045 * s, 0.017 * s, 0.06 * s),
            Bone(
                f"foot_{side}",
                j["ground"] + np.array([-0.03, 0.0, 0.04]) * s,
                j["ground"] + np.array([0.15, 0.0, 0.03]) * s,
                0.035 * s,
                0.013 * s,
                0.06 * s,
            ),
        ]
    return bones


def _balls(s: float, joints: dict[str, np.ndarray]) -> dict[str, list[tuple[np.ndarray, float]]]:
    """Joint balls: each part carries a sphere at the joints it shares."""
    out: dict[str, list[tuple[np.ndarray, float]]] = {}
    for side in ("l", "r"):
        j = {k: joints[f"{k}_{side}"] for k in ("shoulder", "elbow", "hip", "knee", "ankle")}
        out[f"upper_arm_{side}"] = [(j["shoulder"], 0.045 * s), (j["elbow"], 0.034 * s)]
        out[f"forearm_{side}"] = [(j["elbow"], 0.034 * s)]
        out[f"thigh_{side}"] = [(j["hip"], 0.075 * s), (j["knee"], 0.047 * s)]
        out[f"shin_{side}"] = [(j["knee"], 0.047 * s), (j["ankle"], 0.03 * s)]
        out[f"foot_{side}"] = [(j["ankle"], 0.03 * s)]
    out["head"] = [(np.array([0.0, 0.0, 0.6]) * s, 0.048 * s)]
    return out


def _person_materials(
    s: float, look: Look, joints: dict[str, np.ndarray], part: str
) -> list[tuple[str, Field | None, float]]:
    """(material, region or None for all of the part, thickness) for one part's pieces."""
    sleeve = {"tshirt": 0.45, "shirt": 1.0, "jacket": 1.0, "vest": 1.0, "overalls": 0.45}[look.top]
    cloth = 0.012 * s if look.top == "jacket" else 0.003 * s

    def along(a: str, b: str, side: str) -> Field:
        p0, p1 = joints[f"{a}_{side}"], joints[f"{b}_{side}"]
        d = p1 - p0
        return lambda p: product(p - p0, d) / (d @ d)

    side = part[-1]
    if part == "torso":
        neck = (0.6 if look.top == "jacket" else 0.565) * s
        top = "bib" if look.top == "overalls" else "top"
        out = [("skin", lambda p: neck - p[:, 2], 0.0), (top, lambda p: p[:, 2] - neck, cloth)]
        return out
    if part == "pelvis":
        return [("legs", None, 0.004 * s)]
    if part.startswith("upper_arm"):
        if sleeve >= 1:
            return [("arms", None, cloth)]
        t = along("shoulder", "elbow", side)
        return [("arms", lambda p: t(p) - sleeve, cloth), ("skin", lambda p: sleeve - t(p), 0.0)]
    if part.startswith("forearm"):
        if sleeve < 1:
            return [("skin", None, 0.0)]
        t = along("elbow", "hand", side)
        cuff = 0.78
        return [("arms", lambda p: t(p) - cuff, cloth), ("skin", lambda p: cuff - t(p), 0.0)]
    if part.startswith("thigh"):
        return [("legs", None, 0.004 * s)]
    if part.startswith("shin"):
        if not look.boots:
            return [("legs", None, 0.004 * s)]
        t = along("knee", "ankle", side)
        return [("legs", lambda p: t(p) - 0.55, 0.004 * s), ("feet", lambda p: 0.55 - t(p), 0.01 * s)]
    if part.startswith("foot"):
        ground = joints[f"ground_{side}"][2]
        return [("feet", lambda p: ground - p[:, 2], 0.008 * s)]  # soles rest on the floor
    return [("skin", None, 0.0)]


def _hair_field(s: float, look: Look) -> Shape | None:
    h = look.head
    if look.hair == "bald":
        return None
    if look.hair in ("cap", "hardhat"):
        grow = 0.012 if look.hair == "cap" else 0.03
        dome = ellipsoid(
            np.array([-0.008, 0.0, 0.77]) * s, np.array([0.098 + grow, 0.077 + grow, 0.108 + grow]) * s * h
        )
        rim = 0.77 * s if look.hair == "hardhat" else 0.775 * s
        crown = cut(dome, lambda p: rim - p[:, 2])
        if look.hair == "cap":
            peak = ellipsoid(np.array([0.1, 0.0, 0.782]) * s, np.array([0.07, 0.075, 0.008]) * s)
        else:
            peak = ellipsoid(np.array([0.0, 0.0, 0.775]) * s, np.array([0.15, 0.125, 0.01]) * s * h)
        return union([crown, peak])
    grow = 0.012 if look.hair == "short" else 0.02
    cap = ellipsoid(
        np.array([-0.012, 0.0, 0.762]) * s, np.array([0.1 + grow, 0.08 + grow, 0.11 + grow]) * s * h
    )
    fields: list[Shape] = [cap]
    if look.hair == "long":
        fields.append(ellipsoid(np.array([-0.06, 0.0, 0.66]) * s, np.array([0.055, 0.085, 0.11]) * s))

    def region(p: np.ndarray) -> np.ndarray:
        face = np.minimum(p[:, 0] - 0.04 * s, 0.812 * s - p[:, 2])
        low = (0.655 if look.hair == "short" else 0.56) * s + 0.9 * np.maximum(p[:, 0] + 0.03 * s, 0.0)
        return np.maximum(face, low - p[:, 2])

    return cut(union(fields), region)


def _face(s: float, head_origin: np.ndarray) -> list[Surface]:
    """Eyes, brows and mouth as small primitives on the head (in the head frame)."""
    o = head_origin

    def at(x: float, y: float, z: float) -> tuple[float, float, float]:
        return tuple(float(v) for v in np.array([x, y, z]) * s - o)

    across = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)  # a capsule's axis along y
    out = []
    for sign in (1.0, -1.0):
        out.append(
            Surface(
                "eye",
                shape="ellipsoid",
                size=(0.006 * s, 0.012 * s, 0.007 * s),
                pos=at(0.083, sign * 0.033, 0.764),
            )
        )
        out.append(
            Surface(
                "hair",
                shape="capsule",
                size=(0.0045 * s, 0.014 * s),
                pos=at(0.088, sign * 0.034, 0.785),
                quat=across,
            )
        )
    out.append(
        Surface("lips", shape="capsule", size=(0.0055 * s, 0.018 * s), pos=at(0.088, 0.0, 0.693), quat=across)
    )
    return out


Pieces = Callable[[str], list[tuple[str, Field | None, float]]]
"""For a part: (material, region or None for all of it, thickness) of each piece."""


def carve(
    body: Shape,
    bones: list[Bone],
    balls: dict[str, list[tuple[np.ndarray, float]]],
    frames: dict[str, tuple[np.ndarray, np.ndarray]],
    pieces: Pieces,
    overlap: float,
) -> dict[str, list[Surface]]:
    """Cut a bind-pose body into its parts' closed meshes, in the parts' frames.

    A point belongs to the bone nearest it (distance less the bone's flesh radius),
    give or take ``overlap``, or to a joint ball of the part; each piece is that, cut
    by its region and grown by its thickness (clothes over skin)."""
    out: dict[str, list[Surface]] = {}
    for bone in bones:
        lower = np.minimum(bone.a, bone.b) - bone.radius - bone.pad
        upper = np.maximum(bone.a, bone.b) + bone.radius + bone.pad
        if bone.box is not None:
            lower, upper = np.maximum(lower, bone.box[0]), np.minimum(upper, bone.box[1])
        others = [b for b in bones if b is not bone and _within(b, lower, upper, 4 * bone.pad + bone.radius)]
        grid = Grid.around(lower, upper, bone.step)
        p = grid.points
        inside = body(p)
        mine = segment_distance(bone.a, bone.b, p) - bone.radius
        if others:
            mine = mine - np.min([segment_distance(b.a, b.b, p) - b.radius for b in others], axis=0) - overlap
        surfaces: list[Surface] = []
        for material, region, thickness in pieces(bone.part):
            d = np.maximum(inside - thickness, mine)
            for centre, radius in balls.get(bone.part, []):
                d = np.minimum(d, np.linalg.norm(p - centre, axis=1) - radius - thickness)
            if region is not None:
                d = np.maximum(d, region(p))
            mesh = grid.mesh(d)
            if mesh is not None:
                surfaces.append(_piece(material, mesh, frames[bone.part]))
        out[bone.part] = surfaces
    return out


def _within(bone: Bone, lower: np.ndarray, upper: np.ndarray, reach: float) -> bool:
    return bool(
        np.all(np.minimum(bone.a, bone.b) - reach <= upper)
        and np.all(lower <= np.maximum(bone.a, bone.b) + reach)
    )


@kept("person meshes", 64)
def person_surfaces(s: float, look: Look) -> dict[str, tuple[Surface, ...]]:
    """Every part's drawn surfaces, in the part's frame, for a person of scale ``s``."""
    frames, joints = person_bind(s)
    body = _person_body(s, look, joints)
    out = carve(
        body,
        _person_bones(s, joints),
        _balls(s, joints),
        frames,
        lambda part: _person_materials(s, look, joints, part),
        overlap=0.012 * s,
    )
    origin, rotation = frames["head"]
    hair = _hair_field(s, look)
    if hair is not None:
        mesh = mesh_field(hair, hair.lower, hair.upper, 0.011 * s)
        if mesh is not None:
            role = "hat" if look.hair in ("cap", "hardhat") else "hair"
            out["head"].append(_piece(role, mesh, (origin, rotation)))
    out["head"] += _face(s, origin)
    return {part: tuple(surfaces) for part, surfaces in out.items()}


def _piece(material: str, mesh: Mesh, frame: tuple[np.ndarray, np.ndarray]) -> Surface:
    """A mesh piece (bind pose) in its part's ``frame``, with its far version."""
    far = far_version(mesh)
    return Surface(
        material,
        _to_frame(mesh, *frame),
        far=None if far is None else Surface(material, _to_frame(far, *frame)),
    )


def _to_frame(mesh: Mesh, origin: np.ndarray, rotation: np.ndarray) -> Mesh:
    """Bind-pose vertices expressed in a part's frame."""
    return Mesh(product(mesh.vertices - origin, rotation), mesh.faces)


@dataclass(frozen=True)
class AnimalLook:
    """Seeded variation of an animal's shape (its coat is a texture)."""

    ears: str
    """'floppy' or 'erect' (``QuadrupedBody.ears``, or drawn where it leaves them open)."""
    muzzle: float
    """Muzzle length factor."""
    build: float
    """Body depth factor: lean to stocky."""

    @staticmethod
    def draw(rng: np.random.Generator, kind: str) -> AnimalLook:
        """The look of an animal of ``kind`` (a quadruped's name in ``actor_registry``)."""
        body = actor_registry.get(kind).body
        assert isinstance(body, QuadrupedBody), f"{kind} is not a four-legged animal"
        ears = body.ears or pick(rng, ("floppy", "erect"))
        return AnimalLook(ears, float(rng.uniform(0.85, 1.2)), float(rng.uniform(0.9, 1.12)))


QUADRUPED_PARTS = (
    ("body", "head", "snout", "tail")
    + tuple(f"upper_leg_{k}" for k in range(4))
    + tuple(f"lower_leg_{k}" for k in range(4))
)


def wrapped(
    surface: Surface,
    a: np.ndarray,
    b: np.ndarray,
    down: np.ndarray,
    frame: tuple[np.ndarray, np.ndarray],
    width_m: float,
) -> Surface:
    """``surface`` with texture coordinates round the axis a-b (bind pose): u along it,
    ``width_m`` per texture width; v the angle round it from ``down`` (0 and 1) over
    the side to the opposite (0.5). A face across the seam under the body gets its
    corners' v unwrapped past 1 (the texture repeats), not squeezed across the texture."""
    assert surface.mesh is not None
    origin, rotation = frame
    points = product(surface.mesh.vertices, rotation.T) + origin
    axis = (b - a) / np.linalg.norm(b - a)
    rel = points - a
    along = product(rel, axis)
    radial = rel - along[:, None] * axis
    d = down - (down @ axis) * axis
    d /= np.linalg.norm(d)
    side = np.cross(axis, d)
    v = np.mod(np.arctan2(product(radial, side), product(radial, d)) / (2 * np.pi), 1.0)
    corners = np.stack([along / width_m, v], axis=1)[surface.mesh.faces]  # (F, 3, 2)
    v = corners[:, :, 1]  # a view: the unwrapping writes into corners
    across = (v.max(axis=1) - v.min(axis=1)) > 0.5
    v[across[:, None] & (v < 0.5)] += 1.0
    far = None if surface.far is None else wrapped(surface.far, a, b, down, frame, width_m)
    return dataclasses.replace(surface, texcoord=corners.reshape(-1, 2), far=far)


@kept("animal meshes", 32)
def quadruped_surfaces(
    animal: QuadrupedBody,
    frames: dict[str, tuple[np.ndarray, np.ndarray]],
    hips: list[np.ndarray],
    paw_r: float,
    tail: tuple[np.ndarray, np.ndarray],
    look: AnimalLook,
) -> dict[str, tuple[Surface, ...]]:
    """A four-legged animal of proportions ``animal`` in its bind pose (standing, straight
    legs; frames from ``Quadruped.bind``), cut into its 12 parts. Roles: coat, nose, hoof,
    eye (and iris)."""
    hx, hy, hz = animal.half_m
    leg_m = animal.leg_m
    b = look.build
    head = frames["head"][0]
    if animal.barrel:
        trunk = [ellipsoid((0.0, 0.0, 0.0), (1.0 * hx, 0.95 * hy * b, 0.95 * hz * b))]
    else:
        trunk = [
            ellipsoid((0.35 * hx, 0.0, 0.05 * hz), (0.62 * hx, 0.95 * hy * b, 1.1 * hz * b)),
            ellipsoid((-0.4 * hx, 0.0, 0.1 * hz), (0.62 * hx, 0.9 * hy * b, 0.92 * hz * b)),
        ]
    for sign in (1.0, -1.0):
        trunk += [
            ellipsoid((0.68 * hx, sign * 0.5 * hy, -0.3 * hz), (0.24 * hx, 0.42 * hy, 0.85 * hz)),
            ellipsoid((-0.68 * hx, sign * 0.48 * hy, -0.15 * hz), (0.3 * hx, 0.48 * hy, 0.9 * hz)),
        ]
    skull_r = tuple(k * hy for k in animal.skull)
    muzzle_len = animal.muzzle * hy * look.muzzle
    muzzle_r = animal.muzzle_radius * hy
    tip = head + np.array([0.45 * hy + muzzle_len, 0.0, -0.25 * hy])
    head_parts = [
        ellipsoid(head, skull_r),
        round_cone(head + np.array([0.35 * hy, 0.0, -0.12 * hy]), tip, muzzle_r * 1.2, muzzle_r),
        round_cone(head - np.array([0.7 * hy, 0.0, 0.5 * hy]), head, 0.55 * hy * b, 0.5 * hy),
    ]
    if animal.head_rise > 0:  # the neck rises from the chest to the raised head
        neck_base = np.array([0.55 * hx, 0.0, 0.35 * hz])
        head_parts.append(round_cone(neck_base, head - [0.3 * hy, 0.0, 0.25 * hy], 0.75 * hy * b, 0.62 * hy))
    ahead, above = animal.nose_at
    nose = ellipsoid(
        tip + np.array([ahead * muzzle_r, 0.0, above * muzzle_r]), np.array(animal.nose) * muzzle_r
    )
    for sign in (1.0, -1.0):
        if look.ears == "erect":
            base = head + np.array([-0.15 * skull_r[0], sign * 0.5 * skull_r[1], 0.7 * skull_r[2]])
            ear_tip = base + np.array([-0.1, sign * 0.25, 1.0]) * animal.ear_height * skull_r[2]
            ear_r = animal.ear_width * skull_r[1]
            head_parts.append(round_cone(base, ear_tip, ear_r, 0.04 * skull_r[1]))
        else:
            ear = head + np.array([-0.1 * skull_r[0], sign * 0.9 * skull_r[1], 0.0])
            axes = frame_along(np.array([animal.ear_lean, sign * 0.35, -1.0]), np.array([1.0, 0.0, 0.0]))
            head_parts.append(
                ellipsoid(ear, np.array([0.45, 0.12, 0.8]) * skull_r[1] * animal.ear_size, axes)
            )
    if animal.cheeks:  # round whisker pads under wide-set eyes: a face wider than tall
        for sign in (1.0, -1.0):
            head_parts.append(
                ellipsoid(
                    head + np.array([0.45, sign * 0.45, -0.38]) * skull_r,
                    np.array([0.45, 0.4, 0.36]) * skull_r,
                )
            )
    tail_a, tail_b = tail
    tail_r = animal.tail_radius * hy
    tail_pad, tail_box = 2 * tail_r, None
    if animal.tail_bends is not None:
        curve = _tail_curve(tail_a, tail_b, animal.tail_bends)
        limbs = [
            round_cone(
                a, b, tail_r * (1.0 - 0.35 * k / len(curve)), tail_r * (1.0 - 0.35 * (k + 1) / len(curve))
            )
            for k, (a, b) in enumerate(zip(curve[:-1], curve[1:], strict=True))
        ]
        tail_pad = float(segment_distance(tail_a, tail_b, curve).max()) + 2 * tail_r
        # The flesh lies along the curve, blended into the rump (smooth union 0.25 hy): the
        # box reaches 0.35 hy past it, as a smaller margin cuts a stocky tail's root.
        reach = 2 * tail_r + 0.35 * hy
        tail_box = (curve.min(axis=0) - reach, curve.max(axis=0) + reach)
    else:
        limbs = [round_cone(tail_a, tail_b, tail_r, 0.6 * tail_r)]
    leg_r = animal.leg_radius * hy
    bones = [
        Bone(
            "body",
            np.array([-0.75 * hx, 0.0, 0.0]),
            np.array([0.75 * hx, 0.0, 0.05 * hz]),
            0.9 * hy,
            0.09 * hx,
            0.25 * hx,
        ),
        Bone(
            "head",
            head - [0.5 * hy, 0.0, 0.2 * hy],
            head + [0.2 * hy, 0.0, 0.0],
            0.65 * hy,
            0.08 * hy,
            0.9 * hy,
        ),
        Bone("snout", head + [0.6 * hy, 0.0, -0.2 * hy], tip, muzzle_r, 0.06 * hy, 0.6 * hy),
        Bone("tail", tail_a, tail_b, tail_r, 0.3 * tail_r, tail_pad, tail_box),
    ]
    balls: dict[str, list[tuple[np.ndarray, float]]] = {}
    uppers, lowers = [], []
    for k, hip in enumerate(hips):
        knee, foot = hip - [0.0, 0.0, leg_m / 2], hip - [0.0, 0.0, leg_m]
        limbs += [
            round_cone(hip, knee, 1.15 * leg_r, 0.75 * leg_r),
            round_cone(knee, foot, 0.7 * leg_r, 0.6 * leg_r),
            cut(
                ellipsoid(foot + [0.25 * leg_r, 0.0, 0.0], np.array([1.2, 0.85, 0.9]) * leg_r),
                lambda p, z=foot[2] - paw_r: z - p[:, 2],
            ),
        ]
        uppers.append(Bone(f"upper_leg_{k}", hip, knee, 0.9 * leg_r, 0.4 * leg_r, 1.2 * leg_r))
        lowers.append(Bone(f"lower_leg_{k}", knee, foot, 0.65 * leg_r, 0.33 * leg_r, 1.6 * leg_r))
        balls[f"upper_leg_{k}"] = [(knee, 0.68 * leg_r)]
        balls[f"lower_leg_{k}"] = [(knee, 0.68 * leg_r)]
    body = smooth_union(
        [smooth_union(trunk, 0.3 * hy), smooth_union(head_parts, 0.2 * hy), nose, *limbs], 0.25 * hy
    )

    def pieces(part: str) -> list[tuple[str, Field | None, float]]:
        if part == "snout" or part == "head":
            return [("coat", lambda p: -nose(p), 0.0), ("nose", nose, 0.0)]
        if animal.hooves and part.startswith("lower_leg"):
            cutoff = hips[0][2] - 0.82 * leg_m
            return [("coat", lambda p: cutoff - p[:, 2], 0.0), ("hoof", lambda p: p[:, 2] - cutoff, 0.0)]
        return [("coat", None, 0.0)]

    out = carve(body, bones + uppers + lowers, balls, frames, pieces, overlap=0.1 * hy)
    width_m = animal.coat.laid_on_m
    if width_m is not None:  # the coat is laid on round each part, its belly side down (legs: inwards)
        downs = [np.array([0.0, 0.0, -1.0])] * len(bones)
        downs += [np.array([0.0, -np.sign(bone.a[1]), 0.0]) for bone in uppers + lowers]
        for bone, down in zip(bones + uppers + lowers, downs, strict=True):
            out[bone.part] = [
                wrapped(s, bone.a, bone.b, down, frames[bone.part], width_m) if s.material == "coat" else s
                for s in out[bone.part]
            ]
    out["head"] += _animal_eyes(head, skull_r, frames["head"], animal.eye_radius * hy, animal.iris)
    return {part: tuple(surfaces) for part, surfaces in out.items()}


def _animal_eyes(
    head: np.ndarray,
    skull_r: tuple[float, float, float],
    frame: tuple[np.ndarray, np.ndarray],
    eye_r: float,
    iris: bool,
) -> list[Surface]:
    """Two eyes: small and dark just under the coat's surface, or (``iris``) a large amber
    iris set into the skull's surface with a dark pupil, so that a cat's face shows."""
    origin, rotation = frame
    spheres = []
    for sign in (1.0, -1.0):
        if not iris:
            spheres.append(("eye", head + np.array([0.72, sign * 0.45, 0.25]) * skull_r, eye_r))
            continue
        # A unit direction in the skull's own (ellipsoid) coordinates lands on its surface.
        d = np.array([0.8, sign * 0.5, 0.3]) / np.linalg.norm([0.8, 0.5, 0.3])
        normal = d / np.asarray(skull_r)
        normal /= np.linalg.norm(normal)
        surface = head + d * np.asarray(skull_r)
        spheres += [
            ("iris", surface - 0.35 * eye_r * normal, eye_r),
            ("eye", surface + 0.3 * eye_r * normal, 0.45 * eye_r),
        ]
    return [
        Surface(
            role, shape="sphere", size=(radius,), pos=tuple(float(v) for v in product(at - origin, rotation))
        )
        for role, at, radius in spheres
    ]


def _tail_curve(
    a: np.ndarray, b: np.ndarray, bends: tuple[tuple[float, float], ...], count: int = 8
) -> np.ndarray:
    """``count + 1`` points along a tail from its root ``a`` (``b`` gives its length):
    a cubic Bezier whose other three control points are ``bends`` (``QuadrupedBody.tail_bends``)."""
    length = float(np.linalg.norm(b - a))
    back, up = np.array([-1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    controls = [a] + [a + length * (k_back * back + k_up * up) for k_back, k_up in bends]
    u = np.linspace(0.0, 1.0, count + 1)[:, None]
    weights = [(1 - u) ** 3, 3 * u * (1 - u) ** 2, 3 * u**2 * (1 - u), u**3]
    return sum(w * c for w, c in zip(weights, controls, strict=True))


BIRD_SHOULDER = (0.0, 0.05, 0.03)
"""The left wing's joint in the body frame (the right one mirrors it)."""


def bird_surfaces(frames: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, tuple[Surface, ...]]:
    """A pigeon in its bind pose (``Bird.bind``: wings spread level), cut into its 7 parts:
    plump body with breast, fanned tail, neck and small head, dark beak, wings that
    sweep back along the flanks to fold, legs and toes. Materials: fur_bird, nose (beak), metal_orange
    (legs), eye."""
    trunk = [
        ellipsoid((0.0, 0.0, 0.0), (0.11, 0.055, 0.055)),
        ellipsoid((0.045, 0.0, -0.005), (0.065, 0.056, 0.062)),  # breast
        ellipsoid((-0.14, 0.0, 0.005), (0.075, 0.036, 0.012)),  # tail
        round_cone(np.array([0.06, 0.0, 0.02]), np.array([0.115, 0.0, 0.055]), 0.034, 0.026),  # neck
        ellipsoid((0.12, 0.0, 0.06), (0.033, 0.028, 0.03)),  # head
    ]
    beak = round_cone(np.array([0.142, 0.0, 0.056]), np.array([0.172, 0.0, 0.051]), 0.0075, 0.003)
    sx, sy, sz = BIRD_SHOULDER
    wings = [ellipsoid((-0.01, sign * (sy + 0.085), sz), (0.045, 0.085, 0.008)) for sign in (1.0, -1.0)]
    legs = []
    for sign in (1.0, -1.0):
        top, ankle = np.array([0.0, sign * 0.03, -0.045]), np.array([0.0, sign * 0.03, -0.093])
        legs += [
            round_cone(top, ankle, 0.009, 0.005),
            ellipsoid(ankle + [0.012, 0.0, -0.002], (0.02, 0.008, 0.004)),  # toes
        ]
    body = smooth_union([smooth_union(trunk, 0.02), beak, *wings, *legs], 0.008)
    bones = [
        Bone("body", np.array([-0.15, 0.0, 0.0]), np.array([0.07, 0.0, 0.0]), 0.05, 0.006, 0.05),
        Bone("head", np.array([0.095, 0.0, 0.045]), np.array([0.125, 0.0, 0.06]), 0.03, 0.005, 0.02),
        Bone("beak", np.array([0.142, 0.0, 0.056]), np.array([0.175, 0.0, 0.051]), 0.006, 0.002, 0.008),
    ]
    balls: dict[str, list[tuple[np.ndarray, float]]] = {"body": []}
    for name, sign in (("wing_l", 1.0), ("wing_r", -1.0)):
        shoulder = np.array([sx, sign * sy, sz])
        bones.append(
            Bone(
                name,
                shoulder + [0.0, sign * 0.015, 0.0],
                np.array([-0.01, sign * (sy + 0.17), sz]),
                0.012,
                0.004,
                0.05,
            )
        )
        balls[name] = [(shoulder, 0.014)]
        balls["body"].append((shoulder, 0.014))
    for name, sign in (("leg_l", 1.0), ("leg_r", -1.0)):
        bones.append(
            Bone(
                name,
                np.array([0.0, sign * 0.03, -0.05]),
                np.array([0.0, sign * 0.03, -0.1]),
                0.006,
                0.003,
                0.03,
            )
        )
    materials = {"beak": "nose", "leg_l": "metal_orange", "leg_r": "metal_orange"}

    def pieces(part: str) -> list[tuple[str, Field | None, float]]:
        return [(materials.get(part, "fur_bird"), None, 0.0)]

    out = carve(body, bones, balls, frames, pieces, overlap=0.004)
    origin, rotation = frames["head"]
    for sign in (1.0, -1.0):
        at = np.array([0.138, sign * 0.02, 0.068])
        out["head"].append(
            Surface(
                "eye",
                shape="sphere",
                size=(0.005,),
                pos=tuple(float(v) for v in product(at - origin, rotation)),
            )
        )
    return {part: tuple(surfaces) for part, surfaces in out.items()}
