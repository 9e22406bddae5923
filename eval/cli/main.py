"""The ``depotbench`` command line: thin entry points over the library.

A user's mistake (``InputError``) prints one line and exits with code 2; any
other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from depotbench.core.errors import InputError
from depotbench.core.processes import OutsideImports  # light: the handler is set before any heavy import
from depotbench.eval.cli.benchmark import add_benchmark
from depotbench.eval.cli.cache import add_cache
from depotbench.eval.cli.camera import add_camera_options, camera_from_args
from depotbench.eval.cli.compare import add_compare
from depotbench.eval.cli.conventions import (
    Parser,
    add_json,
    add_verbosity,
    add_version,
    describe,
    print_result,
    show_messages,
    verbosity,
)
from depotbench.eval.cli.detectors import (
    add_detect_eval,
    add_detector_options,
    add_export_dataset,
    detector_config,
)
from depotbench.eval.cli.examples import add_examples
from depotbench.eval.cli.gates import add_check
from depotbench.eval.cli.report import add_report
from depotbench.eval.cli.rosbag import add_export_rosbag
from depotbench.eval.cli.sweep import add_sweep
from depotbench.eval.cli.trackers import add_tracker_options, tracker_from_args

if TYPE_CHECKING:
    from depotbench.eval.metrics.accuracy import Statistics
    from depotbench.eval.metrics.evaluate import Comparison

from depotbench.eval.cli import choices
from depotbench.eval.cli.args import (
    WORKERS_HELP,
    backend_of,
    finite_float,
    one_per_core,
    positive_float,
    workers,
)

EXIT_INPUT_ERROR = 2
DEFAULT_PNG_COMPRESSION_LEVEL = 1
"""``depotbench.core.files.DEFAULT_PNG_COMPRESSION``, named here so that ``--help`` imports no numpy
(a test holds the two equal)."""
MAX_PREVIEW_FRAMES = 16
"""Rows of one preview picture (each 3 frames wide)."""
EXIT_INTERRUPTED = 128 + signal.SIGINT
EXIT_TERMINATED = 128 + signal.SIGTERM
EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE


def _add_eval(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="ATE and RPE of an estimated trajectory (TUM files), as evo")
    p.add_argument("reference", help="ground-truth trajectory (a TUM file, or a shipped one's name)")
    p.add_argument("estimate", help="estimated trajectory (a TUM file, or a shipped one's name)")
    p.add_argument(
        "--align",
        choices=choices.ALIGNMENTS,
        default="se3",
        help="Umeyama alignment of the estimate (default: se3)",
    )
    p.add_argument(
        "--max-diff",
        type=finite_float,
        default=choices.MAX_DIFF_S,
        help="association window in seconds (default: 0.02, TUM's)",
    )
    p.add_argument(
        "--t-offset", type=finite_float, default=0.0, help="seconds added to the estimate's stamps"
    )
    p.add_argument("--rpe-delta", type=positive_float, default=1.0, help="RPE delta (default: 1)")
    p.add_argument(
        "--rpe-unit",
        choices=choices.DELTA_UNITS,
        default="frames",
        help="unit of the RPE delta (default: frames)",
    )
    p.add_argument("--all-pairs", action="store_true", help="RPE over all pairs, not consecutive ones")
    p.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    p.set_defaults(handler=_cmd_eval)


def _cmd_eval(args: argparse.Namespace) -> int:
    from depotbench.core.examples import Kind, find
    from depotbench.core.files import dumps_json
    from depotbench.eval.metrics.accuracy import DeltaUnit
    from depotbench.eval.metrics.alignment import Alignment
    from depotbench.eval.metrics.evaluate import ComparisonOptions, compare
    from depotbench.eval.metrics.trajectory import read_tum

    options = ComparisonOptions(
        alignment=Alignment(args.align),
        max_diff_s=args.max_diff,
        offset_s=args.t_offset,
        rpe_delta=args.rpe_delta,
        rpe_unit=DeltaUnit(args.rpe_unit),
        rpe_all_pairs=args.all_pairs,
    )
    # A file, or a shipped trajectory's name (depotbench examples): a path that exists wins.
    reference, estimate = (find(name, Kind.TRAJECTORY) for name in (args.reference, args.estimate))
    result = compare(read_tum(reference), read_tum(estimate), options)
    if args.json:
        print(dumps_json(result.to_dict()))
    else:
        print(format_comparison(result))
    return 0


def format_comparison(result: Comparison) -> str:
    from depotbench.core.text_table import Column, render
    from depotbench.eval.metrics.alignment import Alignment

    o = result.options
    figures = ("rmse", "mean", "median", "std", "min", "max")

    def row(label: str, s: Statistics) -> list[str]:
        values = (s.rmse, s.mean, s.median, s.std, s.min, s.max)
        return [label, *(f"{v:.6f}" for v in values), str(s.count)]

    delta = f"{o.rpe_delta:g} {o.rpe_unit.value}{', all pairs' if o.rpe_all_pairs else ''}"
    table = render(
        [Column("", "left"), *(Column(f) for f in figures), Column("count")],
        [
            row("ATE (m)", result.ate.statistics),
            row("RPE trans (m)", result.rpe.translation),
            row("RPE rot (deg)", result.rpe.rotation_deg),
        ],
    )
    return "\n".join(
        [
            f"reference {result.reference_name}  estimate {result.estimate_name}",
            f"{result.pairs} associated pairs (window {o.max_diff_s} s), "
            f"alignment {o.alignment.value}"
            + (f" (scale {result.ate.transform.scale:.6f})" if o.alignment is Alignment.SIM3 else ""),
            table,
            f"RPE delta: {delta}",
        ]
    )


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="the main job in small: generate a suite, sweep every strategy, gate, write the HTML report",
    )
    p.add_argument("-o", "--output", type=Path, default=Path("runs/demo"), help="where to write")
    p.add_argument("--workers", type=workers, default=None, help=WORKERS_HELP)
    add_json(p, "the files written, the runs, the verdict and the failed budgets")
    p.set_defaults(handler=_cmd_demo)


DEMO_GATES = Path(__file__).resolve().parent.parent / "demo_gates.yaml"


def _cmd_demo(args: argparse.Namespace) -> int:
    """The README's first command: the sweep, the gates and the report of eval/demo_gates.yaml."""
    from depotbench.core.output import OutputContainer, OutputKind, write_text_atomic
    from depotbench.eval.gates.budgets import evaluate, format_report, junit_xml, load_gates
    from depotbench.eval.report.html import write_report
    from depotbench.eval.sweep.execute import execute_sweep
    from depotbench.eval.sweep.summary import format_best

    gates = load_gates(DEMO_GATES)
    started = time.perf_counter()
    status = logging.getLogger("depotbench.demo").info  # on stderr with --json
    with OutputContainer(args.output, OutputKind.DEMO) as container:
        out = container.path
        status(f"1/4 the demo suite and its sweep ({DEMO_GATES.name}): generating, then tracking")
        outcome = execute_sweep(gates.run, DEMO_GATES, out, args.workers)
        status(f"2/4 best configuration per family (of {outcome.jobs} runs; rho: ATE improvement over none)")
        status(format_best(outcome.summary["best"], outcome.summary["unqualified"]))
        report = evaluate(gates, outcome.records)
        status("3/4 gates")
        status(format_report(report))
        write_text_atomic(out / "gates.xml", junit_xml(report))
        status("4/4 HTML report (plots, trajectories, frames with keypoints by decision)")
        page = write_report(out, out / "report", args.workers)
    seconds = time.perf_counter() - started
    failures = [str(failure) for failure in report.failures]
    result = {
        "output": args.output,
        "report": args.output / page.relative_to(out),
        "results_csv": args.output / "results.csv",
        "summary": args.output / "summary.json",
        "junit": args.output / "gates.xml",
        "runs": outcome.jobs,
        "passed": report.passed,
        "failures": failures,
        "seconds": seconds,
    }
    text = (
        f"\ndone in {seconds:.0f} s. Open {result['report']}; "
        f"rows in {result['results_csv']}, JUnit in {result['junit']}"
    )
    print_result(args, result, "\n".join([text, *(f"FAILED {failure}" for failure in failures)]))
    return 0 if report.passed else 1


def _add_generate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("generate", help="render a scenario or a whole suite into sequence folders")
    p.add_argument(
        "spec",
        help="'default', a library scenario's name (depotbench scenarios), a shipped suite's name "
        "(depotbench examples), a scenario file or a suite file",
    )
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        required=True,
        help="sequence folder (scenario) or folder of sequences (suite)",
    )
    p.add_argument("--frames", type=int, help="number of frames (overrides the spec)")
    p.add_argument("--seed", type=int, help="random seed (overrides the spec)")
    p.add_argument("--flow", action="store_true", help="also write exact optical flow (gt/flow)")
    p.add_argument(
        "--sensor",
        choices=("perfect", "kinect", "tum"),
        help="the sensor model (overrides the spec): perfect gives exact pixels, tum (the TUM analogs' "
        "default) a Kinect recorded as TUM fr3 was (docs/scenarios.md)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing output of depotbench (a suite: regenerate every sequence)",
    )
    p.add_argument(
        "--workers",
        type=workers,
        default=None,
        help=f"{WORKERS_HELP}; for a suite",
    )
    p.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="a suite's workers: local processes, or Ray (extra [ray]; local, or --address)",
    )
    p.add_argument("--address", help="--backend ray: the cluster's address (default: start a local Ray)")
    p.add_argument(
        "--png-compression",
        type=_png_level,
        default=DEFAULT_PNG_COMPRESSION_LEVEL,
        metavar="0-9",
        help="deflate level of the PNGs (libdeflate): 0 stores (files about 3.6x larger), 1 is fast, "
        "higher levels are slower for a few percent smaller files; the same pixels at every level "
        "(default: %(default)s)",
    )
    add_json(p, "what was written: the sequence folder(s) with their names, seeds and frames")
    p.set_defaults(handler=_cmd_generate)


def _png_level(text: str) -> int:
    if text not in [str(level) for level in range(10)]:
        raise argparse.ArgumentTypeError(f"must be a zlib level 0-9, got {text!r}")
    return int(text)


def _cmd_generate(args: argparse.Namespace) -> int:
    import dataclasses

    from depotbench.core.examples import Kind, examples, hint, named, reads_as_path
    from depotbench.scenes import library
    from depotbench.scenes.generation import run_suite
    from depotbench.scenes.resolve import DEFAULT, resolve
    from depotbench.scenes.schema import sensor_spec
    from depotbench.scenes.suite import is_suite_file, load_suite
    from depotbench.sim.generate import generate

    started = time.perf_counter()
    path = Path(args.spec)
    if not path.exists():  # a shipped suite by name (depotbench examples); a path wins over a name
        path = named(args.spec, Kind.SUITE) or path
    where = backend_of(args)
    if path.is_file() and is_suite_file(path):
        if args.frames is not None or args.seed is not None or args.flow or args.sensor:
            raise InputError(
                "--frames, --seed, --flow and --sensor apply to one scenario; set them in the suite"
            )
        index = run_suite(
            load_suite(path),
            path,
            args.output,
            args.workers,
            overwrite=args.overwrite,
            **where,
            png_compression=args.png_compression,
        )
        text = f"suite '{index['suite']}': {len(index['sequences'])} sequences in {args.output}"
        result = {"kind": "suite", "suite": index["suite"], "folder": args.output}
        result |= {"sequences": index["sequences"], "seconds": time.perf_counter() - started}
        print_result(args, result, text)
        return 0
    changes = {
        name: value for name, value in (("frames", args.frames), ("seed", args.seed)) if value is not None
    }
    if args.flow:
        changes["flow"] = True
    if not path.exists() and not reads_as_path(args.spec) and args.spec != DEFAULT:
        known = [*library.names(), *(e.name for e in examples().values() if e.kind is Kind.SUITE)]
        if args.spec not in known:
            lister = "depotbench scenarios and depotbench examples list them"
            raise InputError(
                f"no library scenario named {args.spec!r}, nor a shipped suite or a file; "
                f"{hint(args.spec, known, lister)}"
            )
    scenario = resolve(args.spec, changes)
    if args.sensor:
        scenario = dataclasses.replace(scenario, sensor=sensor_spec(args.sensor))
    inputs = (path,) if path.exists() else ()
    out = generate(
        scenario, args.output, overwrite=args.overwrite, inputs=inputs, png_compression=args.png_compression
    )
    text = f"wrote {scenario.frames} frames of '{scenario.name}' (seed {scenario.seed}) to {out}"
    result = {"kind": "scenario", "name": scenario.name, "seed": scenario.seed, "frames": scenario.frames}
    print_result(args, result | {"sequence": out, "seconds": time.perf_counter() - started}, text)
    return 0


def _add_validate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="lint any file the bench reads: every problem, its line and field")
    p.add_argument(
        "files",
        nargs="+",
        metavar="FILE",
        help="scenario, suite, sweep, gate, camera or trajectory files, sequence or sweep folders "
        "(the kind is read from what they hold), or library and example names",
    )
    p.add_argument("--json", action="store_true", help="print each file's kind, verdict and problems as JSON")
    p.set_defaults(handler=_cmd_validate)


def _cmd_validate(args: argparse.Namespace) -> int:
    from depotbench.core.files import dumps_json
    from depotbench.eval.validate import validate_file

    checked = [validate_file(name) for name in args.files]
    if args.json:
        print(dumps_json([c.to_dict() for c in checked]))
    else:
        for c in checked:
            if c.ok:
                print(f"{c.name}: ok: {c.kind}, {c.summary}")
            else:
                for problem in c.problems:
                    print(f"depotbench validate: error: {problem}", file=sys.stderr)
    return 0 if all(c.ok for c in checked) else EXIT_INPUT_ERROR


def _add_scenarios(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scenarios", help="list the library's named scenarios")
    p.add_argument("--tag", help="only scenarios with this tag (e.g. tum-like, depot, stress, smoke)")
    p.add_argument("--json", action="store_true", help="print name, tags and description of each as JSON")
    p.set_defaults(handler=_cmd_scenarios)


def _cmd_scenarios(args: argparse.Namespace) -> int:
    from depotbench.core.files import dumps_json
    from depotbench.scenes import library

    scenarios = [library.get(name) for name in library.names(args.tag)]
    if args.json:
        print(
            dumps_json(
                [{"name": s.name, "tags": list(s.tags), "description": s.description} for s in scenarios]
            )
        )
        return 0
    for scenario in scenarios:
        print(f"{scenario.name:22s} {','.join(scenario.tags):32s} {scenario.description}")
    return 0


def _add_run(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="track a sequence with SLAM and a rejection strategy; write metrics")
    p.add_argument("sequence", type=Path, help="a generated sequence or a TUM RGB-D folder")
    add_tracker_options(p)
    add_detector_options(p, default=None)
    add_camera_options(p)
    p.add_argument(
        "--map",
        action="store_true",
        help="also build the dense map from the keyframes, leaving out what the strategy rejected "
        "(map.ply), and score it against the exact static world: accuracy, completeness, F-score "
        "and the ghosts moving things left (built-in tracker; --slam cmd: the map it writes at {map})",
    )
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        required=True,
        help="folder for trajectory, diagnostics, metrics",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.add_argument("--json", action="store_true", help="print metrics.json's content instead of the summary")
    p.set_defaults(handler=_cmd_run)


def _cmd_run(args: argparse.Namespace) -> int:
    from depotbench.eval.run.cache import StageCache
    from depotbench.eval.run.harness import run_sequence

    tracker, settings = tracker_from_args(args)
    detector = detector_config(args)
    metrics = run_sequence(
        args.sequence,
        args.output,
        args.strategy,
        detector,
        settings,
        overwrite=args.overwrite,
        tracker=tracker,
        cache=StageCache.from_env(),
        dense_map=args.map,
        camera=camera_from_args(args),
    )
    if args.json:
        from depotbench.core.files import dumps_json

        print(dumps_json(metrics))
    else:
        print(format_run(metrics))
    return 0


def format_run(metrics: dict) -> str:
    keyframes = "" if metrics["keyframes"] is None else f", {metrics['keyframes']} keyframes"
    lines = [
        f"{metrics['tracker']} {metrics['strategy']} on {metrics['sequence']}: tracked "
        f"{metrics['tracked_frames']}/{metrics['frames']} frames ({metrics['lost_frames']} lost){keyframes}"
    ]
    if "ate_m" in metrics:
        lines.append(
            f"ATE rmse {metrics['ate_m']['rmse']:.4f} m, RPE {metrics['rpe_translation_m']['rmse']:.4f} m "
            f"/ {metrics['rpe_rotation_deg']['rmse']:.3f} deg per frame"
        )
    rejection = metrics.get("rejection")
    if rejection:

        def show(value):
            return "n/a" if value is None else f"{value:.3f}"

        lines.append(
            f"rejection precision {show(rejection['precision'])}, recall {show(rejection['recall'])} "
            f"({rejection['moving_keypoints']} of {rejection['keypoints']} keypoints on moving objects; "
            f"{rejection['moving_inliers']} ended as inliers)"
        )
    dense = metrics.get("map")
    if dense is not None:
        line = f"dense map: {dense['points']} points from {dense['keyframes']} keyframes"
        if "f_score" in dense:
            ghosts = ", ".join(f"{who} {n}" for who, n in dense["ghosts"].items() if n) or "none"
            line += (
                f"; at {dense['threshold_m'] * 100:g} cm: F-score {dense['f_score']:.3f} (accuracy "
                f"{dense['accuracy']:.3f}, completeness {dense['completeness']:.3f}), ghost fraction "
                f"{dense['ghost_fraction']:.3f} ({ghosts})"
            )
        lines.append(line)
    t = metrics["stage_time"]
    if t["tracking_total"]["mean_ms"] is None:
        lines.append(f"{metrics['wall_time_s']:.1f} s in all (the tracker reports no per-frame time)")
    else:
        mapping = t.get("mapping")
        mapping_text = "" if mapping is None else f"; local mapping {mapping['mean_ms']:.1f} ms mean"
        lines.append(
            f"tracking {t['tracking_total']['mean_ms']:.1f} ms mean, {t['tracking_total']['median_ms']:.1f} "
            f"ms median per frame{mapping_text}"
        )
    return "\n".join(lines)


def _add_vocab(sub: argparse._SubParsersAction) -> None:
    default = choices.VOCABULARY_DEFAULTS
    p = sub.add_parser(
        "vocab",
        help="build an ORB vocabulary (DBoW2 text, as ORB-SLAM reads) from generated frames",
    )
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        help="vocabulary file to write (default: the bench's cache, which --slam orbslam3 uses)",
    )
    p.add_argument("--branching", type=int, default=default["branching"], help="children per node (k)")
    p.add_argument("--levels", type=int, default=default["levels"], help="depth of the tree (L)")
    p.add_argument(
        "--scenes",
        nargs="+",
        default=list(choices.TRAINING_SCENES),
        help="library scenes to train on (default: depot scenes the fidelity benchmark does not run)",
    )
    p.add_argument("--frames", type=int, default=default["frames"], help="frames rendered per scene")
    p.add_argument("--seed", type=int, default=default["seed"], help="seed of the training scenes")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    p.add_argument("--workers", type=workers, default=None, help="scenes rendered at a time")
    add_json(p, "the vocabulary's path, its words and the spec it was built from")
    p.set_defaults(handler=_cmd_vocab)


def _cmd_vocab(args: argparse.Namespace) -> int:
    from depotbench.core.output import check_output_file
    from depotbench.eval.trackers.vocabulary import VocabularySpec, build_file, default_vocabulary, read_text
    from depotbench.scenes import library

    for name in args.scenes:
        library.get(name)  # refuses an unknown scene by name, before any work
    started = time.perf_counter()
    spec = VocabularySpec(args.branching, args.levels, tuple(args.scenes), args.frames, args.seed)
    if args.output is None:
        path = default_vocabulary(progress=True, spec=spec, workers=args.workers)
    else:
        check_output_file(args.output, overwrite=args.overwrite, option="-o")
        path = args.output
        build_file(spec, path, progress=True, workers=args.workers)
    words = read_text(path).words
    result = {
        "vocabulary": path,
        "words": words,
        "branching": spec.branching,
        "levels": spec.levels,
        "scenes": list(spec.scenes),
        "frames": spec.frames,
        "seed": spec.seed,
        "seconds": time.perf_counter() - started,
    }
    print_result(args, result, f"{path}: {words} words (k={spec.branching}, L={spec.levels})")
    return 0


def _add_preview(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("preview", help="save RGB | depth | instances+boxes of sequence frames as a PNG")
    p.add_argument("sequence", type=Path)
    p.add_argument("--frames", type=int, nargs="+", default=[0], help="frame indices (default: 0)")
    p.add_argument("-o", "--output", type=Path, required=True, help="PNG file to write")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    add_json(p, "the picture's path, size and frames")
    p.set_defaults(handler=_cmd_preview)


def _cmd_preview(args: argparse.Namespace) -> int:
    import numpy as np
    from depotbench.core.output import check_output_file
    from depotbench.eval.report.preview import preview, save_png
    from depotbench.sim.sequence import Sequence

    started = time.perf_counter()
    if args.output.suffix.lower() != ".png":
        raise InputError(f"{args.output}: the preview is a PNG; give a file name ending in .png")
    check_output_file(args.output, overwrite=args.overwrite, inputs=(args.sequence,), option="-o")
    if len(args.frames) > MAX_PREVIEW_FRAMES:
        raise InputError(f"--frames: give at most {MAX_PREVIEW_FRAMES} frames, got {len(args.frames)}")
    seq = Sequence.open(args.sequence)
    bad = [i for i in args.frames if not 0 <= i < len(seq)]
    if bad:
        raise InputError(f"{args.sequence}: frame {bad[0]} is out of range (0..{len(seq) - 1})")
    objects = seq.objects() if seq.is_generated else None
    image = np.vstack([preview(seq, i, objects=None if objects is None else objects[i]) for i in args.frames])
    save_png(args.output, image)
    height, width = image.shape[:2]
    result = {"png": args.output, "frames": list(args.frames), "width": width, "height": height}
    print_result(args, result | {"seconds": time.perf_counter() - started}, f"wrote {args.output}")
    return 0


def _add_completion(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("completion", help="print a bash or zsh completion script")
    p.add_argument("shell", choices=SHELLS, help="the shell")
    p.set_defaults(handler=_cmd_completion)


SHELLS = ("bash", "zsh")


def _cmd_completion(args: argparse.Namespace) -> int:
    """shtab writes the script from the parser itself, so it knows every command, option
    and choice the parser does (no list kept by hand)."""
    import shtab

    parser = build_parser()
    # Paths complete as files where an option or argument takes one (argparse's type=Path).
    for action in _actions(parser):
        if action.type is Path:
            action.complete = shtab.FILE  # type: ignore[attr-defined]
    print(shtab.complete(parser, shell=args.shell))
    return 0


def _actions(parser: argparse.ArgumentParser):
    for action in parser._actions:
        yield action
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):
                yield from _actions(child)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="depotbench",
        description="Simulation-backed test bench for dynamic visual SLAM: generate scenario suites, "
        "run trackers (the built-in one, ORB-SLAM3, your own program), sweep rejection thresholds, "
        "gate robustness in CI. 'depotbench COMMAND --help' shows a command's options and examples.",
        epilog="examples:\n  depotbench demo\n  depotbench generate walking_xyz -o seqs/xyz\n"
        "  depotbench run seqs/xyz -o runs/xyz --strategy box_epipolar_flow",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_version(parser)
    add_verbosity(parser, top=True)
    sub = parser.add_subparsers(dest="verb", required=True, metavar="COMMAND", parser_class=Parser)
    for add in (
        _add_demo,
        _add_eval,
        _add_generate,
        _add_validate,
        _add_scenarios,
        add_examples,
        _add_run,
        _add_preview,
        _add_vocab,
        add_detect_eval,
        add_export_dataset,
        add_export_rosbag,
        add_sweep,
        add_check,
        add_report,
        add_compare,
        add_benchmark,
        add_cache,
        _add_completion,
    ):
        add(sub)
    for name, command in sub.choices.items():
        describe(name, command)
        add_verbosity(command, top=False)
        add_version(command)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM (a CI job cancelled, ``timeout``), handled as Ctrl-C: stop, clean up, say so."""


def main(argv: Sequence[str] | None = None) -> int:
    # Ctrl-C and SIGTERM raise, but never inside an import (depotbench.core.processes.OutsideImports):
    # building the parser alone imports numpy, SciPy and OpenCV, and commands import MuJoCo.
    in_main = threading.current_thread() is threading.main_thread()
    previous = {}
    if in_main:
        previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, OutsideImports(Terminated))
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not ignored (nohup, &)
            previous[signal.SIGINT] = signal.signal(signal.SIGINT, OutsideImports(KeyboardInterrupt))
    try:
        try:
            parser = build_parser()
            args = parser.parse_args(argv)
        except KeyboardInterrupt:
            print("depotbench: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        as_json = getattr(args, "json", False)
        level = show_messages(args.verb, verbosity(args), json=as_json)
        try:
            if args.quiet and not as_json:
                with open(os.devnull, "w") as nowhere, contextlib.redirect_stdout(nowhere):
                    return _run(args)
            return _run(args)
        finally:
            logging.getLogger("depotbench").setLevel(level)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _run(args: argparse.Namespace) -> int:
    """The command's exit code; a user's mistake or an interruption ends in one line."""
    from depotbench.core.errors import EnvironmentProblem

    try:
        if getattr(args, "workers", 0) is None:  # read here, so a bad DEPOTBENCH_WORKERS fails only
            args.workers = one_per_core()  # the commands that take --workers, in one line naming it
        return int(args.handler(args))
    except (InputError, EnvironmentProblem) as exc:
        print(f"depotbench {args.verb}: error: {exc}", file=sys.stderr)
        return EXIT_INPUT_ERROR
    except BrokenPipeError:
        # The reader went away (``depotbench scenarios | head``): say nothing more.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except OSError as exc:
        from depotbench.core.output import WRITE_FAILURES

        if exc.filename is None and exc.errno not in WRITE_FAILURES:
            raise
        # A path the system refused (missing, unreadable) or a write that failed (a full disk,
        # which names no file: the command's output is where it was writing).
        where = exc.filename if exc.filename is not None else getattr(args, "output", None) or "the output"
        print(f"depotbench {args.verb}: error: {where}: {exc.strerror}", file=sys.stderr)
        return EXIT_INPUT_ERROR
    except KeyboardInterrupt as exc:
        fresh_line = "\n" if sys.stderr.isatty() else ""  # after a progress bar
        what = "terminated" if isinstance(exc, Terminated) else "interrupted"
        print(
            f"{fresh_line}depotbench {args.verb}: {what}; "
            "finished outputs are kept and nothing is half-written",
            file=sys.stderr,
        )
        return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED


def entry() -> None:
    """The ``depotbench`` program. A Ctrl-C that lands inside an extension module's import
    (numpy's, or MuJoCo's as a command starts) leaves CPython marked as interrupted: it then
    ends itself by SIGINT whatever code we return, and the shell sees a signal, not 130.
    An interrupted command has cleaned up by the time ``main`` returns, so that exit is
    taken directly."""
    code = main()
    if code == EXIT_INTERRUPTED:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    entry()
