"""The options that choose a tracker and its configuration, read once: ``run`` and
``benchmark run`` take the same ones."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from depotbench.core.errors import InputError
from depotbench.eval.cli import choices
from depotbench.eval.cli.args import positive_float
from depotbench.eval.cli.detectors import pairs
from depotbench.eval.trackers.placeholders import PLACEHOLDERS
from depotbench.eval.trackers.registry import TRACKERS  # data only: imports no tracker

if TYPE_CHECKING:
    from depotbench.eval.trackers.registry import TrackerConfig
    from depotbench.slam.config import Setting

COMMAND_PLACEHOLDERS = " ".join(f"{{{name}}}" for name in PLACEHOLDERS)
"""Every placeholder of the external-program protocol, as ``run --help`` lists them."""


def add_tracker_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--slam",
        choices=list(TRACKERS),
        default="builtin",
        help="the tracker (default: builtin): "
        + "; ".join(f"{name}: {t.summary}" for name, t in TRACKERS.items()).replace("%", "%%"),
    )
    p.add_argument(
        "--strategy",
        choices=choices.STRATEGIES,
        default="none",
        help="dynamic-feature rejection; 'mask' blanks dynamic boxes in RGB and depth before the "
        "tracker sees the frames (any tracker); the others are the built-in tracker's",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a threshold, e.g. --set k=2.5 --set epsilon_px=0.8 (repeatable)",
    )
    p.add_argument(
        "--name",
        help="--slam cmd: what results, tables and the leaderboard call the program (default: cmd)",
    )
    p.add_argument(
        "--command",
        metavar="TEMPLATE",
        help=f"--slam cmd: the program and its arguments, with {COMMAND_PLACEHOLDERS} and {{NAME}} of each "
        "--param as whole words, run without a shell (a shell script takes them as arguments, "
        '"$1", or from $DEPOTBENCH_SEQUENCE and the like; docs/external-trackers.md)',
    )
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="--slam cmd: a parameter of the program, as {NAME} in the template, in {parameters} and "
        "in the settings template; --slam orbslam3: one of its settings, e.g. ThDepth=50 or "
        "ORBextractor.nFeatures=1500 (repeatable)",
    )
    p.add_argument(
        "--settings-template",
        type=Path,
        metavar="FILE",
        help="--slam cmd: a Jinja2 template rendered to {settings} with camera, params and "
        "orbslam_camera (docs/external-trackers.md)",
    )
    p.add_argument(
        "--vocabulary",
        type=Path,
        help="--slam orbslam3|cmd: a DBoW2 text vocabulary (default: the bench's, built once)",
    )
    p.add_argument(
        "--timeout",
        type=positive_float,
        default=3600.0,
        help="--slam orbslam3|cmd: seconds before the program is stopped (default: 3600)",
    )


def tracker_from_args(args: argparse.Namespace) -> tuple[TrackerConfig, dict[str, Setting]]:
    """The tracker the options name, checked (an option its kind does not take is refused),
    and the built-in thresholds of ``--set``, typed."""
    from depotbench.eval.trackers.registry import TrackerConfig, tracker_parameters, tracker_type
    from depotbench.eval.trackers.registry import check as check_tracker
    from depotbench.slam.config import ConfigError, parse_settings

    try:  # the one place --set's text becomes values
        settings = parse_settings(args.set)
    except ConfigError as exc:
        raise InputError(f"--set: {exc}") from None
    kind = tracker_type(args.slam)

    def takers(flag: str) -> str:
        return " and ".join(name for name, t in TRACKERS.items() if getattr(t, flag))

    if args.command is not None and not kind.command:
        raise InputError(f"--command applies to --slam {takers('command')} only")
    if args.vocabulary is not None and not kind.vocabulary:
        raise InputError(f"--vocabulary applies to --slam {takers('vocabulary')} only")
    if args.vocabulary is not None:
        from depotbench.eval.trackers.vocabulary import vocabulary_problem

        if (problem := vocabulary_problem(args.vocabulary)) is not None:
            raise InputError(f"{args.vocabulary}: {problem}")
    if args.param and not kind.parameters:
        raise InputError(
            f"--param applies to --slam {takers('parameters')} (the built-in tracker takes --set)"
        )
    if args.name is not None and not kind.command:
        raise InputError(f"--name applies to --slam {takers('command')} only")
    if args.name is not None and not (args.name.strip() and args.name.isprintable() and len(args.name) <= 60):
        raise InputError(f"--name {args.name!r}: give a name of 1 to 60 printable characters")
    if args.settings_template is not None and not kind.command:
        raise InputError(f"--settings-template applies to --slam {takers('command')} only")
    tracker = TrackerConfig(
        kind.name,
        args.command,
        args.vocabulary,
        args.timeout,
        name=args.name or "",
        parameters=tracker_parameters(kind.name, pairs(args.param, "--param")),
        settings_template=args.settings_template,
    )
    check_tracker(tracker)
    return tracker, settings
