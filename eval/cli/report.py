"""``depotbench report``: the HTML page of a run or a sweep (and a Rerun recording)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from depotbench.eval.cli.args import workers
from depotbench.eval.cli.conventions import add_json, print_result


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
        default=None,
        help="processes that track a sweep's featured runs again (used from 300 frames in all)",
    )
    add_json(p, "the page's path and size, the recording's path and what the page leaves out")
    p.set_defaults(handler=_cmd_report)


def _cmd_report(args: argparse.Namespace) -> int:
    from depotbench.eval.report.html import warn
    from depotbench.eval.report.write import report_folder

    started = time.perf_counter()
    written = report_folder(args.source, args.output, args.rerun, args.workers)
    path = written.page
    size = path.stat().st_size
    lines = (
        []
        if written.recording is None
        else [f"wrote {written.recording} (open it with: rerun {written.recording})"]
    )
    lines.append(f"wrote {path} ({size / 1e6:.1f} MB, self-contained: open it in any browser)")
    warn(written.notes)
    result = {
        "source": args.source,
        "page": path,
        "page_bytes": size,
        "recording": written.recording,
        "left_out": list(written.notes.items),
        "seconds": time.perf_counter() - started,
    }
    print_result(args, result, "\n".join(lines))
    return 0
