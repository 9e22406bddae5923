"""``depotbench report``: the HTML page of a run or a sweep (and a Rerun recording)."""

from __future__ import annotations

import argparse
from pathlib import Path

from depotbench.eval.cli.args import one_per_core, workers


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
    p.add_argument(
        "--workers",
        type=workers,
        default=one_per_core(),
        help="processes that track a sweep's featured runs again (used from 300 frames in all)",
    )
    p.set_defaults(handler=_cmd_report)


def _cmd_report(args: argparse.Namespace) -> int:
    from depotbench.eval.report.html import warn
    from depotbench.eval.report.write import report_folder

    written = report_folder(args.source, args.output, args.rerun, args.workers)
    if written.recording is not None:
        print(f"wrote {written.recording} (open it with: rerun {written.recording})")
    path = written.page
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, self-contained: open it in any browser)")
    warn(written.notes)
    return 0
