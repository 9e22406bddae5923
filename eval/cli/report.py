"""``depotbench report``: the HTML page of a run or a sweep (and a Rerun recording)."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path


def add_report(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help="write a self-contained HTML page for a run folder or a sweep folder",
    )
    p.add_argument("source", type=Path, help="a run folder (depotbench run) or a sweep folder")
    p.add_argument("-o", "--output", type=Path, required=True, help="the report folder (index.html)")
    p.add_argument(
        "--rerun",
        type=Path,
        metavar="FILE.rrd",
        help="also write a Rerun recording of a run to scrub through (extra [viz])",
    )
    p.set_defaults(handler=_cmd_report)


def _check_rerun(args: argparse.Namespace) -> None:
    from depotbench.core.errors import InputError

    if not (args.source / "metrics.json").is_file():
        raise InputError(f"--rerun: {args.source} is not a run folder (metrics.json)")
    if args.rerun.exists():
        raise InputError(f"--rerun: {args.rerun} already exists; remove it or give another name")
    if not args.rerun.parent.is_dir():
        raise InputError(f"--rerun: {args.rerun.parent} is not a folder")
    output = args.output.resolve()
    if output in args.rerun.resolve().parents:
        # The report folder is replaced as a whole by the next report: the recording would go.
        raise InputError(
            f"--rerun: {args.rerun} lies inside the report folder {args.output}; give a path outside it"
        )


def _cmd_report(args: argparse.Namespace) -> int:
    """Render, then write: bad input writes nothing. The report folder is staged and swapped
    into place whole, and the recording is renamed into place after it, so a failure at any
    point (a full disk, probe C6) leaves neither half-written."""
    from depotbench.core.errors import InputError
    from depotbench.core.output import OutputKind, StagedOutput, write_text_atomic
    from depotbench.eval.report.html import render_report, warn

    if not args.source.is_dir():
        raise InputError(f"{args.source}: no such folder")
    if args.rerun is not None:
        _check_rerun(args)
    rendered = render_report(args.source)
    if args.rerun is not None and rendered.run is None:
        raise InputError(f"--rerun: {args.source} is not a run folder (metrics.json)")
    recording = contextlib.nullcontext()
    if args.rerun is not None:
        from depotbench.eval.report.rerun import staged_recording

        recording = staged_recording(rendered.run, args.rerun)
    # A folder of depotbench reports (or a new or empty one): never someone else's files.
    # The recording is written first (the longer write), renamed once the folder is in place.
    with StagedOutput(args.output, OutputKind.REPORT, overwrite=True) as staged, recording:
        write_text_atomic(staged.path / "index.html", rendered.text)
        staged.commit()
    if args.rerun is not None:
        print(f"wrote {args.rerun} (open it with: rerun {args.rerun})")
    path = args.output / "index.html"
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, self-contained: open it in any browser)")
    warn(rendered.notes)
    return 0
