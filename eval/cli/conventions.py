"""What every ``depotbench`` command shares, as users of evo, pytest and ROS tools expect:
a description and examples in each command's help, ``-v``/``-q``, ``--version``, and the
library's log messages on stderr.

Kept free of heavy imports: ``depotbench --help`` builds every parser, and must print in a
fraction of a second (0.1-0.2 s here, against 3-4 s when the parsers imported NumPy).
"""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import dataclass
from pathlib import PurePath
from typing import Any, NoReturn

from depotbench.core.logs import DETAIL


@dataclass(frozen=True)
class Usage:
    """A command's description (what it does and what it writes) and examples, as its
    ``--help`` shows them."""

    description: str
    examples: tuple[str, ...]


USAGE: dict[str, Usage] = {
    "demo": Usage(
        "The main job in small: generate the demo suite, sweep every rejection strategy over it, "
        "check the demo gates and write the HTML report. Exit 1 when a budget fails.",
        ("depotbench demo", "depotbench demo -o runs/my-demo --workers 2"),
    ),
    "eval": Usage(
        "ATE and RPE of an estimated trajectory against a reference, both TUM files, with evo's "
        "association, alignment and statistics (tests hold the figures equal to evo's).",
        (
            "depotbench eval seq/groundtruth.txt run/trajectory.txt",
            "depotbench eval gt.txt est.txt --align sim3 --json",
        ),
    ),
    "generate": Usage(
        "Render a scenario (a library name or a file) or a whole suite (a shipped suite's name or a "
        "file) into sequence folders: "
        "RGB, depth, exact poses, instance masks and 2D boxes in the TUM RGB-D layout.",
        (
            "depotbench generate walking_xyz -o seqs/walking_xyz --seed 3 --frames 150",
            "depotbench generate demo -o seqs/demo --workers 2",
        ),
    ),
    "validate": Usage(
        "Lint any file the bench reads before a long run: scenarios, suites, sweep specs, gate files, "
        "camera files, TUM trajectories, sequence folders and results (the kind is recognised from "
        "what each holds). Every problem in one pass, each a line FILE:LINE: field: what is wrong; a "
        "sweep's matrix size and run count. Exit 2 if any file is invalid.",
        (
            "depotbench validate my_scene.yaml",
            "depotbench validate smallest walking-ci --json",
            "depotbench validate seqs/walking_xyz seqs/walking_xyz/camera.yaml runs/smallest",
        ),
    ),
    "scenarios": Usage(
        "List the library's named scenarios with their tags and descriptions.",
        ("depotbench scenarios", "depotbench scenarios --tag tum-like --json"),
    ),
    "examples": Usage(
        "List the sweep specs, gate files, suites and example trackers that ship with depotbench: "
        "sweep, check, generate and validate take each by its name (a path that exists wins over "
        "a name). 'examples copy' copies one, with the files it reads beside it, into a folder to "
        "edit and run there; it never replaces a file unless --overwrite.",
        (
            "depotbench examples",
            "depotbench examples copy smallest my-sweeps",
            "depotbench examples copy my_slam .",
            "depotbench examples copy --all examples --json",
        ),
    ),
    "run": Usage(
        "Track one sequence (generated, or any TUM-layout folder) with a tracker and a dynamic-feature "
        "rejection strategy; write the trajectory, diagnostics and metrics.json (ATE, RPE, rejection "
        "precision and recall, stage times, the camera used). A real folder's camera comes from --camera "
        "or the flags; without them, TUM's calibration by the folder's name or a default, with a warning.",
        (
            "depotbench run seqs/walking_xyz -o runs/xyz-none",
            "depotbench run seqs/walking_xyz -o runs/xyz-flow --strategy box_epipolar_flow --set k=2.5",
            "depotbench run seqs/walking_xyz -o runs/xyz-mine --slam cmd --command "
            '"./my_slam {sequence} {trajectory}" --json',
            "depotbench run my_tum_recording -o runs/mine --camera orbslam_settings.yaml",
            "depotbench run my_recording -o runs/mine --intrinsics 525 525 319.5 239.5 --depth-factor 5000",
        ),
    ),
    "preview": Usage(
        "Save RGB | depth | instances with boxes of chosen frames as one PNG.",
        ("depotbench preview seqs/walking_xyz --frames 0 40 80 -o preview.png",),
    ),
    "vocab": Usage(
        "Build an ORB vocabulary (DBoW2 text, as ORB-SLAM reads it) from frames of depot scenes; "
        "without -o it goes to the cache, where --slam orbslam3 finds it.",
        ("depotbench vocab", "depotbench vocab -o orb_vocab.txt --branching 10 --levels 5"),
    ),
    "detect-eval": Usage(
        "Score a detector's boxes against the sequences' exact boxes: AP50, precision and recall per "
        "class (as pycocotools computes them), COCO's class names matched to the bench's.",
        (
            "depotbench detect-eval seqs/walking_xyz --detector onnx",
            "depotbench detect-eval seqs/* --detector onnx --json",
            "depotbench detect-eval seqs/* --detector onnx -o detections.json",
        ),
    ),
    "export-dataset": Usage(
        "Export generated sequences as a YOLO dataset (images, labels, data.yaml) that training tools "
        "read from any working directory, class ids in COCO's order.",
        ("depotbench export-dataset seqs/* -o datasets/depot --every 5",),
    ),
    "export-rosbag": Usage(
        "Write a generated sequence or a real TUM RGB-D folder as a rosbag2 folder (MCAP or SQLite), no "
        "ROS installation needed: colour (rgb8) and depth images with their camera info on NAMESPACE/color "
        "and NAMESPACE/depth, stamped with the frames' timestamps in the camera's optical frame; the true "
        "poses of groundtruth.txt on /tf (world -> optical frame), /ground_truth/pose and, once and "
        "latched, /ground_truth/path; with --detections the ground-truth boxes as "
        "vision_msgs/Detection2DArray. Depth is 32FC1 metres by default (REP 118). A real folder's camera "
        "is its camera.yaml or given as for run (--camera FILE, --intrinsics ...), never guessed. The bag is "
        "written beside BAG and moved into place when complete; play it with 'ros2 bag play BAG' "
        "(docs/rosbag.md).",
        (
            "depotbench export-rosbag seqs/walking_xyz -o bags/walking_xyz",
            "depotbench export-rosbag seqs/walking_xyz -o bags/walking_xyz --detections --storage sqlite3",
            "depotbench export-rosbag rgbd_dataset_freiburg3_walking_xyz -o bags/fr3_walking_xyz --compress "
            "--intrinsics 535.4 539.2 320.1 247.6",
        ),
    ),
    "sweep": Usage(
        "Run a threshold sweep (a YAML spec) into a resumable SQLite database, with results.csv, "
        "summary.json (the best configuration per family, the Pareto front) and plots.",
        (
            "depotbench sweep smallest -o runs/smallest",
            "depotbench sweep my-sweeps/smallest.yaml -o runs/mine --workers 2 --json",
        ),
    ),
    "check": Usage(
        "Run a gate file's matrix and check its budgets, for CI: exit 1 naming each failed budget, "
        "optionally JUnit XML.",
        (
            "depotbench check walking-ci --junit gates.xml",
            "depotbench check my-gates.yaml --baseline runs/main --json",
        ),
    ),
    "report": Usage(
        "Write a self-contained HTML page of a run folder or a sweep folder (plots, trajectories, "
        "frames with keypoints by decision), optionally a Rerun recording of a run.",
        (
            "depotbench report runs/smallest -o runs/smallest/report",
            "depotbench report runs/xyz-flow -o runs/xyz-flow/report --rerun xyz.rrd",
        ),
    ),
    "compare": Usage(
        "Compare result sets against the first one. Runs are paired by sequence; a change is marked * "
        "where the paired test says it is real (two-sided p < 0.05).",
        (
            "depotbench compare runs/main runs/branch",
            "depotbench compare runs/main runs/branch --fail-on-regression --tolerance 0.05 --json",
        ),
    ),
    "benchmark": Usage(
        "Frozen, named benchmarks (docs/benchmarks.md): a shipped set of sequences keyed to the byte, "
        "one tracker configuration scored on every sequence (a tracker that is not deterministic "
        "at least 3 times each), a results file anyone can recompute, and the papers' tables "
        "against any results file as the baseline.",
        (
            "depotbench benchmark list",
            "depotbench benchmark run smoke-1 -o bench/none",
            "depotbench benchmark run tum-dyn-1 -o bench/flow --strategy box_epipolar_flow --detector onnx",
            "depotbench benchmark run tum-dyn-1 -o bench/orb --slam orbslam3 --repeats 5",
            "depotbench benchmark run tum-dyn-1 -o bench/mine --slam cmd --command './my_slam {sequence} "
            "{trajectory}' --not-deterministic",
            "depotbench benchmark table bench/flow bench/orb --baseline bench/none -o tables/tum",
            "depotbench benchmark verify bench/flow",
        ),
    ),
    "cache": Usage(
        "Show or clear depotbench's caches: the tracking stages (detections, features, flow), the "
        "generated sequences and the ORB vocabularies. They live under one root, "
        "$XDG_CACHE_HOME/depotbench (~/.cache/depotbench); DEPOTBENCH_CACHE moves it (an absolute "
        "folder) or switches every cache off (off), DEPOTBENCH_CACHE_STAGES, _SEQUENCES and "
        "_VOCABULARY do the same for one cache, and DEPOTBENCH_CACHE_STAGES_MAX_BYTES and "
        "DEPOTBENCH_CACHE_SEQUENCES_MAX_BYTES bound the first two.",
        ("depotbench cache info", "depotbench cache info --json", "depotbench cache clear --stage"),
    ),
    "completion": Usage(
        "Print a shell completion script for bash or zsh.",
        (
            "depotbench completion bash > ~/.local/share/bash-completion/completions/depotbench",
            "depotbench completion zsh > ~/.zfunc/_depotbench  # with fpath+=(~/.zfunc) in .zshrc",
        ),
    ),
}


def describe(name: str, parser: argparse.ArgumentParser) -> None:
    """Give a command's ``--help`` its description and examples (``USAGE``)."""
    usage = USAGE[name]
    parser.description = usage.description
    parser.epilog = "examples:\n" + "\n".join(f"  {example}" for example in usage.examples)
    parser.formatter_class = argparse.RawDescriptionHelpFormatter


class Parser(argparse.ArgumentParser):
    """argparse with its errors in one line, as every other error of the command line, and
    said in the name of the parser they belong to (``depotbench run: error: ...``).

    argparse hands an option a command does not know back to the top parser, which then says
    ``depotbench: error: unrecognized arguments`` and points to the wrong ``--help``; and a
    missing positional hid a mistyped option (``run --bogus`` said "SEQUENCE is required").
    So each parser first reads its words with nothing required: anything left over is
    refused there, by name; the second, ordinary reading then reports what is missing."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        words = list(sys.argv[1:] if args is None else args)
        required = [action for action in self._actions if action.required]
        for action in required:
            action.required = False
        try:
            _, extras = super().parse_known_args(words, argparse.Namespace())
        finally:
            for action in required:
                action.required = True
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return super().parse_known_args(words, namespace)


def add_version(parser: argparse.ArgumentParser) -> None:
    """``--version`` before or after the command's name (``depotbench run --version``), as the
    README promises; the version is read when asked (installed metadata, not at import)."""
    parser.add_argument("--version", action=_Version, nargs=0, help="print the version and exit")


class _Version(argparse.Action):
    def __call__(self, parser, namespace, values, option_string=None) -> NoReturn:
        from depotbench.core.version import package_version

        print(f"depotbench {package_version()}")  # on stdout, as argparse's own version action
        parser.exit(0)


def add_verbosity(parser: argparse.ArgumentParser, *, top: bool) -> None:
    """``-v`` (repeatable) and ``-q``, before or after the command's name. A command's parser
    counts its own ``-v`` apart (``verbose_command``) and leaves ``-q`` unset unless given, so
    that ``depotbench -v run -v`` is ``-vv`` and ``depotbench -q run`` is not undone by
    ``run``'s defaults (argparse reads a command's words into a namespace of their own)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "-v",
        "--verbose",
        action="count",
        dest="verbose" if top else "verbose_command",
        help="say more (on stderr): -v the steps' details (workers, times, programs' command "
        "lines), -vv debugging detail too (cache hits and misses with their keys)",
        **({"default": 0} if top else {"default": argparse.SUPPRESS}),
    )
    group.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="print nothing but errors (a result asked for with --json still prints)",
        **({"default": False} if top else {"default": argparse.SUPPRESS}),
    )


def verbosity(args: argparse.Namespace) -> int:
    """-1 for ``-q``, else the number of ``-v`` before and after the command's name."""
    if args.quiet:
        return -1
    return args.verbose + getattr(args, "verbose_command", 0)


class Messages(logging.Handler):
    """The library's log records as the command line prints them: ``depotbench VERB:
    warning: ...`` and ``... error: ...`` lines on stderr; status lines (INFO) on stdout
    beside the command's own output, or on stderr when stdout carries ``--json`` (it then
    holds nothing but the JSON); ``-v`` and ``-vv`` lines on stderr, as ``depotbench VERB:
    detail|debug: ...`` with the logger's name, so that they never mix with a result. The
    streams are looked up when a line is written (tests and callers replace ``sys.stdout``
    and ``sys.stderr``)."""

    def __init__(self) -> None:
        super().__init__(logging.NOTSET)
        self.verb = ""
        self.status_to_stderr = False

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if record.levelno >= logging.ERROR:
            line, stream = f"depotbench {self.verb}: error: {message}", sys.stderr
        elif record.levelno >= logging.WARNING:
            line, stream = f"depotbench {self.verb}: warning: {message}", sys.stderr
        elif record.levelno >= logging.INFO:
            line, stream = message, sys.stderr if self.status_to_stderr else sys.stdout
        else:
            kind = "detail" if record.levelno >= DETAIL else "debug"
            where = record.name.removeprefix("depotbench.")
            line, stream = f"depotbench {self.verb}: {kind}: [{where}] {message}", sys.stderr
        print(line, file=stream, flush=True)


MESSAGES = Messages()

LEVELS = {-1: logging.ERROR, 0: logging.INFO, 1: DETAIL}
"""``-q``, nothing, ``-v``; ``-vv`` and more: DEBUG."""


def show_messages(verb: str, verbosity: int, *, json: bool = False) -> int:
    """Route the ``depotbench`` logger's records to stderr at the level ``verbosity`` asks for
    (-1 for ``-q``; ``json``: stdout is the command's JSON). The library's status lines are
    INFO: a command line user sees them unless ``-q``, a library user only by asking
    (Python shows warnings alone by default); progress bars stop at ``-q`` too. Returns the
    level it replaced."""
    logger = logging.getLogger("depotbench")
    MESSAGES.verb = verb
    MESSAGES.status_to_stderr = json
    previous = logger.level
    logger.setLevel(LEVELS.get(verbosity, logging.DEBUG))
    if MESSAGES not in logger.handlers:
        logger.addHandler(MESSAGES)
    return previous


def add_json(parser: argparse.ArgumentParser, what: str) -> None:
    """``--json``: the command's result as one JSON object on stdout (``what`` it holds); its
    status lines then go to stderr (``show_messages``), so stdout parses as a whole."""
    parser.add_argument(
        "--json",
        action="store_true",
        help=f"print {what} as one JSON object, and nothing else on stdout",
    )


def print_result(args: argparse.Namespace, result: dict[str, Any], text: str) -> None:
    """A command's result: ``result`` as JSON with ``--json`` (paths as text that
    ``core.path_text`` reads back), else ``text`` for a reader."""
    if getattr(args, "json", False):
        from depotbench.core.files import dumps_json

        print(dumps_json(_json_paths(result)))
    elif text:
        print(text)


def _json_paths(value: Any) -> Any:
    from depotbench.core.path_text import path_text

    if isinstance(value, PurePath):
        return path_text(value)
    if isinstance(value, dict):
        return {key: _json_paths(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_json_paths(item) for item in value]
    return value
