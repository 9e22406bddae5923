"""The Python scenario spec the simulator builds from (the YAML layer lives in scenes/).

All distances in metres, angles in degrees, the world z axis up, the floor at z = 0,
the hall centred on the origin with the default camera looking along +y.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field

from depotbench.core.version import FORMAT_VERSION, generator_version
from depotbench.sim import actor_registry
from depotbench.sim.kinds import PATH_MODES

CAMERA_MOTIONS = ("static", "xyz", "rpy", "halfsphere", "robot")
CLOTHING = ("plain", "stripes", "plaid")
MAX_IMAGE_SIDE = 2048
"""Pixels a side: a 2048x1536 sequence takes about 640 MB to generate (measured)."""
SPEED_RANGE_MPS = (0.0, 5.0)
"""An actor's speed: a brisk run at most."""
FPS_RANGE = (1.0, 240.0)
MIN_IMAGE_SIDE = 16


@dataclass(frozen=True)
class LayoutSpec:
    hall_size_m: tuple[float, float] = (14.0, 11.0)
    hall_height_m: float = 4.5
    rack_rows: int = 2
    racks_per_row: int = 3
    floor_props: int = 10
    desk: bool = True


@dataclass(frozen=True)
class ActorSpec:
    """One actor. ``kind`` names an entry of ``actor_registry``. Empty ``waypoints`` means:
    generated from the seed, crossing the camera's view."""

    kind: str
    speed_mps: float = 1.1
    path: str = "loop"
    waypoints: tuple[tuple[float, float], ...] = ()
    clothing: str | None = None
    scale: float | None = None

    def __post_init__(self) -> None:
        actor_registry.get(self.kind)
        if self.path not in PATH_MODES:
            raise ValueError(f"path {self.path!r} is not one of {PATH_MODES}")
        if self.clothing is not None and self.clothing not in CLOTHING:
            raise ValueError(f"clothing {self.clothing!r} is not one of {CLOTHING}")
        low, high = SPEED_RANGE_MPS
        if not low <= self.speed_mps <= high:
            raise ValueError(f"speed_mps must be in [{low:g}, {high:g}], got {self.speed_mps}")


@dataclass(frozen=True)
class ChairSpec:
    position_m: tuple[float, float]
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class CameraSpec:
    """A camera rig. ``position_m``/``target_m`` set the mean viewpoint."""

    motion: str = "static"
    position_m: tuple[float, float, float] = (0.0, -3.2, 1.45)
    target_m: tuple[float, float, float] = (0.0, 1.5, 0.9)
    amplitude_m: float = 0.25
    amplitude_deg: float = 12.0
    period_s: float = 6.0
    speed_mps: float = 0.6

    def __post_init__(self) -> None:
        if self.motion not in CAMERA_MOTIONS:
            raise ValueError(f"camera motion {self.motion!r} is not one of {CAMERA_MOTIONS}")


@dataclass(frozen=True)
class SensorSpec:
    """Post-render sensor effects; all off by default (a perfect sensor)."""

    depth_noise: bool = False
    disparity_quantisation: bool = False
    depth_range_m: tuple[float, float] = (0.0, 13.0)
    edge_dropout: float = 0.0
    rgb_noise_sigma: float = 0.0
    motion_blur_exposure_s: float = 0.0
    exposure_variation: float = 0.0

    @property
    def enabled(self) -> bool:
        return self != SensorSpec()


@dataclass(frozen=True)
class ScenarioSpec:
    name: str = "default"
    seed: int = 0
    frames: int = 90
    fps: float = 30.0
    width: int = 640
    height: int = 480
    focal_px: float = 525.0
    layout: LayoutSpec = field(default_factory=LayoutSpec)
    actors: tuple[ActorSpec, ...] = ()
    chairs: tuple[ChairSpec, ...] = ()
    camera: CameraSpec = field(default_factory=CameraSpec)
    light_intensity: float = 0.9
    flow: bool = False
    sensor: SensorSpec = field(default_factory=SensorSpec)
    layout_seed: int | None = None
    """Draw the layout from this seed instead of the scenario seed (suites vary actors only)."""
    tags: tuple[str, ...] = ()
    """The scenario's tags (``smoke``, ``crowd``): they shape no pixel, but meta.json keeps
    them, so that a gate's ``tags:`` can select the runs of a sequence by them."""

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if not FPS_RANGE[0] <= self.fps <= FPS_RANGE[1]:
            raise ValueError(f"fps must be in [{FPS_RANGE[0]:g}, {FPS_RANGE[1]:g}], got {self.fps}")
        sides = (MIN_IMAGE_SIDE, MAX_IMAGE_SIDE)
        if not (sides[0] <= self.width <= sides[1] and sides[0] <= self.height <= sides[1]):
            raise ValueError(f"image size {self.width}x{self.height} is out of range")


def default_scenario(frames: int = 90, seed: int = 0) -> ScenarioSpec:
    """Two people walking past the desk, one seated, a dog, and two chairs; hand-held camera."""
    return ScenarioSpec(
        name="default",
        seed=seed,
        frames=frames,
        actors=(
            ActorSpec("person", speed_mps=1.2, clothing="stripes"),
            ActorSpec("person", speed_mps=1.0, clothing="plaid"),
            ActorSpec("sitting_person", path="seated", speed_mps=0.0, clothing="plain"),
            ActorSpec("dog", speed_mps=1.3),
        ),
        chairs=(ChairSpec((1.6, 0.6), 30.0), ChairSpec((-2.2, 2.6), -20.0)),
        camera=CameraSpec(motion="xyz"),
    )


def content_key(scenario: ScenarioSpec) -> str:
    """What a generated sequence's bytes depend on: the spec (seed included), format and generator.

    Stored in the sequence's marker, so a suite counts a sequence complete only when it
    holds exactly what is asked for now.
    """
    data = {
        "scenario": dataclasses.asdict(scenario),
        "format_version": FORMAT_VERSION,
        "generator": generator_version(),
    }
    digest = hashlib.sha256(json.dumps(data, sort_keys=True).encode("utf-8")).hexdigest()
    return f"sha256:{digest}"


def spec_from_dict(data: dict) -> ScenarioSpec:
    """Rebuild a ScenarioSpec from its ``dataclasses.asdict`` form (as stored in meta.json)."""

    def tuples(value):
        return tuple(tuples(v) for v in value) if isinstance(value, list) else value

    values = {k: tuples(v) for k, v in data.items()}
    values["layout"] = LayoutSpec(**{k: tuples(v) for k, v in data["layout"].items()})
    values["camera"] = CameraSpec(**{k: tuples(v) for k, v in data["camera"].items()})
    values["sensor"] = SensorSpec(**{k: tuples(v) for k, v in data.get("sensor", {}).items()})
    values["actors"] = tuple(ActorSpec(**{k: tuples(v) for k, v in a.items()}) for a in data["actors"])
    values["chairs"] = tuple(ChairSpec(**{k: tuples(v) for k, v in c.items()}) for c in data["chairs"])
    return ScenarioSpec(**values)
