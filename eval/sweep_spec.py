"""Sweep specs: what to run, and which threshold values, as validated YAML.

```yaml
sweep: epsilon
description: How far from its epipolar line a point may be.
suite: walking.yaml          # a suite file (relative to this file), generated into OUT/sequences
sequences: [runs/walk]       # and/or sequence folders
trackers: [builtin]
detectors:
  - groundtruth
  - {detector: groundtruth, faults: {miss: 0.3, latency: 2}}
strategies: [none, box_epipolar_flow]
thresholds:
  box_epipolar_flow:
    epsilon_px: {grid: [0.5, 1.0, 2.0]}
    l_thr1_px: {range: [0.5, 2.0, 0.5]}            # start, stop (inclusive), step
  prior_flow:
    k: {random: {low: 1.0, high: 4.0, samples: 8, seed: 0}}
```

Each strategy's thresholds form a grid (their cross product); ``none`` always
runs too, as every rho's baseline. Values are checked against the SLAM
configuration before anything runs.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import Field, model_validator

from detectors.config import (
    DetectorConfig,
    DetectorConfigError,
    DetectorKind,
    check_model_file,
    parse_detector,
)
from eval.harness import EXTERNAL_STRATEGIES, STRATEGY_CHOICES, TrackerConfig, slam_config
from eval.trackers.base import TrackerKind
from scenes.schema import SpecError, Strict, load_model
from sim.errors import InputError

MAX_JOBS = 100_000


class Grid(Strict):
    grid: list[float] = Field(min_length=1, max_length=10_000)


class Range(Strict):
    range: tuple[float, float, float]

    @model_validator(mode="after")
    def _steps(self) -> Range:
        start, stop, step = self.range
        if not all(math.isfinite(v) for v in self.range) or step <= 0 or stop < start:
            raise ValueError("range is [start, stop, step] with start <= stop and step > 0")
        if (stop - start) / step > 10_000:
            raise ValueError("range has more than 10,000 values")
        return self

    def values(self) -> list[float]:
        start, stop, step = self.range
        count = int(math.floor((stop - start) / step + 1e-9)) + 1
        return [round(start + i * step, 12) for i in range(count)]


class RandomDraw(Strict):
    low: float
    high: float
    samples: int = Field(ge=1, le=10_000)
    seed: int = Field(default=0, ge=0)
    log: bool = False

    @model_validator(mode="after")
    def _bounds(self) -> RandomDraw:
        if not (math.isfinite(self.low) and math.isfinite(self.high)) or self.high <= self.low:
            raise ValueError("random needs finite low < high")
        if self.log and self.low <= 0:
            raise ValueError("a log-uniform draw needs low > 0")
        return self

    def values(self) -> list[float]:
        rng = np.random.default_rng(self.seed)
        if self.log:
            drawn = np.exp(rng.uniform(np.log(self.low), np.log(self.high), self.samples))
        else:
            drawn = rng.uniform(self.low, self.high, self.samples)
        return [float(v) for v in drawn]


class Random(Strict):
    random: RandomDraw


class Interval(Strict):
    low: float
    high: float
    log: bool = False

    @model_validator(mode="after")
    def _bounds(self) -> Interval:
        if not (math.isfinite(self.low) and math.isfinite(self.high)) or self.high <= self.low:
            raise ValueError("a search interval needs finite low < high")
        if self.log and self.low <= 0:
            raise ValueError("a log interval needs low > 0")
        return self


class Search(Strict):
    """An Optuna search over one strategy's thresholds (extra [search])."""

    strategy: str
    space: dict[str, Interval] = Field(min_length=1)
    trials: int = Field(default=30, ge=1, le=10_000)
    seed: int = Field(default=0, ge=0)
    objective: str = Field(default="mean_ate", pattern="^(mean_ate|ate_time)$")
    """mean_ate: mean ATE RMSE (m) over the sweep's runs of a trial; ate_time: that plus
    ``time_weight`` x the mean of their median tracking ms."""
    time_weight: float = Field(default=0.0001, ge=0.0)

    @model_validator(mode="after")
    def _strategy(self) -> Search:
        if self.strategy not in STRATEGY_CHOICES or self.strategy in ("none", "mask"):
            raise ValueError(f"search.strategy {self.strategy!r} has no thresholds to search")
        return self


class DetectorEntry(Strict):
    detector: str = "groundtruth"
    settings: dict[str, str | float | int] = Field(default_factory=dict)
    faults: dict[str, str | float | int] = Field(default_factory=dict)
    class_priors: dict[str, str] = Field(default_factory=dict)


class SweepSpec(Strict):
    sweep: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    description: str = ""
    suite: str | None = None
    sequences: list[str] = Field(default_factory=list, max_length=10_000)
    trackers: list[str] = Field(default_factory=lambda: ["builtin"], min_length=1)
    detectors: list[str | DetectorEntry] = Field(default_factory=lambda: ["groundtruth"], min_length=1)
    strategies: list[str] = Field(default_factory=lambda: ["none"], min_length=1)
    thresholds: dict[str, dict[str, Grid | Range | Random]] = Field(default_factory=dict)
    search: Search | None = None

    @model_validator(mode="after")
    def _something_to_run(self) -> SweepSpec:
        if self.suite is None and not self.sequences:
            raise ValueError("give a suite or sequences")
        unknown = [s for s in self.strategies if s not in STRATEGY_CHOICES]
        if unknown:
            raise ValueError(f"unknown strategy {unknown[0]!r}; choose from {', '.join(STRATEGY_CHOICES)}")
        stray = sorted(set(self.thresholds) - set(self.strategies))
        if stray:
            raise ValueError(f"thresholds for {stray[0]!r}, which is not among the strategies")
        if "none" in self.thresholds:
            raise ValueError("thresholds for 'none': the baseline takes no thresholds (it rejects nothing)")
        return self


@dataclass(frozen=True)
class Variant:
    """One strategy with one set of threshold values."""

    strategy: str
    settings: tuple[tuple[str, str], ...]


def setting_text(value: float) -> str:
    """A value as ``--set`` takes it: integers without a point (integer fields refuse '2.0')."""
    v = float(value)
    return str(int(v)) if v.is_integer() and abs(v) < 1e15 else repr(v)


def variants(spec: SweepSpec) -> list[Variant]:
    """Every (strategy, thresholds) to run; ``none`` first, always once."""
    out = [Variant("none", ())]
    for strategy in spec.strategies:
        if strategy == "none":
            continue
        axes = spec.thresholds.get(strategy, {})
        names = sorted(axes)
        values = [_values(axes[n]) for n in names]
        for combo in itertools.product(*values) if names else [()]:
            out.append(
                Variant(strategy, tuple((n, setting_text(v)) for n, v in zip(names, combo, strict=True)))
            )
    return out


def variant_count(spec: SweepSpec) -> int:
    """How many variants ``variants`` would list, counted without listing them: three axes
    within their 10,000-value limits make 10^12 variants, which must be refused, not built."""
    count = 1
    for strategy in dict.fromkeys(spec.strategies):
        if strategy != "none":
            count += math.prod(_count(axis) for axis in spec.thresholds.get(strategy, {}).values())
    return count


def _count(axis: Grid | Range | Random) -> int:
    if isinstance(axis, Grid):
        return len(axis.grid)
    if isinstance(axis, Range):
        start, stop, step = axis.range
        return int(math.floor((stop - start) / step + 1e-9)) + 1
    return axis.random.samples


def _values(axis: Grid | Range | Random) -> list[float]:
    if isinstance(axis, Grid):
        return list(axis.grid)
    if isinstance(axis, Range):
        return axis.values()
    return axis.random.values()


def detector_configs(spec: SweepSpec, source: str) -> list[DetectorConfig]:
    """The detectors, their files (``onnx:PATH``, ``names``) relative to the spec's folder as
    every path of a spec is, and checked to exist before any output is made."""
    folder = Path(source).parent
    configs = []
    for i, entry in enumerate(spec.detectors):
        e = DetectorEntry(detector=entry) if isinstance(entry, str) else entry
        settings = {k: str(v) for k, v in e.settings.items()}
        if settings.get("names"):
            settings["names"] = str(_beside(folder, settings["names"]))
        kind, colon, model = e.detector.partition(":")
        text = f"{kind}:{_beside(folder, model)}" if colon and model else e.detector
        try:
            config = parse_detector(text, settings, {k: str(v) for k, v in e.faults.items()}, e.class_priors)
            if config.kind is DetectorKind.ONNX:
                check_model_file(config.model_path)
        except (DetectorConfigError, InputError) as exc:
            raise SpecError(f"{source}: detectors.{i}: {exc}") from None
        configs.append(config)
    return configs


def _beside(folder: Path, name: str) -> Path:
    path = Path(name).expanduser()
    return path if path.is_absolute() else folder / path


def tracker_configs(spec: SweepSpec, source: str) -> list[TrackerConfig]:
    out = []
    for i, name in enumerate(spec.trackers):
        try:
            kind = TrackerKind(name)
        except ValueError:
            raise SpecError(f"{source}: trackers.{i}: {name!r} is not builtin or orbslam3") from None
        if kind is TrackerKind.COMMAND:
            raise SpecError(f"{source}: trackers.{i}: cmd trackers are not supported in sweeps yet")
        out.append(TrackerConfig(kind))
    return out


def check_variants(spec: SweepSpec, found: list[Variant], trackers: list[TrackerConfig], source: str) -> None:
    """Every value against the SLAM configuration and the trackers, before anything runs."""
    builtin = any(t.kind is TrackerKind.BUILTIN for t in trackers)
    for strategy in spec.strategies:
        if not builtin and strategy not in EXTERNAL_STRATEGIES:
            names = ", ".join(t.kind.value for t in trackers)
            raise SpecError(
                f"{source}: strategies: {strategy} needs the built-in tracker (it decides per keypoint); "
                f"trackers {names} take {' or '.join(EXTERNAL_STRATEGIES)}"
            )
    for variant in found:
        for tracker in trackers:
            if tracker.kind is not TrackerKind.BUILTIN and variant.strategy not in ("none", "mask"):
                continue  # external trackers only take none and mask: those jobs are skipped
            try:
                slam_config(variant.strategy, dict(variant.settings), tracker.kind)
            except InputError as exc:
                raise SpecError(f"{source}: thresholds.{variant.strategy}: {exc}") from None


def check_search(spec: SweepSpec, trackers: list[TrackerConfig], source: str) -> None:
    """A search space's names and both ends of each interval against the strategy's settings,
    named as ``search.space.NAME``, before any output or study is made."""
    if spec.search is None:
        return
    kinds = {t.kind for t in trackers}
    for name, interval in sorted(spec.search.space.items()):
        for value in (interval.low, interval.high):
            for kind in kinds:
                try:
                    slam_config(spec.search.strategy, {name: setting_text(value)}, kind)
                except InputError as exc:
                    reason = str(exc).removeprefix("--set: ")
                    raise SpecError(f"{source}: search.space.{name}: {reason}") from None


def load_sweep(path: Path) -> SweepSpec:
    return load_model(SweepSpec, path)


def resolve(spec: SweepSpec, path: Path, name: str) -> Path:
    """A path of the spec, relative to the spec's folder."""
    candidate = Path(name).expanduser()
    return candidate if candidate.is_absolute() else path.parent / candidate
