"""Sweep specs: what to run, and which threshold values, as validated YAML.

```yaml
sweep: epsilon
description: How far from its epipolar line a point may be.
suite: walking.yaml          # a suite file (relative to this file), generated into OUT/sequences
sequences: [runs/walk, runs/speeds, 'seqs/*']  # and/or sequence folders, suite folders (generate -o), globs
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
import shlex
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Any, ClassVar

import numpy as np
from depotbench.core.errors import InputError
from depotbench.core.parameters import parameter_text
from depotbench.detectors.config import (
    DetectorConfig,
    DetectorConfigError,
    DetectorKind,
    check_model_file,
    parse_detector,
)
from depotbench.eval.metrics.figures import Baseline
from depotbench.eval.run.harness import EXTERNAL_STRATEGIES, STRATEGY_CHOICES, slam_config
from depotbench.eval.trackers.registry import (
    EXTERNAL,
    TRACKERS,
    TrackerConfig,
    tracker_parameters,
)
from depotbench.eval.trackers.registry import check as check_tracker
from depotbench.scenes.schema import SpecError, Strict, load_model
from depotbench.slam.config import ConfigError, Setting, setting_names, setting_value
from pydantic import BeforeValidator, Field, field_validator, model_validator

MAX_JOBS = 100_000


class _Axis(Strict):
    """One axis of a sweep, told from the other kinds by its one key. A mapping without it
    is refused before its fields are read: its error is then shallower than those of the
    kind whose key it has, which the union's error reporting keeps (a bad ``range:`` read
    as a Grid said 'grid: Field required')."""

    _key: ClassVar[str]

    @model_validator(mode="before")
    @classmethod
    def _has_key(cls, data: Any) -> Any:
        if isinstance(data, dict) and cls._key not in data:
            raise ValueError("give one of grid:, range: or random:")
        return data


class Grid(_Axis):
    _key = "grid"
    grid: list[float] = Field(min_length=1, max_length=10_000)


def _scalar(value: Any) -> Any:
    """A mapping or a list where a value belongs, refused as what it is (else the error
    names the first alternative that refused it: 'should be a valid boolean')."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError("give a finite number")
    if isinstance(value, bool | int | float | str):
        return value
    kind = {dict: "mapping", list: "list", type(None): "empty value"}.get(type(value), type(value).__name__)
    raise ValueError(f"give text, a number or a boolean, not a {kind}")


ParameterValue = Annotated[bool | int | float | str, BeforeValidator(_scalar)]
"""A program's parameter value as YAML gives it; ``bool`` first, or ``true`` would be
read as the number 1 (pydantic's lax mode takes a boolean for a number)."""


class ParameterGrid(_Axis):
    """The values of one of a program's parameters: numbers, text (``[fast, accurate]``)
    or booleans (``[true, false]``); each reaches the program as ``parameter_text`` spells it."""

    _key = "grid"
    grid: list[ParameterValue] = Field(min_length=1, max_length=10_000)


EnvValue = ParameterValue
"""An ``env:`` value as YAML gives it; the program gets it as text (``env_text``)."""


def env_text(value: EnvValue) -> str:
    """An environment value as the OS takes it (text): a boolean as YAML and JSON spell it
    (``true``), a whole number without a point, any other number as Python writes it
    (``1.5e3`` is ``1500.0``: quote a value whose spelling matters)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return value if isinstance(value, str) else str(value)


class Range(_Axis):
    _key = "range"
    range: tuple[float, float, float]

    @field_validator("range")
    @classmethod
    def _steps(cls, value: tuple[float, float, float]) -> tuple[float, float, float]:
        """A check of the field, not the model, so that its error lies deeper than the
        other kinds' (see ``_Axis``)."""
        start, stop, step = value
        if not all(math.isfinite(v) for v in value) or step <= 0 or stop < start:
            raise ValueError("range is [start, stop, step] with start <= stop and step > 0")
        if (stop - start) / step > 10_000:
            raise ValueError("range has more than 10,000 values")
        return value

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


class Random(_Axis):
    _key = "random"
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
    """An Optuna search over one strategy's thresholds, or over one external tracker's
    parameters (``tracker:``; then ``strategy`` is what it runs with, none or mask)
    (extra [search])."""

    strategy: str = "none"
    tracker: str | None = None
    space: dict[str, Interval] = Field(min_length=1)
    trials: int = Field(default=30, ge=1, le=10_000)
    seed: int = Field(default=0, ge=0)
    objective: str = Field(default="mean_ate", pattern="^(mean_ate|ate_time)$")
    """mean_ate: mean ATE RMSE (m) over the sweep's runs of a trial; ate_time: that plus
    ``time_weight`` x the mean of their median tracking ms."""
    time_weight: float = Field(default=0.0001, ge=0.0)

    @model_validator(mode="after")
    def _strategy(self) -> Search:
        if self.tracker is not None:
            if self.strategy not in EXTERNAL_STRATEGIES:
                raise ValueError(
                    f"search.strategy: a tracker's search runs with {' or '.join(EXTERNAL_STRATEGIES)}"
                )
        elif self.strategy not in STRATEGY_CHOICES or self.strategy in ("none", "mask"):
            raise ValueError(f"search.strategy {self.strategy!r} has no thresholds to search")
        return self


class TrackerEntry(Strict):
    """An external tracker of a sweep: a program (``kind: cmd``) or ORB-SLAM3, by name,
    with its own parameters (docs/external-trackers.md)."""

    name: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    kind: str = "cmd"
    """An external tracker kind of the registry (``registry.EXTERNAL``: cmd, orbslam3)."""
    command: str | None = None
    """``cmd``: the command template, run without a shell; a program with a slash is
    relative to the spec file."""
    parameters: dict[str, ParameterValue] = Field(default_factory=dict)
    """The parameters' default values (numbers, text or booleans); ``parameters:`` of the
    spec sweeps them."""
    settings: str | None = None
    """``cmd``: a Jinja2 settings template (relative to the spec file)."""
    timeout_s: float = Field(default=3600.0, gt=0.0, le=7 * 86400.0)
    env: dict[str, EnvValue] = Field(default_factory=dict)
    """``cmd``: variables added to the program's environment; numbers and booleans are
    written as text (``env_text``)."""
    vocabulary: str | None = None

    @model_validator(mode="after")
    def _fits(self) -> TrackerEntry:
        if self.kind not in EXTERNAL:
            raise ValueError(f"kind: {self.kind!r} is not one of {', '.join(EXTERNAL)}")
        if self.name in TRACKERS:
            raise ValueError(f"name {self.name!r} is a tracker kind; give your tracker a name of its own")
        takes_command = TRACKERS[self.kind].command
        if takes_command and not self.command:
            raise ValueError(f"command: a {self.kind} tracker needs its command template")
        if not takes_command and (self.command or self.settings):
            raise ValueError(
                f"{self.kind} takes no command or settings template (its settings are parameters)"
            )
        return self

    @field_validator("env")
    @classmethod
    def _environment(cls, env: dict[str, Any]) -> dict[str, Any]:
        """Checked as a field, so that its error is placed at ``env`` (an error of the
        whole entry ties with the ``str`` alternative of ``trackers``, which would win)."""
        for name in env:
            if not name or "=" in name or "\0" in name:
                raise ValueError(f"{name!r} is not an environment variable name")
        return env  # a NUL in a value is refused with the command's (``command._refuse_nul``)


class Statistics(Strict):
    """How runs over seeds are judged: a run succeeds when it did not fail and tracked at
    least ``min_tracked_fraction`` of its frames; the best configuration of a family is
    chosen among those that succeeded on at least ``best_min_success_rate`` of its runs."""

    min_tracked_fraction: float = Field(default=0.9, ge=0.0, le=1.0)
    best_min_success_rate: float = Field(default=1.0, ge=0.0, le=1.0)


class DetectorEntry(Strict):
    detector: str = "groundtruth"
    settings: dict[str, str | float | int] = Field(default_factory=dict)
    faults: dict[str, str | float | int] = Field(default_factory=dict)
    class_priors: dict[str, str] = Field(default_factory=dict)


class BaselineEntry(Strict):
    """``baseline:``: the configuration every rho is taken against, in place of each run's own
    ``none`` (``figures.Baseline``). The fields given must pick one run on each sequence:

    ```yaml
    baseline: {tracker: orbslam3}                       # the real ORB-SLAM3 as the baseline
    baseline: {tracker: my_slam, parameters: {reject: 0}}   # a program with its rejection off
    baseline: {strategy: box_rule, settings: {}}        # the box rule at its defaults
    ```
    """

    tracker: str | None = None
    parameters: dict[str, float | int | bool | str] | None = None
    detector: str | None = None
    strategy: str | None = None
    settings: dict[str, float | int | bool] | None = None

    @model_validator(mode="after")
    def _names_something(self) -> BaselineEntry:
        if all(
            v is None for v in (self.tracker, self.parameters, self.detector, self.strategy, self.settings)
        ):
            raise ValueError("name the baseline's tracker, parameters, detector, strategy and/or settings")
        return self

    def to_baseline(self) -> Baseline:
        parameters = self.parameters
        settings = self.settings
        return Baseline(
            self.tracker,
            None
            if parameters is None
            else tuple(sorted((k, parameter_text(v)) for k, v in parameters.items())),
            self.detector,
            self.strategy,
            None
            if settings is None
            else tuple(sorted((k, threshold_value(k, v)) for k, v in settings.items())),
        )


class SweepSpec(Strict):
    sweep: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    description: str = ""
    suite: str | None = None
    sequences: list[str] = Field(default_factory=list, max_length=10_000)
    trackers: list[str | TrackerEntry] = Field(default_factory=lambda: ["builtin"], min_length=1)
    detectors: list[str | DetectorEntry] = Field(default_factory=lambda: ["groundtruth"], min_length=1)
    strategies: list[str] = Field(default_factory=lambda: ["none"], min_length=1)
    thresholds: dict[str, dict[str, Grid | Range | Random]] = Field(default_factory=dict)
    parameters: dict[str, dict[str, ParameterGrid | Range | Random]] = Field(default_factory=dict)
    """By tracker name: values of that external tracker's parameters to sweep (a grid may
    hold text and booleans as well as numbers)."""
    search: Search | None = None
    statistics: Statistics = Field(default_factory=Statistics)
    baseline: BaselineEntry | None = None
    """The configuration rho is taken against; each run's own ``none`` where not given."""
    dense_map: bool = False
    """Also build each built-in run's dense map and score it against the exact static world
    (``eval/run/dense.py``): rows then carry map_f_score, map_accuracy, map_completeness and
    ghost_fraction, and gates may bound them."""

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
        names = [t if isinstance(t, str) else t.name for t in self.trackers]
        if len(set(names)) != len(names):
            raise ValueError("trackers: two trackers of one name")
        entries = {t.name: t for t in self.trackers if isinstance(t, TrackerEntry)}
        for tracker, axes in self.parameters.items():
            if tracker not in entries:
                raise ValueError(f"parameters for {tracker!r}, which is not a named tracker of this sweep")
            if entries[tracker].kind == "cmd":
                undeclared = sorted(set(axes) - set(entries[tracker].parameters))
                if undeclared:
                    raise ValueError(
                        f"parameters.{tracker}.{undeclared[0]}: not a parameter of {tracker} "
                        "(declare it, with its default, under the tracker's parameters)"
                    )
        baseline = self.baseline
        if baseline is not None and baseline.tracker is not None and baseline.tracker not in names:
            raise ValueError(
                f"baseline.tracker {baseline.tracker!r} is not a tracker of this sweep ({', '.join(names)})"
            )
        if (
            baseline is not None
            and baseline.strategy is not None
            and baseline.strategy not in self.strategies
        ):
            raise ValueError(f"baseline.strategy {baseline.strategy!r} is not among the strategies")
        if self.search is not None and self.search.tracker is not None and self.search.tracker not in entries:
            raise ValueError(f"search.tracker {self.search.tracker!r} is not a named tracker of this sweep")
        return self


@dataclass(frozen=True)
class Variant:
    """One strategy with one set of threshold values."""

    strategy: str
    settings: tuple[tuple[str, Setting], ...]
    """Threshold values by name, typed as their fields are (``threshold_value``)."""


def threshold_value(name: str, value: float) -> Setting:
    """A spec's number for threshold ``name`` as its field holds it (8.0 for a whole-number
    field is 8). A name or value the field refuses stays as given: ``check_variants`` names
    it with its place in the spec."""
    try:
        return setting_value(name, value)
    except ConfigError:
        return value


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
                Variant(
                    strategy, tuple((n, threshold_value(n, v)) for n, v in zip(names, combo, strict=True))
                )
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


def tracker_count(spec: SweepSpec) -> int:
    """How many tracker configurations ``tracker_variants`` would list (each named tracker
    once per combination of its swept parameters), counted without listing them."""
    return sum(
        math.prod(_count(axis) for axis in spec.parameters.get(_name(entry), {}).values())
        for entry in spec.trackers
    )


def _name(entry: str | TrackerEntry) -> str:
    return entry if isinstance(entry, str) else entry.name


def _count(axis: Grid | ParameterGrid | Range | Random) -> int:
    if isinstance(axis, Grid | ParameterGrid):
        return len(axis.grid)
    if isinstance(axis, Range):
        start, stop, step = axis.range
        return int(math.floor((stop - start) / step + 1e-9)) + 1
    return axis.random.samples


def _values(axis: Grid | ParameterGrid | Range | Random) -> list:
    if isinstance(axis, Grid | ParameterGrid):
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
    """The trackers with their parameters' default values, each checked (an external
    program's template, program and parameter names; ORB-SLAM3's settings), before any run.
    Paths (a program with a slash, a settings template, a vocabulary) are relative to the
    spec file, as every path of a spec is."""
    folder = Path(source).parent
    out = []
    for i, entry in enumerate(spec.trackers):
        if isinstance(entry, str):
            bare = [name for name, t in TRACKERS.items() if not t.command]
            if entry not in TRACKERS:
                raise SpecError(
                    f"{source}: trackers.{i}: {entry!r} is not {' or '.join(bare)} (an external program "
                    "is given as a mapping: name, command, parameters)"
                )
            if TRACKERS[entry].command:
                raise SpecError(
                    f"{source}: trackers.{i}: a {entry} tracker needs a name and a command (a mapping)"
                )
            out.append(TrackerConfig(entry))
            continue
        try:
            parameters = _parameter_defaults(entry)
        except InputError as exc:
            raise SpecError(f"{source}: trackers.{i} ({entry.name}): {exc}") from None
        config = TrackerConfig(
            entry.kind,
            command=_program_beside(folder, entry.command) if entry.command else None,
            vocabulary=_beside(folder, entry.vocabulary) if entry.vocabulary else None,
            timeout_s=entry.timeout_s,
            name=entry.name,
            parameters=parameters,
            settings_template=_beside(folder, entry.settings) if entry.settings else None,
            env=tuple(sorted((name, env_text(value)) for name, value in entry.env.items())),
        )
        try:
            check_tracker(config)
        except InputError as exc:
            raise SpecError(f"{source}: trackers.{i} ({entry.name}): {exc}") from None
        out.append(config)
    return out


def _parameter_defaults(entry: TrackerEntry) -> tuple[tuple[str, str], ...]:
    given = {
        name: value if isinstance(value, str) else parameter_text(value)
        for name, value in entry.parameters.items()
    }
    if entry.kind == "orbslam3":
        from depotbench.eval.trackers.orbslam3 import known_parameters

        unknown = sorted(set(given) - set(known_parameters()))
        if unknown:
            raise InputError(
                f"unknown ORB-SLAM3 parameter {unknown[0]!r}; known: {', '.join(known_parameters())}"
            )
    return tracker_parameters(entry.kind, given)


def _program_beside(folder: Path, command: str) -> str:
    """The command with a program given by a relative path with a slash made absolute from
    the spec's folder (a placeholder or a bare name is left to the run)."""
    try:
        words = shlex.split(command)
    except ValueError:
        return command  # the template's own check names the problem
    if not words or "/" not in words[0] or words[0].startswith("{") or Path(words[0]).is_absolute():
        return command
    return shlex.join([str(folder.resolve() / words[0]), *words[1:]])


def tracker_variants(spec: SweepSpec, trackers: list[TrackerConfig], source: str) -> list[TrackerConfig]:
    """Each tracker once per combination of its swept parameters (``parameters:``), in a
    stable order; every value checked as the tracker takes it."""
    out = []
    for config in trackers:
        axes = spec.parameters.get(config.label, {})
        names = sorted(axes)
        for combo in itertools.product(*(_values(axes[n]) for n in names)) if names else [()]:
            swept = {n: parameter_text(v) for n, v in zip(names, combo, strict=True)}
            parameters = tracker_parameters(config.kind, dict(config.parameters) | swept)
            variant = replace(config, parameters=parameters)
            if names:
                try:
                    check_tracker(variant)
                except InputError as exc:
                    raise SpecError(f"{source}: parameters.{config.label}: {exc}") from None
            out.append(variant)
    return out


def unknown_thresholds(spec: SweepSpec, source: str) -> list[str]:
    """A line per threshold name that is no setting, naming it where the spec has it (a
    ``--set`` flag's message would name a flag the user never typed)."""
    known = setting_names()
    return [
        f"{source}: thresholds.{strategy}.{name}: unknown setting (known: {', '.join(known)})"
        for strategy, axes in spec.thresholds.items()
        for name in axes
        if name not in known
    ]


def check_variants(spec: SweepSpec, found: list[Variant], trackers: list[TrackerConfig], source: str) -> None:
    """Every value against the SLAM configuration and the trackers, before anything runs."""
    unknown = unknown_thresholds(spec, source)
    if unknown:
        raise SpecError("\n".join(unknown))
    builtin = any(t.type.per_keypoint for t in trackers)
    for strategy in spec.strategies:
        if not builtin and strategy not in EXTERNAL_STRATEGIES:
            names = ", ".join(t.kind for t in trackers)
            raise SpecError(
                f"{source}: strategies: {strategy} needs the built-in tracker (it decides per keypoint); "
                f"trackers {names} take {' or '.join(EXTERNAL_STRATEGIES)}"
            )
    for variant in found:
        for tracker in trackers:
            if not tracker.type.per_keypoint and variant.strategy not in EXTERNAL_STRATEGIES:
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
    if spec.search.tracker is not None:
        base = next(t for t in trackers if t.label == spec.search.tracker)
        for name, interval in sorted(spec.search.space.items()):
            if base.type.command and name not in dict(base.parameters):
                raise SpecError(f"{source}: search.space.{name}: not a parameter of {base.label}")
            for value in (interval.low, interval.high):
                values = dict(base.parameters) | {name: parameter_text(value)}
                try:
                    check_tracker(replace(base, parameters=tracker_parameters(base.kind, values)))
                except InputError as exc:
                    raise SpecError(f"{source}: search.space.{name}: {exc}") from None
        return
    kinds = {t.kind for t in trackers}
    for name, interval in sorted(spec.search.space.items()):
        for value in (interval.low, interval.high):
            for kind in kinds:
                try:
                    slam_config(spec.search.strategy, {name: threshold_value(name, value)}, kind)
                except InputError as exc:
                    reason = str(exc).removeprefix("--set: ")
                    raise SpecError(f"{source}: search.space.{name}: {reason}") from None


def load_sweep(path: Path) -> SweepSpec:
    return load_model(SweepSpec, path)


def resolve(spec: SweepSpec, path: Path, name: str) -> Path:
    """A path of the spec, relative to the spec's folder."""
    candidate = Path(name).expanduser()
    return candidate if candidate.is_absolute() else path.parent / candidate
