"""The Python scenario spec the simulator builds from (the YAML layer lives in scenes/).

All distances in metres, angles in degrees, the world z axis up, the floor at z = 0,
the hall centred on the origin with the default camera looking along +y.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

ACTOR_KINDS = ("person", "sitting_person", "chair_pusher", "dog", "cat", "pig", "bird")
PATH_MODES = ("loop", "random_walk", "seated")
CAMERA_MOTIONS = ("static", "xyz", "rpy", "halfsphere", "robot")
CLOTHING = ("plain", "stripes", "plaid")


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
    """One actor. Empty ``waypoints`` means: generated from the seed, crossing the camera's view."""

    kind: str
    speed_mps: float = 1.1
    path: str = "loop"
    waypoints: tuple[tuple[float, float], ...] = ()
    clothing: str | None = None
    scale: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in ACTOR_KINDS:
            raise ValueError(f"actor kind {self.kind!r} is not one of {ACTOR_KINDS}")
        if self.path not in PATH_MODES:
            raise ValueError(f"path {self.path!r} is not one of {PATH_MODES}")
        if self.clothing is not None and self.clothing not in CLOTHING:
            raise ValueError(f"clothing {self.clothing!r} is not one of {CLOTHING}")
        if not 0.0 <= self.speed_mps <= 5.0:
            raise ValueError(f"speed_mps must be in [0, 5], got {self.speed_mps}")


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

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if not 1.0 <= self.fps <= 240.0:
            raise ValueError(f"fps must be in [1, 240], got {self.fps}")
        if not (16 <= self.width <= 4096 and 16 <= self.height <= 4096):
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


_NESTED = {"layout": LayoutSpec, "camera": CameraSpec}


def scenario_from_dict(data: dict, source: str = "spec") -> ScenarioSpec:
    """A ScenarioSpec from plain data; unknown keys and bad values name the field.

    The scenes package adds the full YAML schema, library and suites on top.
    """
    from sim.errors import InputError

    if not isinstance(data, dict):
        raise InputError(f"{source}: must be a mapping of scenario fields")
    known = {f.name for f in fields(ScenarioSpec)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise InputError(
            f"{source}: unknown field(s) {', '.join(unknown)}; allowed: {', '.join(sorted(known))}"
        )
    values = dict(data)
    try:
        for key, cls in _NESTED.items():
            if key in values:
                values[key] = cls(
                    **{k: tuple(v) if isinstance(v, list) else v for k, v in values[key].items()}
                )
        if "actors" in values:
            values["actors"] = tuple(
                ActorSpec(
                    **{k: tuple(map(tuple, v)) if k == "waypoints" else v for k, v in a.items()}
                )
                for a in values["actors"]
            )
        if "chairs" in values:
            values["chairs"] = tuple(
                ChairSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in c.items()})
                for c in values["chairs"]
            )
        return ScenarioSpec(**values)
    except (TypeError, ValueError, AttributeError) as exc:
        raise InputError(f"{source}: {exc}") from None


def load_scenario(path: Path) -> ScenarioSpec:
    import yaml

    from sim.errors import InputError

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: no such scenario file") from None
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML ({exc})") from None
    return scenario_from_dict(data, str(path))
