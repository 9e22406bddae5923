"""The trackers the bench can run, in one table that the command line, sweep specs, gate
files and the run read: a new tracker is its module (with ``build`` and ``check``) and its
entry in ``TRACKERS``.

An entry is data, so reading the table imports no tracker: the command line's ``--help``
stays fast, and ORB-SLAM3's wheel is only touched when it runs.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError


@dataclass(frozen=True)
class TrackerType:
    name: str
    """The kind as specs and ``--slam`` name it."""
    module: str
    """The module holding ``build(tracker, config, progress, stages)`` and
    ``check(tracker, camera_sequence)`` (and, when it has parameters of its own,
    ``default_parameters()`` and ``canonical_parameters(values)`` where a value has more
    than one spelling)."""
    summary: str
    per_keypoint: bool
    """It is the bench's own pipeline: it decides per keypoint, so it takes every rejection
    strategy and threshold, and its features and flow are cacheable stages; the others take
    the bench's boxes (``none``) or its masks (``mask``) only."""
    external: bool
    """It runs another program: keyed by that program's bytes, a failure of it is a failed
    row (not ours to raise), and its runs may not repeat themselves bit for bit."""
    command: bool = False
    """It takes a command template and a Jinja2 settings template."""
    vocabulary: bool = False
    """It takes a DBoW2 vocabulary (the bench builds one from generated frames)."""
    parameters: bool = False
    """It takes its own parameters (``--param``, a spec's ``parameters:``)."""
    maps: bool = False
    """Its runs carry a map to score (``--map``): the built-in dense map, ORB-SLAM3's map points."""


TRACKERS: dict[str, TrackerType] = {
    t.name: t
    for t in (
        TrackerType(
            "builtin",
            "depotbench.eval.trackers.builtin",
            "the bench's ORB-SLAM2-style RGB-D pipeline with every rejection strategy",
            per_keypoint=True,
            external=False,
            maps=True,
        ),
        TrackerType(
            "orbslam3",
            "depotbench.eval.trackers.orbslam3",
            "the real ORB-SLAM3 (extra [orbslam3], GPL-3), run in a process of its own",
            per_keypoint=False,
            external=True,
            vocabulary=True,
            parameters=True,
            maps=True,
        ),
        TrackerType(
            "cmd",
            "depotbench.eval.trackers.command",
            "any SLAM program, through a command template (docs/external-trackers.md)",
            per_keypoint=False,
            external=True,
            command=True,
            vocabulary=True,
            parameters=True,
        ),
    )
}
BUILTIN = "builtin"
EXTERNAL = tuple(name for name, t in TRACKERS.items() if t.external)


def tracker_type(name: str) -> TrackerType:
    try:
        return TRACKERS[name]
    except KeyError:
        raise InputError(f"unknown tracker {name!r}; choose one of {', '.join(TRACKERS)}") from None


@dataclass(frozen=True)
class TrackerConfig:
    """Which tracker runs, and what an external one needs."""

    kind: str = BUILTIN
    """A ``TRACKERS`` name."""
    command: str | None = None
    """``cmd``: the command template (see ``depotbench.eval.trackers.command``)."""
    vocabulary: Path | None = None
    """A DBoW2 text vocabulary for trackers that take one; the bench's default one if None."""
    timeout_s: float = 3600.0
    name: str = ""
    """What rows, tables and gates call it: a sweep's name for it, else the kind."""
    parameters: tuple[tuple[str, str], ...] = ()
    """An external tracker's parameter values for this run, by name, sorted (the program's
    own, or ORB-SLAM3's settings)."""
    settings_template: Path | None = None
    """``cmd``: a Jinja2 template rendered to ``{settings}`` (else ORB-SLAM settings)."""
    env: tuple[tuple[str, str], ...] = ()
    """``cmd``: variables added to the program's environment."""

    def __post_init__(self) -> None:
        tracker_type(self.kind)

    @property
    def type(self) -> TrackerType:
        return TRACKERS[self.kind]

    @property
    def label(self) -> str:
        return self.name or self.kind


def _module(tracker: TrackerConfig):
    return importlib.import_module(tracker.type.module)


def build(tracker: TrackerConfig, config: Any, progress: bool, stages: list | None = None) -> Any:
    """The tracker of a configuration, ready to run (``config``: the SLAM configuration;
    ``stages``: cached features and flow, for the bench's pipeline)."""
    return _module(tracker).build(tracker, config, progress, stages)


def check(tracker: TrackerConfig, camera_sequence: Any = None) -> None:
    """Refuse, before any run, a tracker that cannot run (``camera_sequence``: a sequence
    whose camera a settings template is rendered with)."""
    _module(tracker).check(tracker, camera_sequence)


def tracker_parameters(kind: str, given: Mapping[str, str]) -> tuple[tuple[str, str], ...]:
    """A run's parameters, sorted: the kind's defaults overridden by ``given``, each spelled
    as the kind keys it. ORB-SLAM3's are numbers, so ``pace=1``, ``pace=1.0`` and a spec's
    ``pace: 1`` are one value and one run; a program's (``cmd``) are its own text."""
    module = importlib.import_module(tracker_type(kind).module)
    values = dict(module.default_parameters()) if hasattr(module, "default_parameters") else {}
    values |= given
    if hasattr(module, "canonical_parameters"):
        values = module.canonical_parameters(values)
    return tuple(sorted(values.items()))
