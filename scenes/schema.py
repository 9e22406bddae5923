"""The YAML scenario spec: validated at load, unknown keys refused, errors name the field.

A scenario file describes what a user wants (counts, speed ranges, a camera
motion, a sensor); ``to_scenario`` turns it, with its seed, into the simulator's
exact ``depotbench.sim.spec.ScenarioSpec``. The choices (actor kinds, paths, camera
motions, clothing) and the defaults are the simulator's, read from its spec and its
table of actor kinds (``depotbench.sim.actor_registry``), not written here again.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import numpy as np
import yaml
from depotbench.core.errors import FileError, InputError
from depotbench.core.files import MAX_SPEC_BYTES, read_text
from depotbench.sim import actor_registry, sensor_profiles
from depotbench.sim import spec as sim_spec
from depotbench.sim.kinds import TUM_WALK
from depotbench.sim.layout import CHAIR_HALF_M, fixed_footprints, overlaps
from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    TypeAdapter,
    ValidationError,
    field_validator,
    model_validator,
)

M = TypeVar("M", bound=BaseModel)

MAX_FRAMES = 100_000
MAX_ACTORS = 40
MAX_CHAIRS = 12
MAX_IMAGE_SIDE = sim_spec.MAX_IMAGE_SIDE
SCENARIO, LAYOUT, CAMERA, SENSOR = (
    sim_spec.ScenarioSpec(),
    sim_spec.LayoutSpec(),
    sim_spec.CameraSpec(),
    sim_spec.SensorSpec(),
)
"""The simulator's defaults, which a scenario file's are."""
ACTOR_DEFAULTS = {f.name: f.default for f in dataclasses.fields(sim_spec.ActorSpec)}
MIN_CHAIR_SPACING_M = 0.9
"""Chairs closer than this overlap (each is about 0.9 m across with its legs)."""
MAX_YAML_NODES = 100_000
"""Values a scenario or suite file may expand to, aliases counted at every use."""
MAX_YAML_DEPTH = 32
MIN_VIEW_DISTANCE_M = 0.01
MIN_PATH_SPAN_M = 0.1
WALL_MARGIN_M = 0.3
"""Waypoints and chairs keep this far from the walls."""
PositiveFloat = Annotated[float, Field(gt=0)]


def _number_or_range(value: Any) -> str:
    return "range" if isinstance(value, list | tuple) else "number"


NumberOrRange = Annotated[
    Annotated[float, Tag("number")] | Annotated[tuple[float, float], Tag("range")],
    Discriminator(_number_or_range),
]
"""A value, or a [low, high] range drawn from the seed; errors name the one that was given."""


class SpecError(InputError):
    """A scenario or suite file that does not validate."""


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=False, allow_inf_nan=False)


class Image(Strict):
    width: int = Field(SCENARIO.width, ge=sim_spec.MIN_IMAGE_SIDE, le=MAX_IMAGE_SIDE)
    height: int = Field(SCENARIO.height, ge=sim_spec.MIN_IMAGE_SIDE, le=MAX_IMAGE_SIDE)


class IntrinsicsSpec(Strict):
    """Pinhole intrinsics in OpenCV's convention (pixel centres at integers), rendered exactly.

    Left out, fy is fx and (cx, cy) the image centre ((W-1)/2, (H-1)/2); TUM fr3's camera is
    ``{fx: 535.4, fy: 539.2, cx: 320.1, cy: 247.6}`` (ORB-SLAM2's TUM3.yaml).
    """

    fx: PositiveFloat = SCENARIO.focal_px
    fy: PositiveFloat | None = None
    cx: float | None = None
    cy: float | None = None

    def principal(self, width: int, height: int) -> tuple[float, float] | None:
        """(cx, cy) where either is given, the centre standing in for the other; else None."""
        if self.cx is None and self.cy is None:
            return None
        cx = (width - 1) / 2 if self.cx is None else self.cx
        return cx, (height - 1) / 2 if self.cy is None else self.cy


class Layout(Strict):
    size_m: tuple[Annotated[float, Field(ge=8, le=60)], Annotated[float, Field(ge=8, le=60)]] = (
        LAYOUT.hall_size_m
    )
    height_m: float = Field(LAYOUT.hall_height_m, ge=3.0, le=15.0)
    rack_rows: int = Field(LAYOUT.rack_rows, ge=0, le=4)
    racks_per_row: int = Field(LAYOUT.racks_per_row, ge=0, le=8)
    props: int = Field(LAYOUT.floor_props, ge=0, le=60)
    desk: bool = LAYOUT.desk
    seed: int | None = Field(None, ge=0, description="fixes the layout across a suite's variations")

    def to_spec(self) -> sim_spec.LayoutSpec:
        return sim_spec.LayoutSpec(
            hall_size_m=self.size_m,
            hall_height_m=self.height_m,
            rack_rows=self.rack_rows,
            racks_per_row=self.racks_per_row,
            floor_props=self.props,
            desk=self.desk,
        )


def _choices(values: tuple[str, ...]) -> str:
    """'a', 'b' or 'c', as pydantic words a Literal's."""
    quoted = [repr(v) for v in values]
    return quoted[0] if len(quoted) == 1 else f"{', '.join(quoted[:-1])} or {quoted[-1]}"


def _kind_enum(schema: dict[str, Any]) -> None:
    schema["enum"] = list(actor_registry.names())


class Actor(Strict):
    kind: str = Field(json_schema_extra=_kind_enum, description="an actor kind (sim/actor_registry.py)")
    """Read from the table of kinds when validated, so a kind registered later is accepted."""
    count: int = Field(1, ge=0, le=MAX_ACTORS)
    speed_mps: NumberOrRange = ACTOR_DEFAULTS["speed_mps"]
    path: Literal[sim_spec.PATH_MODES] = ACTOR_DEFAULTS["path"]  # type: ignore[valid-type]
    waypoints: list[tuple[float, float]] | None = None
    clothing: Literal[(*sim_spec.CLOTHING, "any")] = "any"  # type: ignore[valid-type]
    scale: NumberOrRange | None = None

    @field_validator("kind")
    @classmethod
    def _kind(cls, value: str) -> str:
        if value not in actor_registry.names():
            raise ValueError(f"Input should be {_choices(actor_registry.names())}")
        return value

    @field_validator("speed_mps")
    @classmethod
    def _speed(cls, value: float | tuple[float, float]) -> float | tuple[float, float]:
        low, high = (value, value) if isinstance(value, int | float) else value
        least, most = sim_spec.SPEED_RANGE_MPS
        if not (least <= low <= high <= most):
            raise ValueError(
                f"speed must lie in [{least:g}, {most:g}] m/s, as a number or a [low, high] range"
            )
        return value

    @field_validator("scale")
    @classmethod
    def _scale(cls, value: float | tuple[float, float] | None) -> float | tuple[float, float] | None:
        if value is None:
            return value
        low, high = (value, value) if isinstance(value, int | float) else value
        if not (0.3 <= low <= high <= 2.0):
            raise ValueError("scale must lie in [0.3, 2.0], as a number or a [low, high] range")
        return value

    @model_validator(mode="after")
    def _path_fits_kind(self) -> Actor:
        paths = actor_registry.get(self.kind).paths
        if self.path not in paths:
            raise ValueError(
                f"path {self.path!r} does not go with kind {self.kind!r}, which takes {_choices(paths)}"
            )
        if self.waypoints is not None and len(self.waypoints) < 2:
            raise ValueError("waypoints need at least two [x, y] points")
        return self


class Chair(Strict):
    position_m: tuple[float, float]
    yaw_deg: float = Field(0.0, ge=-360, le=360)


class Camera(Strict):
    motion: Literal[sim_spec.CAMERA_MOTIONS] = CAMERA.motion  # type: ignore[valid-type]
    position_m: tuple[float, float, float] = CAMERA.position_m
    target_m: tuple[float, float, float] = CAMERA.target_m
    amplitude_m: float = Field(CAMERA.amplitude_m, ge=0, le=3)
    amplitude_deg: float = Field(CAMERA.amplitude_deg, ge=0, le=60)
    period_s: float = Field(CAMERA.period_s, gt=0.2, le=600)
    speed_mps: float = Field(CAMERA.speed_mps, ge=0, le=5)
    mean_speed_mps: float | None = Field(CAMERA.mean_speed_mps, gt=0, le=2)
    """Calibrate the hand-held motion to this mean translational speed over the sequence
    (TUM's per-sequence figure, e.g. 0.208 for fr3/walking_xyz); unset: fixed amplitudes."""
    mean_angular_speed_dps: float | None = Field(CAMERA.mean_angular_speed_dps, gt=0, le=180)
    """Calibrate the hand-held motion to this mean angular speed in deg/s (5.49 for
    fr3/walking_xyz); unset: fixed amplitudes."""


class Lighting(Strict):
    intensity: float = Field(SCENARIO.light_intensity, gt=0, le=3)


TUM_SENSOR = sensor_profiles.TUM_ADDITIONS
"""The TUM profile's additions to ``kinect`` (sim/sensor_profiles.py gives their sources)."""


class Sensor(Strict):
    depth_noise: bool = SENSOR.depth_noise
    disparity_quantisation: bool = SENSOR.disparity_quantisation
    depth_range_m: tuple[float, float] = SENSOR.depth_range_m
    edge_dropout: float = Field(SENSOR.edge_dropout, ge=0, le=1)
    rgb_noise_sigma: float = Field(SENSOR.rgb_noise_sigma, ge=0, le=50)
    motion_blur_exposure_s: float = Field(SENSOR.motion_blur_exposure_s, ge=0, le=0.1)
    exposure_variation: float = Field(SENSOR.exposure_variation, ge=0, le=1)
    rolling_shutter_readout_s: float = Field(SENSOR.rolling_shutter_readout_s, ge=0, le=0.1)
    white_balance_drift: float = Field(SENSOR.white_balance_drift, ge=0, le=0.5)
    depth_delay_mean_s: float = Field(SENSOR.depth_delay_mean_s, ge=0, le=0.01)
    timestamp_jitter_s: float = Field(SENSOR.timestamp_jitter_s, ge=0, le=0.01)
    dropped_frame_rate: float = Field(SENSOR.dropped_frame_rate, ge=0, le=0.5)
    gt_rate_hz: float = Field(SENSOR.gt_rate_hz, ge=0, le=1000)
    gt_position_noise_m: float = Field(SENSOR.gt_position_noise_m, ge=0, le=0.05)
    gt_rotation_noise_deg: float = Field(SENSOR.gt_rotation_noise_deg, ge=0, le=5)
    gt_time_offset_s: float = Field(SENSOR.gt_time_offset_s, ge=-0.1, le=0.1)

    @field_validator("depth_range_m")
    @classmethod
    def _range(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not 0 <= value[0] < value[1] <= 13.1:
            raise ValueError("depth_range_m must be [near, far] with 0 <= near < far <= 13.1 m")
        return value

    @classmethod
    def kinect(cls) -> Sensor:
        return cls(**dataclasses.asdict(sensor_profiles.KINECT))

    @classmethod
    def tum(cls) -> Sensor:
        """A Kinect v1 recorded as TUM fr3 was: ``kinect`` plus the timing, shutter and
        ground-truth effects, each default from the source docs/scenarios.md names."""
        return cls(**dataclasses.asdict(sensor_profiles.TUM))


SENSOR_PRESETS = {"perfect": Sensor, "kinect": Sensor.kinect, "tum": Sensor.tum}
"""The sensors a scenario (``sensor: tum``) or ``depotbench generate --sensor`` names."""


def sensor_spec(preset: str) -> sim_spec.SensorSpec:
    """The simulator's sensor of a named preset."""
    return sim_spec.SensorSpec(**SENSOR_PRESETS[preset]().model_dump())


class Scenario(Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    description: str = ""
    tags: list[Annotated[str, Field(pattern=r"^[a-z0-9-]{1,32}$")]] = []
    seed: int = Field(SCENARIO.seed, ge=0, le=2**32 - 1)
    duration_s: float | None = Field(None, gt=0, le=3600)
    frames: int | None = Field(None, ge=1, le=MAX_FRAMES)
    fps: float = Field(SCENARIO.fps, ge=sim_spec.FPS_RANGE[0], le=sim_spec.FPS_RANGE[1])
    image: Image = Image()
    intrinsics: IntrinsicsSpec = IntrinsicsSpec()
    layout: Layout = Layout()
    actors: list[Actor] = []
    chairs: list[Chair] = Field([], max_length=MAX_CHAIRS)
    camera: Camera = Camera()
    lighting: Lighting = Lighting()
    sensor: Sensor = Sensor()
    """``perfect``, ``kinect``, ``tum`` or a mapping of sensor settings."""
    flow: bool = SCENARIO.flow

    @field_validator("sensor", mode="before")
    @classmethod
    def _sensor_preset(cls, value: Any) -> Any:
        if not isinstance(value, str):
            return value
        if value not in SENSOR_PRESETS:
            raise ValueError(f"give {' or '.join(SENSOR_PRESETS)}, or a mapping of sensor settings")
        return SENSOR_PRESETS[value]()

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        """Checks across fields; each message starts with the field it names."""
        if self.frames is not None and self.duration_s is not None:
            raise ValueError("frames: give frames or duration_s, not both")
        if self.n_frames > MAX_FRAMES:
            raise ValueError(
                f"duration_s: duration_s x fps gives {self.n_frames} frames, more than {MAX_FRAMES}"
            )
        self._check_intrinsics()
        if sum(a.count for a in self.actors) > MAX_ACTORS:
            raise ValueError(f"actors: at most {MAX_ACTORS} actors in all")
        wanted = {a.kind: actor_registry.get(a.kind).place.needs for a in self.actors if a.count}
        for kind, needs in wanted.items():
            if needs == "chair" and not self.chairs:
                raise ValueError(f"chairs: a {kind} needs at least one chair")
        for kind, needs in wanted.items():
            if needs == "desk" and not self.layout.desk:
                raise ValueError(f"layout.desk: a {kind} needs the desk (layout.desk: true)")
        if not self.layout.desk and any(a.count and a.path == TUM_WALK for a in self.actors):
            raise ValueError("layout.desk: path 'tum_walk' sits people at the desk (layout.desk: true)")
        self._check_geometry()
        self._check_camera_targets()
        return self

    def _check_camera_targets(self) -> None:
        """Speed targets the motion cannot reach within its amplitude caps are refused here,
        not at generate time: the rig is calibrated as generate will (same seed, frames)."""
        camera = self.camera
        if camera.mean_speed_mps is None and camera.mean_angular_speed_dps is None:
            return
        from depotbench.sim.camera_rig import CameraRig
        from depotbench.sim.world import scenario_streams

        _, _, _, camera_rng, _, _ = scenario_streams(self.seed)
        spec = sim_spec.CameraSpec(**camera.model_dump())
        CameraRig(spec, camera_rng, duration_s=self.n_frames / self.fps, fps=self.fps)

    def _check_intrinsics(self) -> None:
        k, w, h = self.intrinsics, self.image.width, self.image.height
        cx, cy = k.principal(w, h) or ((w - 1) / 2, (h - 1) / 2)
        pinhole = (k.fx, k.fx if k.fy is None else k.fy, cx, cy)
        names = tuple(f"intrinsics.{name}" for name in ("fx", "fy", "cx", "cy"))
        sim_spec.check_pinhole(w, h, pinhole, names)

    def _check_geometry(self) -> None:
        """The camera inside the hall and looking somewhere; paths and chairs on its floor."""
        half_x, half_y = self.layout.size_m[0] / 2, self.layout.size_m[1] / 2
        height = self.layout.height_m

        def on_floor(point: tuple[float, ...], margin: float) -> bool:
            return abs(point[0]) <= half_x - margin and abs(point[1]) <= half_y - margin

        camera = self.camera
        if camera.motion != "robot":  # the robot drives its own loop
            x, y, z = camera.position_m
            if not (on_floor(camera.position_m, 0.05) and 0.05 <= z <= height - 0.05):
                raise ValueError(
                    f"camera.position_m: {[x, y, z]} lies outside the hall (x within +-{half_x}, "
                    f"y within +-{half_y}, z in 0..{height} m; layout.size_m and layout.height_m set it)"
                )
            if math.dist(camera.position_m, camera.target_m) < MIN_VIEW_DISTANCE_M:
                raise ValueError("camera.target_m: the target must lie away from position_m")
        for i, group in enumerate(self.actors):
            points = group.waypoints or []
            for j, point in enumerate(points):
                if not on_floor(point, WALL_MARGIN_M):
                    raise ValueError(
                        f"actors.{i}.waypoints.{j}: {list(point)} lies outside the hall floor "
                        f"(x within +-{half_x - WALL_MARGIN_M}, y within +-{half_y - WALL_MARGIN_M})"
                    )
            if points and max(math.dist(points[0], p) for p in points) < MIN_PATH_SPAN_M:
                raise ValueError(
                    f"actors.{i}.waypoints: the points coincide; a path needs two of them at "
                    f"least {MIN_PATH_SPAN_M} m apart"
                )
        for i, chair in enumerate(self.chairs):
            if not on_floor(chair.position_m, WALL_MARGIN_M):
                raise ValueError(
                    f"chairs.{i}.position_m: {list(chair.position_m)} lies outside the hall floor"
                )
            half = CHAIR_HALF_M
            x, y = chair.position_m
            for what, rect in fixed_footprints(self.layout.to_spec()):
                if overlaps((x - half, y - half, x + half, y + half), rect):
                    raise ValueError(f"chairs.{i}.position_m: {[x, y]} stands on {what}; move it")
            for j, other in enumerate(self.chairs[:i]):
                if math.dist(chair.position_m, other.position_m) < MIN_CHAIR_SPACING_M:
                    raise ValueError(
                        f"chairs.{i}.position_m: overlaps chairs.{j} (chairs stand at least "
                        f"{MIN_CHAIR_SPACING_M} m apart)"
                    )

    @property
    def n_frames(self) -> int:
        if self.frames is not None:
            return self.frames
        return max(1, round((self.duration_s or 10.0) * self.fps))


def _pick(rng: np.random.Generator, value: float | tuple[float, float]) -> float:
    if isinstance(value, int | float):
        return float(value)
    return float(rng.uniform(value[0], value[1]))


def to_scenario(scenario: Scenario) -> sim_spec.ScenarioSpec:
    """Expand counts and ranges (drawn from the scenario's seed) into the simulator's spec."""
    rng = np.random.default_rng(np.random.SeedSequence(scenario.seed, spawn_key=(1000,)))
    actors = []
    for group in scenario.actors:
        for _ in range(group.count):
            clothing = None if group.clothing == "any" else group.clothing
            actors.append(
                sim_spec.ActorSpec(
                    kind=group.kind,
                    speed_mps=_pick(rng, group.speed_mps),
                    path=group.path,
                    waypoints=tuple(tuple(p) for p in group.waypoints or ()),
                    clothing=clothing,
                    scale=None if group.scale is None else _pick(rng, group.scale),
                )
            )
    lay = scenario.layout
    return sim_spec.ScenarioSpec(
        name=scenario.name,
        seed=scenario.seed,
        frames=scenario.n_frames,
        fps=scenario.fps,
        width=scenario.image.width,
        height=scenario.image.height,
        focal_px=scenario.intrinsics.fx,
        focal_y_px=scenario.intrinsics.fy,
        principal_px=scenario.intrinsics.principal(scenario.image.width, scenario.image.height),
        layout=lay.to_spec(),
        actors=tuple(actors),
        chairs=tuple(sim_spec.ChairSpec(c.position_m, c.yaw_deg) for c in scenario.chairs),
        camera=sim_spec.CameraSpec(**scenario.camera.model_dump()),
        light_intensity=scenario.lighting.intensity,
        flow=scenario.flow,
        sensor=sim_spec.SensorSpec(**scenario.sensor.model_dump()),
        layout_seed=lay.seed,
        tags=tuple(scenario.tags),
    )


_TYPE_TAGS = frozenset({"str", "int", "float", "bool", "bytes", "none", "list", "dict", "tuple"})
"""How pydantic names a union's alternative of a plain type in an error's location."""


def _model_names() -> set[str]:
    """The class names pydantic gives a union's model alternatives in an error's location."""
    names, pending = set(), [BaseModel]
    while pending:
        for sub in pending.pop().__subclasses__():
            names.add(sub.__name__)
            pending.append(sub)
    return names


def _tags(loc: tuple, models: set[str]) -> list[int]:
    """Where ``loc`` may name a union's alternative (``Grid``, ``str``, ``function-after[...]``)."""
    return [
        i
        for i, part in enumerate(loc)
        if isinstance(part, str) and (part in _TYPE_TAGS or "[" in part or part in models)
    ]


def relevant_errors(errors: list[dict]) -> list[dict]:
    """A union's errors for the alternative the input came nearest to, its tag dropped from
    the location: pydantic reports every alternative (``grid: [.nan]`` read as a Grid, a
    Range and a Random gave 5 lines, 4 of them 'unknown field grid' or 'range: Field
    required'). The nearest is the one whose errors reach deepest into the input (the NaN at
    ``grid.0`` against a missing ``range``); on a tie, the first alternative. A place is a
    union only where errors name two alternatives there (a user's key named ``str`` stays)."""
    models = _model_names()
    while (union := _first_union(errors, models)) is not None:
        prefix, at, members = union
        depth: dict[str, int] = {}
        for e in members:
            depth[e["loc"][at]] = max(depth.get(e["loc"][at], 0), len(e["loc"]))
        chosen = max(depth, key=lambda tag: depth[tag])  # the first of the deepest
        kept = []
        for e in errors:
            if not any(e is m for m in members):
                kept.append(e)
            elif e["loc"][at] == chosen:
                kept.append({**e, "loc": (*prefix, *e["loc"][at + 1 :])})
        errors = kept
    return errors


def _first_union(errors: list[dict], models: set[str]) -> tuple[tuple, int, list[dict]] | None:
    """The first place where errors name two or more alternatives: its location, the tag's
    index and the errors of every alternative there."""
    for error in errors:
        loc = tuple(error["loc"])
        for at in _tags(loc, models):
            members = [
                e for e in errors if tuple(e["loc"][:at]) == loc[:at] and at in _tags(tuple(e["loc"]), models)
            ]
            if len({e["loc"][at] for e in members}) > 1:
                return loc[:at], at, members
    return None


def format_validation_error(source: str, exc: ValidationError) -> str:
    """One line per problem: ``file: field.path: what is wrong (got X)``; of a union, the
    alternative the input came nearest to (``relevant_errors``)."""
    lines = []
    for error in relevant_errors(exc.errors()):
        path = ".".join(str(p) for p in error["loc"])
        message = error["msg"].removeprefix("Value error, ")
        if error["type"] == "extra_forbidden":
            message = "unknown field (check the spelling; see `depotbench validate --help`)"
        got = error.get("input")
        shown = "" if isinstance(got, dict | list) or error["type"] == "missing" else f" (got {got!r:.80})"
        if not path and error["type"] == "value_error":
            # A check across fields: its message starts with the field it names.
            lines.append(f"{source}: {message}")
            continue
        lines.append(f"{source}: {path or '(top level)'}: {message}{shown}")
    return "\n".join(lines)


def _check_size(data: Any, path: Path) -> None:
    """Refuse YAML whose aliases expand past ``MAX_YAML_NODES`` or nest past ``MAX_YAML_DEPTH``.

    Aliases load as shared references, so a small file can stand for a tree of 10^9
    nodes that validation would walk; sizes are counted once per shared node.
    """
    sizes: dict[int, int] = {}

    def size(node: Any, depth: int, path_ids: frozenset[int]) -> int:
        if depth > MAX_YAML_DEPTH or id(node) in path_ids:
            raise SpecError(
                f"{path}: nested more than {MAX_YAML_DEPTH} levels deep (or an alias refers to itself)"
            )
        if not isinstance(node, dict | list):
            return 1
        if id(node) not in sizes:
            children = list(node.keys()) + list(node.values()) if isinstance(node, dict) else node
            inner = path_ids | {id(node)}
            sizes[id(node)] = 1 + sum(size(child, depth + 1, inner) for child in children)
            if sizes[id(node)] > MAX_YAML_NODES:
                raise SpecError(f"{path}: expands to more than {MAX_YAML_NODES} values (check its aliases)")
        return sizes[id(node)]

    size(data, 0, frozenset())


class _StrictLoader(yaml.SafeLoader):
    """PyYAML's safe loader, but a key given twice in one mapping is an error, not the last one wins."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()  # a list made 80,000 keys cost 48 s (probe N15); a set, linear
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
            try:
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {key!r} appears twice in one mapping", key_node.start_mark
                    )
                seen.add(key)
            except TypeError:
                continue  # an unhashable key: the base class refuses it, naming the line
        return super().construct_mapping(node, deep=deep)


def read_yaml(path: Path) -> Any:
    """Parse YAML safely: tags that would build Python objects are refused, and size,
    nesting and alias expansion are bounded."""
    try:
        text = read_text(path, MAX_SPEC_BYTES, "scenario or suite file")
    except FileNotFoundError:
        raise SpecError(f"{path}: no such file") from None
    except FileError as exc:
        raise SpecError(str(exc)) from None
    try:
        data = yaml.load(text, Loader=_StrictLoader)  # noqa: S506 - a SafeLoader that refuses duplicate keys
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise SpecError(f"{path}:{where}: not valid YAML: {problem}") from None
    except RecursionError:
        raise SpecError(f"{path}: nested too deeply to parse (more than {MAX_YAML_DEPTH} levels)") from None
    except ValueError as exc:  # e.g. an integer of more digits than Python converts
        raise SpecError(f"{path}: holds a value that cannot be read: {str(exc).split(';')[0]}") from None
    _check_size(data, path)
    if data is None:
        raise SpecError(f"{path}: the file is empty; a scenario needs at least a name")
    if not isinstance(data, dict):
        raise SpecError(f"{path}: the top level must be a mapping of fields, got {type(data).__name__}")
    return data


def check_option(field: str, value: Any, option: str) -> Any:
    """A command-line value checked against the limits the schema sets for ``field``."""
    info = Scenario.model_fields[field]
    kind = Annotated[info.annotation, *info.metadata] if info.metadata else info.annotation  # type: ignore[valid-type]
    adapter = TypeAdapter(kind)
    try:
        return adapter.validate_python(value)
    except ValidationError as exc:
        raise SpecError(f"{option} {value}: {exc.errors()[0]['msg']} (the scenario's {field})") from None


def validate_model(model: type[M], data: Any, source: str) -> M:
    """``data`` as ``model``, or one SpecError line per problem, each naming ``source`` and the field."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise SpecError(format_validation_error(source, exc)) from None


def load_model(model: type[M], path: Path) -> M:
    """A YAML file (read safely, ``read_yaml``) validated as ``model``: scenarios, suites,
    sweep specs and gate files all load this way."""
    return validate_model(model, read_yaml(path), str(path))


def parse_scenario(data: dict[str, Any], source: str) -> Scenario:
    return validate_model(Scenario, data, source)


def load_scenario(path: Path) -> Scenario:
    return parse_scenario(read_yaml(path), str(path))
