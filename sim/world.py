"""Build the MuJoCo world of a scenario through MjSpec: hall, props, actors, chairs, camera.

Actors are kinematic: each part is a mocap body whose pose is set every physics
step. Chairs are free bodies with mass and friction; they move only when an
actor's part pushes them (contact bits: actors touch chairs, nothing else).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from depotbench.core.camera import Intrinsics
from depotbench.sim import actor_registry, textures
from depotbench.sim.actors import Actor, Bird, Quadruped, SittingPerson, TumWalker, Walker
from depotbench.sim.camera_rig import CameraRig
from depotbench.sim.conventions import gl_from_cv_rotation, quat_wxyz
from depotbench.sim.draws import pick
from depotbench.sim.figures import AnimalLook, Look, Surface
from depotbench.sim.kinds import TUM_WALK, ActorKind, BirdBody, PersonBody, Place, QuadrupedBody
from depotbench.sim.layout import (
    CENTRAL_AREA,
    CHAIR_HALF_M,
    DESK_CENTRE,
    DESK_HALF,
    Layout,
    Piece,
    Rect,
    plan_layout,
)
from depotbench.sim.memo import content_key, frozen, memo
from depotbench.sim.mujoco_env import mujoco
from depotbench.sim.paths import Path, plan_errands, plan_loop
from depotbench.sim.render import FAR_SUFFIX, HIDDEN_GROUP
from depotbench.sim.spec import CLOTHING, ActorSpec, ChairSpec, ScenarioSpec

STATIC_BITS, CHAIR_BITS, ACTOR_BITS = (1, 1), (1, 3), (2, 0)
"""(contype, conaffinity): actors collide with chairs only; chairs with everything."""

CHAIR_MASS_KG = 6.0
CHAIR_FRICTION = 0.5
PHYSICS_STEP_S = 0.002


@dataclass(frozen=True)
class InstanceInfo:
    instance_id: int
    class_name: str
    prior: str
    kind: str
    """'actor', 'chair' or 'object' (never moves)."""
    index: int
    """Index into World.actors, World.chair_bodies or World.layout.objects."""


@dataclass
class World:
    spec: ScenarioSpec
    model: mujoco.MjModel
    layout: Layout
    intrinsics: Intrinsics
    rig: CameraRig
    actors: list[Actor]
    actor_mocap: list[np.ndarray]
    """Per actor, the mocap indices of its parts (in part order)."""
    chair_bodies: list[int]
    chair_qpos: list[int]
    chair_qvel: list[int]
    camera_mocap: int
    camera_id: int
    instances: list[InstanceInfo]
    body_instance: np.ndarray
    """Instance id of every body (0 = static world)."""
    substeps: int
    object_positions: list[np.ndarray] = field(default_factory=list)
    """Centre of each never-moving object (its rotation is the identity)."""

    def classes(self) -> dict[str, str]:
        return {i.class_name: i.prior for i in self.instances}


PERSON_ROLES = ("skin", "hair", "hat", "top", "bib", "arms", "legs", "feet")
"""A person's materials, one each (named role + actor index)."""

HARD_HATS: tuple[textures.Colour, ...] = ((235, 200, 30), (240, 240, 235), (235, 120, 30), (40, 90, 190))
JACKETS: tuple[textures.Colour, ...] = ((35, 45, 70), (30, 30, 32), (70, 80, 50), (150, 40, 35), (90, 90, 95))
TROUSERS: tuple[textures.Colour, ...] = (
    (40, 50, 90),
    (60, 60, 60),
    (120, 100, 70),
    (45, 55, 40),
    (25, 25, 30),
)


TEXTURES = memo("textures", 4)
"""Worlds' textures by their stream's state, clothes and looks (9.5 MB a world)."""


def _material_images(
    rng: np.random.Generator, clothing: list[tuple[str, ActorKind]], looks: list[Look | AnimalLook | None]
) -> dict[str, tuple[str, np.ndarray]]:
    """Every material's texture, kept (sim/memo.py) with where the stream ends after them."""
    key = content_key(rng.bit_generator.state, clothing, looks)
    kept = TEXTURES.get(key)
    if kept is None:
        kept = frozen(_draw_material_images(rng, clothing, looks)), rng.bit_generator.state
        TEXTURES.put(key, kept)
    images, after = kept
    rng.bit_generator.state = after
    return dict(images)


def _draw_material_images(
    rng: np.random.Generator, clothing: list[tuple[str, ActorKind]], looks: list[Look | AnimalLook | None]
) -> dict[str, tuple[str, np.ndarray]]:
    """Every material's texture: ('2d' | 'cube' | 'uv', image). Each is drawn from ``rng``
    in turn, so the list's order is part of every sequence's pixels: a material added
    goes last, or every texture after it changes."""
    mats: dict[str, tuple[str, np.ndarray]] = {
        "floor": ("2d", textures.concrete(rng)),
        "ceiling": ("2d", textures.wall(rng, 256)),
    }
    for k in range(3):
        mats[f"wall{k}"] = ("2d", textures.wall(rng))
        mats[f"wood{k}"] = ("cube", textures.wood(rng))
    for k in range(4):
        mats[f"crate{k}"] = ("cube", textures.crate(rng))
        mats[f"cardboard{k}"] = ("cube", textures.cardboard(rng))
        mats[f"sack{k}"] = ("cube", textures.sack(rng))
    mats["metal_blue"] = ("cube", textures.metal(rng, colour=(40, 70, 160)))
    mats["metal_orange"] = ("cube", textures.metal(rng, colour=(230, 120, 30)))
    mats["metal_grey"] = ("cube", textures.metal(rng, colour=(120, 120, 125)))
    mats["screen0"] = ("cube", textures.screen(rng))
    mats["screen1"] = ("cube", textures.screen(rng))
    mats["lamp"] = ("cube", np.full((16, 16, 3), 250, np.uint8))
    # No geom wears these three (each animal wears its own coat{k}); they stay drawn
    # because the textures after them in the stream would change without them.
    mats["fur_dog"] = ("cube", textures.fur(rng, (150, 105, 60), spots=True))
    mats["fur_cat"] = ("cube", textures.fur(rng, (110, 110, 105)))
    mats["fur_pig"] = ("cube", textures.fur(rng, (235, 170, 165)))
    mats["fur_bird"] = ("cube", textures.fur(rng, (120, 125, 140)))
    mats["chair"] = ("cube", textures.metal(rng, colour=(120, 120, 128)))
    mats["chair_seat"] = ("cube", textures.cloth(rng, "plain", (80, 100, 150)))
    mats["eye"] = ("cube", np.full((8, 8, 3), 28, np.uint8))
    mats["iris"] = ("cube", np.full((8, 8, 3), (185, 160, 55), np.uint8))  # a cat's amber eyes
    mats["lips"] = ("cube", textures.skin_tone(rng, (150, 80, 75), size=16))
    mats["nose"] = ("cube", textures.skin_tone(rng, (30, 25, 25), size=16))
    mats["hoof"] = ("cube", textures.skin_tone(rng, (60, 50, 45), size=16))
    for k, ((pattern, kind), look) in enumerate(zip(clothing, looks, strict=True)):
        if isinstance(look, Look):
            mats |= {f"{role}{k}": image for role, image in _person_images(rng, pattern, look).items()}
        elif isinstance(look, AnimalLook):
            # laid on along the body (figures.wrapped), or a cube map
            laid_on = isinstance(kind.body, QuadrupedBody) and kind.body.coat.laid_on_m is not None
            mats[f"coat{k}"] = ("uv" if laid_on else "cube", textures.coat(rng, kind.name))
    return mats


def _pick(rng: np.random.Generator, colours: tuple[textures.Colour, ...]) -> textures.Colour:
    return colours[int(rng.integers(len(colours)))]


def _person_images(rng: np.random.Generator, pattern: str, look: Look) -> dict[str, tuple[str, np.ndarray]]:
    """One person's textures, by role: skin, hair, hat, clothes and footwear."""
    shirt = tuple(int(c) for c in rng.integers(30, 230, 3))
    top = textures.cloth(rng, pattern, shirt)
    legs = textures.denim(rng, _pick(rng, TROUSERS))
    images = {
        "skin": textures.skin_tone(rng, _pick(rng, textures.SKIN_TONES)),
        "hair": textures.hair(rng, _pick(rng, textures.HAIR_COLOURS)),
        "hat": textures.plastic(rng, _pick(rng, HARD_HATS) if look.hair == "hardhat" else shirt),
        "top": top,
        "arms": top,
        "bib": legs,
        "legs": legs,
        "feet": textures.cloth(rng, "plain", _pick(rng, ((35, 30, 30), (85, 55, 35), (20, 20, 22)))),
    }
    if look.top == "jacket":
        images["top"] = images["arms"] = textures.cloth(rng, "plain", _pick(rng, JACKETS))
    elif look.top == "vest":
        images["top"] = textures.hivis(rng, _pick(rng, ((215, 235, 40), (250, 140, 30))))
    return {role: ("cube", image) for role, image in images.items()}


def _add_materials(spec: mujoco.MjSpec, images: dict[str, tuple[str, np.ndarray]]) -> None:
    for name, (kind, image) in images.items():
        h, w = image.shape[:2]
        if kind in ("2d", "uv"):
            tex = spec.add_texture(
                name=name, type=mujoco.mjtTexture.mjTEXTURE_2D, width=w, height=h, nchannel=3
            )
            tex.data = np.ascontiguousarray(image).tobytes()
        else:
            tex = spec.add_texture(
                name=name, type=mujoco.mjtTexture.mjTEXTURE_CUBE, width=w, height=6 * h, nchannel=3
            )
            tex.data = np.ascontiguousarray(np.tile(image, (6, 1, 1))).tobytes()
        mat = spec.add_material(name=name)
        mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = name
        mat.specular = 0.0
        mat.shininess = 0.0
        mat.reflectance = 0.0
        if kind == "2d":  # tiled over the surface; "uv": laid on by the mesh's coordinates
            mat.texuniform = True
            mat.texrepeat = [1.0, 1.0] if name == "floor" else [0.5, 0.5]
        if name == "lamp":
            mat.emission = 1.0


def _piece_geom(body: mujoco.MjsBody, piece: Piece, bits: tuple[int, int]) -> None:
    if piece.axes is not None:
        quat = quat_wxyz(np.array(piece.axes, dtype=float).T)
    else:
        quat = [
            math.cos(math.radians(piece.yaw_deg) / 2),
            0,
            0,
            math.sin(math.radians(piece.yaw_deg) / 2),
        ]
    if piece.shape == "cylinder":
        geom_type, size = (
            mujoco.mjtGeom.mjGEOM_CYLINDER,
            [piece.half_size[0], piece.half_size[2], 0],
        )
    else:
        geom_type, size = mujoco.mjtGeom.mjGEOM_BOX, list(piece.half_size)
    body.add_geom(
        type=geom_type,
        size=size,
        pos=list(piece.center),
        quat=list(quat),
        material=piece.material,
        contype=bits[0],
        conaffinity=bits[1],
    )


_SHAPES = {
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
    "ellipsoid": mujoco.mjtGeom.mjGEOM_ELLIPSOID,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
}


def _make_actor(
    spec: ActorSpec,
    k: int,
    layout: Layout,
    chairs: tuple[ChairSpec, ...],
    rng: np.random.Generator,
    duration_s: float,
    seat_index: int,
    look: Look | AnimalLook | None,
) -> Actor:
    """The actor of ``spec``: where its kind goes (``Place``) and its body's family say
    what moves it."""
    kind = actor_registry.get(spec.kind)
    materials = {m: f"{m}{k}" for m in PERSON_ROLES}
    scale = spec.scale if spec.scale is not None else float(rng.uniform(0.9, 1.08))
    bounds = (-layout.size[0] / 2, -layout.size[1] / 2, layout.size[0] / 2, layout.size[1] / 2)
    person_look = look if isinstance(look, Look) else None
    if kind.place is Place.DESK:
        if not layout.seats:
            raise ValueError(f"a {kind.name} needs a desk (layout.desk: true)")
        return SittingPerson(layout.seats[seat_index % len(layout.seats)], scale, materials, rng, person_look)
    if kind.place is Place.CHAIR:
        if not chairs:
            raise ValueError(f"a {kind.name} needs at least one chair")
        cx, cy = chairs[k % len(chairs)].position_m
        direction = np.array([1.0, 0.35]) / np.linalg.norm([1.0, 0.35])
        waypoints = np.array([[cx, cy] - 1.6 * direction, [cx, cy] + 1.4 * direction])
        path = Path(waypoints, smoothing_m=0.3)
        return Walker(path, spec.speed_mps, scale, materials, start_s=0.0, push=True, look=person_look)
    obstacles = layout.obstacles + chair_footprints(chairs)
    if spec.path == TUM_WALK:
        if not layout.seats:
            raise ValueError(f"path {TUM_WALK!r} needs a desk (layout.desk: true)")
        seat = layout.seats[seat_index % len(layout.seats)]
        (x, y), (hx, hy) = DESK_CENTRE, DESK_HALF
        walks = plan_errands(
            rng, seat, (x - hx, y - hy, x + hx, y + hy), obstacles, bounds, duration_s, spec.speed_mps
        )
        return TumWalker(walks, seat, scale, materials, rng, person_look)
    if spec.waypoints:
        waypoints = np.array(spec.waypoints, dtype=float)
    else:
        n_points = 4 if spec.path == "loop" else 7
        region = (
            CENTRAL_AREA
            if spec.path == "loop"
            else (bounds[0] + 1.5, bounds[1] + 1.2, bounds[2] - 1.5, bounds[3] - 1.5)
        )
        waypoints = plan_loop(rng, region, obstacles, bounds, n_points)
    path = Path(waypoints)
    start = float(rng.uniform(0, path.length))
    body = kind.body
    if isinstance(body, PersonBody):
        return Walker(path, spec.speed_mps, scale, materials, start, look=person_look)
    if isinstance(body, BirdBody):
        return Bird(path, start, duration_s, rng)
    assert look is None or isinstance(look, AnimalLook)
    return Quadruped(body, path, spec.speed_mps, start, look, {"coat": f"coat{k}"})


def _add_chair(spec: mujoco.MjSpec, chair: ChairSpec, k: int) -> mujoco.MjsBody:
    yaw = math.radians(chair.yaw_deg)
    body = spec.worldbody.add_body(
        name=f"chair{k}",
        pos=[*chair.position_m, 0.0],
        quat=[math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)],
    )
    body.add_freejoint()
    bits = CHAIR_BITS
    parts = [
        ((0.0, 0.0, 0.46), (0.22, 0.22, 0.03), "chair_seat"),
        ((-0.2, 0.0, 0.72), (0.02, 0.2, 0.2), "chair_seat"),
    ]
    parts += [
        ((sx * 0.19, sy * 0.19, 0.215), (0.02, 0.02, 0.215), "chair") for sx in (-1, 1) for sy in (-1, 1)
    ]
    volume = sum(8 * h[0] * h[1] * h[2] for _, h, _ in parts)
    for pos, half, material in parts:
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=list(half),
            pos=list(pos),
            material=material,
            contype=bits[0],
            conaffinity=bits[1],
            density=CHAIR_MASS_KG / volume,
            friction=[CHAIR_FRICTION, 0.005, 0.0001],
        )
    return body


def _add_surface(spec: mujoco.MjSpec, body: mujoco.MjsBody, surface: Surface, name: str) -> None:
    """A drawn, non-colliding geom: a mesh piece of a figure or a small primitive."""
    common = {"material": surface.material, "contype": 0, "conaffinity": 0, "group": 0}
    if surface.mesh is None:
        size = list(surface.size) + [0.0] * (3 - len(surface.size))
        body.add_geom(
            type=_SHAPES[surface.shape], size=size, pos=list(surface.pos), quat=list(surface.quat), **common
        )
        return
    mesh = spec.add_mesh(
        name=name,
        uservert=surface.mesh.vertices.astype(np.float32).ravel().tolist(),
        userface=surface.mesh.faces.ravel().tolist(),
        inertia=mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL,
    )
    if surface.texcoord is not None:
        mesh.usertexcoord = surface.texcoord.astype(np.float32).ravel().tolist()
        mesh.userfacetexcoord = list(range(len(surface.texcoord)))
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name, mass=0.0, name=name, **common)
    if surface.far is not None:  # in the near version's material, whatever renamed it
        far = replace(surface.far, material=surface.material)
        _add_surface(spec, body, far, name + FAR_SUFFIX)


def chair_footprints(chairs: tuple[ChairSpec, ...]) -> tuple[Rect, ...]:
    h = CHAIR_HALF_M
    return tuple((x - h, y - h, x + h, y + h) for x, y in (c.position_m for c in chairs))


def intrinsics_of(scenario: ScenarioSpec) -> Intrinsics:
    """The intrinsics of the scenario's camera, exactly as it is rendered.

    Without ``focal_y_px`` and ``principal_px`` it is a plain MuJoCo camera (square pixels,
    centre at ((W-1)/2, (H-1)/2)), derived through its ``fovy`` as every sequence before was,
    so that their bytes stay the same; with them, the given pinhole (``camera_attributes``).
    """
    if scenario.focal_y_px is None and scenario.principal_px is None:
        return Intrinsics.from_fovy(
            2 * math.degrees(math.atan((scenario.height / 2) / scenario.focal_px)),
            scenario.width,
            scenario.height,
        )
    w, h = scenario.width, scenario.height
    fy = scenario.focal_px if scenario.focal_y_px is None else scenario.focal_y_px
    cx, cy = scenario.principal_px or ((w - 1) / 2, (h - 1) / 2)
    return Intrinsics(fx=scenario.focal_px, fy=fy, cx=cx, cy=cy, width=w, height=h)


def at_size(scenario: ScenarioSpec, width: int, height: int) -> ScenarioSpec:
    """The same scenario and field of view at another image size: each focal length scales
    with its side, and the principal point with the pixels' edges (c' = (c + 0.5) s - 0.5),
    so that a shrunk TUM analog keeps fr3's off-centre axis instead of leaving the image."""
    sx, sy = width / scenario.width, height / scenario.height
    principal = None
    if scenario.principal_px is not None:
        cx, cy = scenario.principal_px
        principal = ((cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5)
    fy = None if scenario.focal_y_px is None else scenario.focal_y_px * sy
    return replace(
        scenario,
        width=width,
        height=height,
        focal_px=scenario.focal_px * sx,
        focal_y_px=fy,
        principal_px=principal,
    )


def camera_attributes(intrinsics: Intrinsics) -> dict:
    """MjSpec attributes of a camera that renders ``intrinsics`` (OpenCV convention) exactly.

    A square, centred pinhole gets ``fovy`` (what every sequence before was made with). Any
    other gets MuJoCo's intrinsic attributes, with a sensor one length unit per pixel: its
    frustum spans (W/2 -+ p) / f on either side of the axis (engine_vis_visualize.c,
    getFrustum), so ``principalpixel`` p is the image centre minus the principal point, not
    the principal point: cx = (W-1)/2 - p_x and, rows counted down, cy = (H-1)/2 - p_y.
    """
    k = intrinsics
    centre = ((k.width - 1) / 2, (k.height - 1) / 2)
    if k.fx == k.fy and (k.cx, k.cy) == centre:
        return {"fovy": k.fovy_deg()}
    return {
        "resolution": [k.width, k.height],
        "sensor_size": [float(k.width), float(k.height)],
        "focal_pixel": [k.fx, k.fy],
        "principal_pixel": [centre[0] - k.cx, centre[1] - k.cy],
    }


def build_world(scenario: ScenarioSpec) -> World:
    """Compile the scenario into a MuJoCo model; every random draw comes from its seed."""
    texture_rng, layout_rng, actor_rng, camera_rng, _, figure_rng = scenario_streams(scenario.seed)
    intrinsics = intrinsics_of(scenario)
    if scenario.layout_seed is not None:
        layout_rng = np.random.default_rng(scenario.layout_seed)
    layout = plan_layout(scenario.layout, layout_rng, keep_out=chair_footprints(scenario.chairs))
    duration = scenario.frames / scenario.fps
    kinds = [actor_registry.get(a.kind) for a in scenario.actors]
    seated = [
        kind.place is Place.DESK or a.path == TUM_WALK for a, kind in zip(scenario.actors, kinds, strict=True)
    ]
    seat_of = np.cumsum(seated) - 1
    looks: list[Look | AnimalLook | None] = [
        Look.draw(figure_rng)
        if isinstance(kind.body, PersonBody)
        else AnimalLook.draw(figure_rng, kind.name)
        if isinstance(kind.body, QuadrupedBody)
        else None
        for kind in kinds
    ]
    actors = [
        _make_actor(a, k, layout, scenario.chairs, actor_rng, duration, int(seat_of[k]), looks[k])
        for k, a in enumerate(scenario.actors)
    ]
    patterns = [a.clothing or pick(actor_rng, CLOTHING) for a in scenario.actors]
    clothing = list(zip(patterns, kinds, strict=True))

    spec = mujoco.MjSpec()
    spec.modelname = f"depot_{scenario.name}"
    spec.option.timestep = 1.0 / (scenario.fps * max(1, round(1.0 / (scenario.fps * PHYSICS_STEP_S))))
    spec.visual.global_.offwidth = scenario.width
    spec.visual.global_.offheight = scenario.height
    spec.visual.quality.offsamples = 0
    spec.visual.quality.shadowsize = 0
    # Each box face one quad (MuJoCo's default splits it 4 x 4 for per-vertex lighting) and
    # coarser spheres and capsules (eyes, brows): the rack's hundreds of boxes were a
    # quarter of a CPU render pass; the light barely changes (benchmarks/render.py).
    spec.visual.quality.numquads = 1
    spec.visual.quality.numslices = 12
    spec.visual.quality.numstacks = 8
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.0, 0.0, 0.0]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    spec.stat.extent = 10.0
    spec.stat.center = [0.0, 0.0, 1.5]
    spec.visual.map.znear = 0.005
    spec.visual.map.zfar = 6.0
    _add_materials(spec, _material_images(texture_rng, clothing, looks))

    world_body = spec.worldbody
    for piece in layout.world:
        _piece_geom(world_body, piece, STATIC_BITS)
    n_seated = sum(seated)
    for x, y, _ in layout.seats[:n_seated]:
        _piece_geom(world_body, Piece((x, y, 0.22), (0.2, 0.2, 0.22), "metal_grey"), STATIC_BITS)
    intensity = scenario.light_intensity
    # High-bay lamps throw wide beams, as LED fixtures do (90-120 degrees), so that the
    # sides of people and animals are lit, not left in ambient grey, flat as cut-outs
    # (MuJoCo's default spot, 45 degrees, lights pools on the floor): with these, YOLOX-nano
    # finds seated people in 0.93 of sightings (docs/recognition.md).
    for lx, ly, lz in layout.lights:
        world_body.add_light(
            pos=[lx, ly, lz],
            dir=[0.2 * np.sign(lx), 0.1, -1.0],
            castshadow=False,
            cutoff=75.0,
            exponent=2.0,
            diffuse=[intensity * 0.5] * 3,
            specular=[0, 0, 0],
            ambient=[0, 0, 0],
        )
    world_body.add_light(
        pos=[0, 0, layout.height],
        dir=[0.3, 0.5, -1.0],
        castshadow=False,
        diffuse=[intensity * 0.4] * 3,
        specular=[0, 0, 0],
    )
    object_bodies = []
    for k, obj in enumerate(layout.objects):
        body = world_body.add_body(name=f"object{k}_{obj.class_name}")
        for piece in obj.pieces:
            _piece_geom(body, piece, STATIC_BITS)
        object_bodies.append(body)
    actor_bodies = []
    for k, actor in enumerate(actors):
        positions, rotations = actor.pose(0.0)
        bodies = []
        for j, part in enumerate(actor.parts):
            body = world_body.add_body(
                name=f"actor{k}_{part.name}",
                mocap=True,
                pos=list(positions[j]),
                quat=list(quat_wxyz(rotations[j])),
            )
            size = list(part.size) + [0.0] * (3 - len(part.size))
            body.add_geom(
                type=_SHAPES[part.shape],
                size=size,
                material=part.material,
                contype=ACTOR_BITS[0],
                conaffinity=ACTOR_BITS[1],
                group=HIDDEN_GROUP if part.surfaces else 0,
            )
            for n, surface in enumerate(part.surfaces):
                _add_surface(spec, body, surface, f"actor{k}_{part.name}_{n}")
            bodies.append(body)
        actor_bodies.append(bodies)
    chair_bodies = [_add_chair(spec, chair, k) for k, chair in enumerate(scenario.chairs)]
    rig = CameraRig(scenario.camera, camera_rng, duration_s=scenario.frames / scenario.fps, fps=scenario.fps)
    pose0 = rig.world_from_camera(0.0)
    cam_body = world_body.add_body(
        name="camera_rig",
        mocap=True,
        pos=list(pose0[:3, 3]),
        quat=list(quat_wxyz(gl_from_cv_rotation(pose0[:3, :3]))),
    )
    cam_body.add_camera(name="camera", **camera_attributes(intrinsics))

    model = spec.compile()
    mocap_of = {int(b.id): int(model.body_mocapid[b.id]) for bodies in actor_bodies for b in bodies}
    instances: list[InstanceInfo] = []
    body_instance = np.zeros(model.nbody, dtype=np.uint16)
    next_id = 1

    def register(class_name: str, prior: str, kind: str, index: int, body_ids: list[int]) -> None:
        nonlocal next_id
        instances.append(InstanceInfo(next_id, class_name, prior, kind, index))
        body_instance[body_ids] = next_id
        next_id += 1

    for k, (obj, body) in enumerate(zip(layout.objects, object_bodies, strict=True)):
        register(obj.class_name, obj.prior, "object", k, [body.id])
    for k, (kind, bodies) in enumerate(zip(kinds, actor_bodies, strict=True)):
        register(kind.class_name, kind.prior, "actor", k, [b.id for b in bodies])
    for k, body in enumerate(chair_bodies):
        register("chair", "potential", "chair", k, [body.id])
    chair_ids = [int(b.id) for b in chair_bodies]
    joint_of = {int(model.jnt_bodyid[j]): j for j in range(model.njnt)}
    return World(
        spec=scenario,
        model=model,
        layout=layout,
        intrinsics=intrinsics,
        rig=rig,
        actors=actors,
        actor_mocap=[np.array([mocap_of[b.id] for b in bodies], dtype=int) for bodies in actor_bodies],
        chair_bodies=chair_ids,
        chair_qpos=[int(model.jnt_qposadr[joint_of[b]]) for b in chair_ids],
        chair_qvel=[int(model.jnt_dofadr[joint_of[b]]) for b in chair_ids],
        camera_mocap=int(model.body_mocapid[cam_body.id]),
        camera_id=int(model.camera("camera").id),
        instances=instances,
        body_instance=body_instance,
        substeps=max(1, round(1.0 / (scenario.fps * model.opt.timestep))),
        object_positions=[np.mean([p.center for p in obj.pieces], axis=0) for obj in layout.objects],
    )


def scenario_streams(seed: int) -> list[np.random.Generator]:
    """Independent streams: textures, layout, actors, camera, sensor, figures (in that
    order; a stream added at the end leaves the others' draws unchanged)."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(6)]
