"""Command-line words for detectors: the --detector options, detect-eval, export-dataset."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from depotbench.core.errors import InputError
from depotbench.eval.cli.conventions import add_json, print_result


def add_detector_options(p: argparse.ArgumentParser, default: str | None = "groundtruth") -> None:
    """``default`` None: the run picks one that needs nothing the sequence lacks
    (``harness.default_detector``)."""
    said = default or (
        "groundtruth on a generated sequence; none on a real folder with --strategy none, which uses no boxes"
    )
    p.add_argument(
        "--detector",
        default=default,
        metavar="DETECTOR",
        help="where boxes come from: groundtruth (true visible boxes), onnx (the shipped "
        "YOLOX-nano), onnx:PATH (another YOLOX/YOLOv5/YOLOv8 ONNX model) or none "
        f"(default: {said})",
    )
    p.add_argument(
        "--detector-set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a detector setting: confidence, nms_iou, threads, layout, names (onnx); "
        "min_visible_pixels (groundtruth)",
    )
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="inject a detector fault, e.g. --fault miss=0.3 --fault latency=2 (docs/detectors.md: "
        "miss, miss_small, miss_occluded, miss_blurred, jitter, scale, false_positives, "
        "confusion, latency, confidence_noise, drop, every, seed)",
    )
    p.add_argument(
        "--class-prior",
        action="append",
        default=[],
        metavar="CLASS=PRIOR",
        help="map a detector class to dynamic, potential or static, e.g. --class-prior 'teddy bear=dynamic'",
    )


def pairs(items: list[str], flag: str) -> dict[str, str]:
    """NAME=VALUE arguments as a dict (the last of a repeated name wins)."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise InputError(f"{flag} {item!r}: expected NAME=VALUE")
        out[name.strip()] = value.strip()
    return out


def detector_config(args: argparse.Namespace):
    """The detector the options name; None where they name none and the command picks
    (``add_detector_options(default=None)``): a setting or fault alone means groundtruth's."""
    from depotbench.detectors.config import DetectorConfigError, parse_detector

    if args.detector is None and not (args.detector_set or args.fault or args.class_prior):
        return None
    try:
        return parse_detector(
            args.detector or "groundtruth",
            pairs(args.detector_set, "--detector-set"),
            pairs(args.fault, "--fault"),
            pairs(args.class_prior, "--class-prior"),
        )
    except DetectorConfigError as exc:
        raise InputError(f"--detector: {exc}") from None


def add_detect_eval(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "detect-eval",
        help="precision, recall and AP50 of a detector against the true boxes of generated sequences",
    )
    p.add_argument("sequences", nargs="+", type=Path, help="generated sequence folders")
    add_detector_options(p, default="onnx")
    p.add_argument(
        "--min-pixels",
        type=int,
        default=1000,
        help="objects with fewer visible pixels are ignored: found or missed, they do not count "
        "(default 1000)",
    )
    p.add_argument("--json", action="store_true", help="print the full report as JSON instead of the table")
    p.add_argument(
        "-o", "--output", type=Path, metavar="FILE", help="also write the full report (JSON) to this file"
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing --output file")
    p.set_defaults(handler=_cmd_detect_eval)


def _cmd_detect_eval(args: argparse.Namespace) -> int:
    from depotbench.core.files import dumps_json
    from depotbench.core.output import check_output_file, write_text_atomic
    from depotbench.detectors.config import DetectorKind
    from depotbench.eval.detection.evaluate import evaluate_detector, format_evaluation
    from depotbench.eval.run.cache import StageCache
    from depotbench.sim.sequence import Sequence

    config = detector_config(args)
    if config.kind is DetectorKind.NONE:
        raise InputError("detect-eval needs a detector (not --detector none)")
    if args.min_pixels < 1:
        raise InputError(f"--min-pixels must be at least 1, got {args.min_pixels}")
    if args.output is not None:
        check_output_file(args.output, overwrite=args.overwrite, inputs=tuple(args.sequences), option="-o")
    sequences = [Sequence.open(root) for root in args.sequences]
    for seq in sequences:
        if not seq.is_generated:
            raise InputError(f"{seq.root}: detect-eval needs generated sequences (true boxes)")
    report = evaluate_detector(
        sequences, config, StageCache.from_env(), progress=True, min_visible_pixels=args.min_pixels
    )
    if args.output is not None:
        write_text_atomic(args.output, dumps_json(report) + "\n")
    if args.json:  # stdout is the report alone, as `eval --json` prints its result
        print(dumps_json(report))
        return 0
    print(
        f"detector {config.label} on {len(sequences)} sequence(s), IoU >= 0.5, "
        f"objects >= {args.min_pixels} px"
    )
    print(format_evaluation(report))
    if args.output is not None:
        print(f"wrote {args.output}")
    return 0


def add_export_dataset(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export-dataset",
        help="generated sequences as a YOLO and COCO training set, split by sequence",
    )
    p.add_argument("sequences", nargs="+", type=Path, help="generated sequence folders")
    p.add_argument("-o", "--output", type=Path, required=True, help="the dataset folder")
    p.add_argument("--val-fraction", type=float, default=0.2, help="share of sequences for validation (0.2)")
    p.add_argument(
        "--val", nargs="+", default=[], metavar="NAME", help="these sequences are the validation set"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the sequence split (0)")
    p.add_argument("--every", type=int, default=1, help="take every n-th frame (1)")
    p.add_argument("--min-pixels", type=int, default=100, help="objects with fewer visible pixels get no box")
    p.add_argument(
        "--names",
        type=Path,
        help="class names in id order, one a line, instead of COCO's ids (COCO's and Darknet's "
        "spellings name the bench's classes: 'dining table' is the desk); other classes get no box",
    )
    p.add_argument("--overwrite", action="store_true", help="replace a dataset depotbench wrote")
    add_json(p, "the dataset's folder, images and boxes per split and the class ids")
    p.set_defaults(handler=_cmd_export_dataset)


def _cmd_export_dataset(args: argparse.Namespace) -> int:
    from depotbench.core.files import read_text
    from depotbench.eval.detection.dataset import ClassTable, ExportOptions, export_dataset

    if not 0.0 <= args.val_fraction < 1.0:
        raise InputError(f"--val-fraction must lie in [0, 1), got {args.val_fraction}")
    if args.every < 1:
        raise InputError(f"--every must be at least 1, got {args.every}")
    if args.min_pixels < 1:
        raise InputError(f"--min-pixels must be at least 1, got {args.min_pixels}")
    classes = None
    if args.names is not None:
        text = read_text(args.names, 1 << 20, "class names")
        classes = ClassTable.from_names(
            [ln.strip() for ln in text.splitlines() if ln.strip()], str(args.names)
        )
    options = ExportOptions(
        args.val_fraction, args.seed, tuple(args.val), args.every, args.min_pixels, classes
    )
    started = time.perf_counter()
    summary = export_dataset(args.sequences, args.output, options, overwrite=args.overwrite)
    c = summary["counts"]
    ids = ", ".join(f"{name} {i}" for name, i in summary["ids"].items())
    lines = [
        f"exported {c['train']['images']} train and {c['val']['images']} val images "
        f"({c['train']['boxes']} / {c['val']['boxes']} boxes) to {args.output}; class ids: {ids or 'none'}"
    ]
    if summary["appended_classes"]:
        lines.append(
            "classes neither COCO's nor the bench's, numbered after them in this export only: "
            + ", ".join(summary["appended_classes"])
        )
    if summary["skipped_classes"]:
        skipped = ", ".join(f"{k} ({v})" for k, v in sorted(summary["skipped_classes"].items()))
        lines.append(f"boxes of classes not in --names were left out: {skipped}")
    result = {"dataset": args.output, **summary, "seconds": time.perf_counter() - started}
    print_result(args, result, "\n".join(lines))
    return 0
