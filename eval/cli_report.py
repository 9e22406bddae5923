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
    from eval.html_report import load_run, write_report
    from sim.errors import InputError

    if not args.source.is_dir():
        raise InputError(f"{args.source}: no such folder")
    if args.rerun is not None:
        from eval.rerun import write_recording

        if not (args.source / "metrics.json").is_file():
            raise InputError(f"--rerun: {args.source} is not a run folder (metrics.json)")
        write_recording(load_run(args.source), args.rerun)
        print(f"wrote {args.rerun} (open it with: rerun {args.rerun})")
    path = write_report(args.source, args.output)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, self-contained: open it in any browser)")
    return 0
