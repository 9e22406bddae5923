"""Every SLAM and rejection threshold as a named, range-checked field.

Rejection thresholds cite their source; sweeps vary them by name (``--set k=2.5``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields
from typing import Any


class ConfigError(ValueError):
    """A threshold out of range or an unknown name."""


def _check(obj: Any, limits: dict[str, tuple[float, float]]) -> None:
    for name, (low, high) in limits.items():
        value = getattr(obj, name)
        if not low <= value <= high:
            raise ConfigError(f"{name} = {value} is out of range [{low}, {high}]")


@dataclass(frozen=True)
class TrackingConfig:
    n_features: int = 1000
    """ORB features per frame (ORB-SLAM2's TUM setting)."""
    scale_factor: float = 1.2
    n_levels: int = 8
    fast_threshold: int = 20
    """ORB-SLAM's iniThFAST: a cell keeps only corners this strong when it has any."""
    fast_threshold_min: int = 7
    """ORB-SLAM's minThFAST: the fallback threshold of cells without a strong corner. It is
    what gives low-contrast surfaces (clothes, skin) features; 20 disables the fallback and
    saves ~5 ms of extraction per frame (measured)."""
    grid_cell_px: int = 32
    """Cell side at each pyramid level (ORB-SLAM: 30), for the fallback and the spreading."""
    min_depth_m: float = 0.1
    max_depth_m: float = 12.0
    baseline_fx: float = 40.0
    """ORB-SLAM's bf for RGB-D: turns depth into a virtual right-image coordinate."""
    match_radius_px: float = 15.0
    """Search radius at pyramid level 0 for the last frame's points (ORB-SLAM's TrackWithMotionModel:
    15 px for RGB-D, times scale_factor^octave of the point's keypoint in the last frame)."""
    match_max_hamming: int = 100
    """Largest descriptor distance of a projection match: ORB-SLAM2's TH_HIGH, which its
    SearchByProjection uses. 50 (TH_LOW, its bag-of-words threshold) halves the matches per
    frame, nearly doubles keyframes and measured 2.5 vs 1.9 mm ATE on static_depot."""
    local_search_th: float = 3.0
    """ORB-SLAM's SearchLocalPoints th for RGB-D: a local-map point is searched for within th x
    (2.5 px seen within 3.6 degrees of its normal, else 4 px) x scale^predicted level."""
    motion_model_ransac: bool = False
    """False (ORB-SLAM2/3's TrackWithMotionModel): the pose optimisation starts from the
    constant-velocity prediction, and PnP RANSAC runs only when that fails and for
    relocalisation. True re-solves every frame with PnP RANSAC first, which re-anchors the
    pose each frame and hides some of the dynamic-scene failures the bench exists to show."""
    ransac_reprojection_px: float = 4.0
    ransac_iterations: int = 100
    min_inliers: int = 30
    keyframe_inlier_ratio: float = 0.75
    """A keyframe is due when inliers fall below this fraction of the reference keyframe's
    points (ORB-SLAM2 RGB-D: 0.75)."""
    keyframe_points: int = 100
    """A keyframe makes map points from its closest keypoints first: all closer than ThDepth,
    and farther ones only until it holds this many (ORB-SLAM's CreateNewKeyFrame)."""
    recent_point_keyframes: int = 3
    """A new map point is culled for a poor found/visible ratio or too few observations only
    while fewer than this many keyframes have followed its own (ORB-SLAM's MapPointCulling)."""
    local_keyframes: int = 80
    """ORB-SLAM's UpdateLocalKeyFrames stops adding neighbours once the local map holds 80 keyframes."""
    ba_iterations: int = 10
    mapper_time_scale: float = 0.0
    """How long local mapping takes, as a multiple of ``slam.mapping_clock.MappingCosts`` (one
    core of the 2-core development machine): 0 maps each keyframe to its end before the next
    frame (the mapper always idle); 1 runs ORB-SLAM3's mapping thread on a virtual clock at
    that core's pace, which skips and interrupts work as keyframes queue (deterministic)."""
    relocalize_keyframes: int = 20
    seed: int = 0

    def __post_init__(self) -> None:
        _check(
            self,
            {
                "n_features": (50, 20000),
                "scale_factor": (1.01, 2.0),
                "n_levels": (1, 16),
                "fast_threshold": (1, 100),
                "fast_threshold_min": (1, 100),
                "grid_cell_px": (8, 256),
                "min_depth_m": (0.0, 5.0),
                "max_depth_m": (0.5, 100.0),
                "baseline_fx": (1.0, 1000.0),
                "match_radius_px": (1.0, 200.0),
                "match_max_hamming": (1, 256),
                "local_search_th": (0.1, 50.0),
                "ransac_reprojection_px": (0.5, 50.0),
                "ransac_iterations": (10, 10000),
                "min_inliers": (6, 1000),
                "keyframe_inlier_ratio": (0.1, 1.0),
                "keyframe_points": (0, 100000),
                "recent_point_keyframes": (1, 100000),
                "local_keyframes": (1, 1000),
                "ba_iterations": (0, 200),
                "mapper_time_scale": (0.0, 1000.0),
                "relocalize_keyframes": (1, 1000),
                "seed": (0, 2**31 - 1),
            },
        )
        if self.min_depth_m >= self.max_depth_m:
            raise ConfigError(
                f"min_depth_m = {self.min_depth_m} must be below max_depth_m = {self.max_depth_m}"
            )
        if self.fast_threshold_min > self.fast_threshold:
            raise ConfigError(
                f"fast_threshold_min = {self.fast_threshold_min} must not exceed "
                f"fast_threshold = {self.fast_threshold} (it is the fallback for cells without a corner)"
            )


MIN_PYRAMID_SIDE_PX = 8
"""The coarsest ORB pyramid level keeps at least this many pixels on its short side."""


def check_pyramid(config: TrackingConfig, width: int, height: int) -> None:
    """Refuse a pyramid whose coarsest level would shrink the image to (almost) nothing."""
    side = min(width, height) / config.scale_factor ** (config.n_levels - 1)
    if side < MIN_PYRAMID_SIDE_PX:
        raise ConfigError(
            f"n_levels = {config.n_levels} with scale_factor = {config.scale_factor} shrinks a "
            f"{width}x{height} image to {side:.1f} px at the coarsest level (at least "
            f"{MIN_PYRAMID_SIDE_PX} needed); use fewer levels or a smaller scale factor"
        )


@dataclass(frozen=True)
class RejectionConfig:
    """Thresholds of the rejection strategies (design.md, methods 1-3)."""

    min_confidence: float = 0.5
    """Detections below this confidence are ignored."""
    box_dilation_px: float = 0.0
    """Boxes grow by this many pixels on every side before the inside test."""
    k: float = 2.0
    """Method 1: a Q point is dynamic when its flow differs from the mean P flow by
    more than z = k |(U, V)| (the source uses k = 2)."""
    z_min_px: float = 1.0
    """Method 1: floor on z, so a still camera (|(U,V)| ~ 0) does not flag every Q point
    (our addition; 0 reproduces the source exactly)."""
    epsilon_px: float = 1.0
    """Method 3: distance to the epipolar line above which a point is dynamic."""
    sigma_factor: float = 2.0
    """Method 3: |L_i - L_avg| > sigma_factor * L_std flags a point (the source's 2-sigma rule)."""
    l_thr1_px: float = 2.0
    """Method 3: |L_i - L_avg| > L_thr1 flags a point while L_std < L_thr2."""
    l_thr2_px: float = 1.0
    fundamental_ransac_px: float = 1.0
    """Method 3: RANSAC threshold when estimating F."""
    lk_window_px: int = 11
    """Methods 1 and 3: side of the pyramidal LK window. 11 costs half of 15 with the same ATE and
    recall on the crowd scene (measured); OpenCV's default is 21."""
    lk_levels: int = 3

    def __post_init__(self) -> None:
        _check(
            self,
            {
                "min_confidence": (0.0, 1.0),
                "box_dilation_px": (0.0, 200.0),
                "k": (0.0, 100.0),
                "z_min_px": (0.0, 100.0),
                "epsilon_px": (0.01, 100.0),
                "sigma_factor": (0.1, 10.0),
                "l_thr1_px": (0.0, 100.0),
                "l_thr2_px": (0.0, 100.0),
                "fundamental_ransac_px": (0.05, 20.0),
                "lk_window_px": (5, 51),
                "lk_levels": (0, 6),
            },
        )


@dataclass(frozen=True)
class SlamConfig:
    strategy: str = "none"
    tracking: TrackingConfig = TrackingConfig()
    rejection: RejectionConfig = RejectionConfig()

    def with_settings(self, settings: Mapping[str, Setting]) -> SlamConfig:
        """Apply overrides by name (typed values: ``setting_value`` checks each against its
        field); a name is looked up in rejection, then tracking."""
        rejection, tracking = {}, {}
        rej_names = {f.name for f in fields(RejectionConfig)}
        for name, value in settings.items():
            (rejection if name in rej_names else tracking)[name] = setting_value(name, value)
        return dataclasses.replace(
            self,
            rejection=dataclasses.replace(self.rejection, **rejection),
            tracking=dataclasses.replace(self.tracking, **tracking),
        )


_BOOLEANS = {"true": True, "1": True, "yes": True, "false": False, "0": False, "no": False}

Setting = int | float | bool
"""A threshold's value, typed as its field is: text is parsed once, where it comes in
(``parse_setting``: ``--set``), and every stage after that passes the value."""


def setting_names() -> list[str]:
    """Every setting a strategy's thresholds may name (the fields of both configs), sorted."""
    return sorted(f.name for c in (RejectionConfig, TrackingConfig) for f in fields(c))


def _kind(name: str) -> str:
    """The type of setting ``name``: 'int', 'float' or 'bool' (its field's annotation)."""
    kinds = {f.name: str(f.type) for c in (RejectionConfig, TrackingConfig) for f in fields(c)}
    if name not in kinds:
        raise ConfigError(f"unknown setting {name!r}; known: {', '.join(sorted(kinds))}")
    return kinds[name]


def parse_setting(name: str, text: str) -> Setting:
    """A setting given as text (``--set name=text``) as the value its field holds."""
    kind = _kind(name)
    if kind == "bool":
        if text.strip().lower() not in _BOOLEANS:
            raise ConfigError(f"setting {name}={text!r} is not true or false")
        return _BOOLEANS[text.strip().lower()]
    try:
        number = float(text)
    except ValueError:
        raise ConfigError(f"setting {name}={text!r} is not a number") from None
    if kind != "int":
        return number
    try:
        return int(text)  # exact, however many digits
    except ValueError:  # 1e12 or 8.0: a number written otherwise, whole or not
        return setting_value(name, number)


def parse_settings(items: Iterable[str]) -> dict[str, Setting]:
    """``NAME=VALUE`` texts (``--set``) as settings by name; the last of a repeated name wins."""
    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ConfigError(f"{item!r}: expected NAME=VALUE")
        out[name.strip()] = parse_setting(name.strip(), text.strip())
    return out


def setting_value(name: str, value: Setting) -> Setting:
    """A typed value checked against its field: a whole-number field takes 8 and 8.0 (a YAML
    grid's numbers are floats) but not 8.5, a number field takes 2 as 2.0, a switch takes only
    True or False. Text is refused: it is parsed at the edge (``parse_setting``)."""
    kind = _kind(name)
    if isinstance(value, str):
        raise ConfigError(f"setting {name}={value!r}: give a value, not text")
    if kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"setting {name}={value!r} is not true or false")
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"setting {name}={value!r} is not a number")
    if kind == "int":
        if not float(value).is_integer():
            raise ConfigError(f"setting {name}={value!r} must be a whole number")
        return int(value)
    return float(value)
