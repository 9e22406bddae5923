"""The Python scenario spec the simulator builds from (the YAML layer lives in scenes/).

All distances in metres, angles in degrees, the world z axis up, the floor at z = 0,
the hall centred on the origin with the default camera looking along +y.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
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
FIELD_OF_VIEW_DEG = (1.0, 170.0)
"""Narrowest and widest field of view across an image side: fx spans the width, fy the height."""
PIXEL_ASPECT_RANGE = (0.5, 2.0)
"""fy / fx of a real sensor: TUM fr3 1.007, a Kinect v1 1.0; 2 is already an anamorphic lens."""


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
    mean_speed_mps: float | None = None
    """Calibrate a hand-held motion to this mean translational speed over the sequence's
    frames (jitter included; TUM lists it per sequence). None: the fixed amplitudes."""
    mean_angular_speed_dps: float | None = None
    """Calibrate a hand-held motion to this mean angular speed (deg/s), as ``mean_speed_mps``."""

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
    rolling_shutter_readout_s: float = 0.0
    """Time from the first image row's exposure to the last's (0: a global shutter)."""
    white_balance_drift: float = 0.0
    """Stationary standard deviation of each colour channel's log gain (auto white balance)."""
    depth_delay_mean_s: float = 0.0
    """Mean of the per-frame delay of the depth capture after the RGB capture (exponential)."""
    timestamp_jitter_s: float = 0.0
    """Standard deviation of a frame's stamp about its capture time (USB arrival)."""
    dropped_frame_rate: float = 0.0
    """Share of frames the driver loses: they are absent from every list."""
    gt_rate_hz: float = 0.0
    """Motion-capture rate: groundtruth.txt's poses are the samples nearest each frame (0: exact times)."""
    gt_position_noise_m: float = 0.0
    """Standard deviation of groundtruth.txt's position noise, per axis."""
    gt_rotation_noise_deg: float = 0.0
    """Standard deviation of groundtruth.txt's orientation noise, per axis."""
    gt_time_offset_s: float = 0.0
    """Fixed offset of the motion-capture clock: a row stamped t holds the pose at t + offset."""

    @property
    def enabled(self) -> bool:
        return self != SensorSpec()

    @property
    def timing(self) -> bool:
        """Whether frame times, stamps or the recorded ground truth differ from the exact ones."""
        return bool(
            self.depth_delay_mean_s
            or self.timestamp_jitter_s
            or self.dropped_frame_rate
            or self.gt_rate_hz
            or self.gt_position_noise_m
            or self.gt_rotation_noise_deg
            or self.gt_time_offset_s
        )


@dataclass(frozen=True)
class ScenarioSpec:
    name: str = "default"
    seed: int = 0
    frames: int = 90
    fps: float = 30.0
    width: int = 640
    height: int = 480
    focal_px: float = 525.0
    """fx, in pixels; also fy where ``focal_y_px`` is None (square pixels)."""
    focal_y_px: float | None = None
    """fy, in pixels (TUM fr3: 539.2 beside fx 535.4); None: equal to fx."""
    principal_px: tuple[float, float] | None = None
    """(cx, cy) in OpenCV's convention (pixel centres at integers); None: the image centre
    ((W-1)/2, (H-1)/2), as a plain MuJoCo camera renders, and as every sequence before had."""
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
        cx, cy = self.principal_px or ((self.width - 1) / 2, (self.height - 1) / 2)
        fy = self.focal_px if self.focal_y_px is None else self.focal_y_px
        check_pinhole(self.width, self.height, (self.focal_px, fy, cx, cy), PINHOLE_FIELDS)


PINHOLE_FIELDS = ("focal_px", "focal_y_px", "principal_px[0]", "principal_px[1]")
"""ScenarioSpec's names of fx, fy, cx, cy, for ``check_pinhole``'s messages."""


def check_pinhole(
    width: int, height: int, pinhole: tuple[float, float, float, float], names: tuple[str, ...]
) -> None:
    """Refuse a camera the simulator cannot render as given, in one line naming the field
    (``names``: what fx, fy, cx, cy are called where they were given).

    Each focal length must give a field of view in ``FIELD_OF_VIEW_DEG`` across its side, fy / fx
    must lie in ``PIXEL_ASPECT_RANGE``, and the principal point must lie on the image: inside
    [-0.5, W - 0.5] x [-0.5, H - 0.5], the outer edges of the border pixels.
    """
    fx, fy, cx, cy = pinhole
    for name, value in zip(names, pinhole, strict=True):
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ValueError(f"{name}: must be a finite number, got {value!r}")
    for name, focal, side in ((names[0], fx, width), (names[1], fy, height)):
        low, high = (side / 2 / math.tan(math.radians(f / 2)) for f in reversed(FIELD_OF_VIEW_DEG))
        if not low <= focal <= high:
            raise ValueError(
                f"{name}: {focal:g} px gives a field of view outside {FIELD_OF_VIEW_DEG[0]:g}-"
                f"{FIELD_OF_VIEW_DEG[1]:g} degrees across {side} pixels; "
                f"it must lie in [{low:.1f}, {high:.1f}]"
            )
    low, high = PIXEL_ASPECT_RANGE
    if not low <= fy / fx <= high:
        raise ValueError(
            f"{names[1]}: fy / fx = {fy / fx:.3g} is outside the {low:g}-{high:g} of a real sensor"
        )
    for name, value, side in ((names[2], cx, width), (names[3], cy, height)):
        if not -0.5 <= value <= side - 0.5:
            raise ValueError(
                f"{name}: {value:g} px lies off the image (-0.5 to {side - 0.5:g} for {side} pixels)"
            )


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
