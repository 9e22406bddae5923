"""``depotbench report``: the HTML page of a run or a sweep (and a Rerun recording)."""

from __future__ import annotations

import argparse
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


def _cmd_report(args: argparse.Namespace) -> int:
    from eval.html_report import load_run, render_report
    from sim.errors import InputError
    from sim.output import OutputContainer, OutputKind, write_text_atomic

    if not args.source.is_dir():
        raise InputError(f"{args.source}: no such folder")
    if args.rerun is not None:
        if not (args.source / "metrics.json").is_file():
            raise InputError(f"--rerun: {args.source} is not a run folder (metrics.json)")
        if args.rerun.exists():
            raise InputError(f"--rerun: {args.rerun} already exists; remove it or give another name")
        if not args.rerun.parent.is_dir():
            raise InputError(f"--rerun: {args.rerun.parent} is not a folder")
    text = render_report(args.source)  # before anything is written: bad input writes nothing
    # A folder of depotbench reports (or a new or empty one): never someone else's files.
    with OutputContainer(args.output, OutputKind.REPORT) as container:
        path = container.path / "index.html"
        write_text_atomic(path, text)
    if args.rerun is not None:
        from eval.rerun import write_recording

        write_recording(load_run(args.source), args.rerun)
        print(f"wrote {args.rerun} (open it with: rerun {args.rerun})")
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, self-contained: open it in any browser)")
    return 0
