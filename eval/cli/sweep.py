"""``depotbench sweep``: a sweep spec in, a results database, CSV, plots and the best settings out."""

from __future__ import annotations

import argparse
from pathlib import Path

from depotbench.eval.cli.args import WORKERS_HELP, add_backend, backend_of, workers


def add_sweep(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sweep",
        help="run a threshold sweep (a YAML spec) into a resumable SQLite database, with CSV and plots",
    )
    p.add_argument(
        "spec",
        help="the sweep spec: a file, or the name of a shipped one (depotbench examples lists them; "
        "a path that exists wins over a name)",
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="the sweep folder (resumed if it exists)")
    p.add_argument("--workers", type=workers, default=None, help=WORKERS_HELP)
    add_backend(p)
    p.add_argument(
        "--no-dedupe",
        action="store_true",
        help="track every job, even where another keeps the same keypoints in every frame",
    )
    p.add_argument(
        "--retry-failed",
        action="store_true",
        help="run the failed rows again (a program's exit, time limit or unreadable output) instead "
        "of reusing them",
    )
    p.add_argument(
        "--prune-stale",
        action="store_true",
        help="remove the folder's rows of older versions of the spec's trackers (another tracker "
        "fingerprint), one line per version removed (the next report drops their kept views); "
        "without it they are kept apart",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print summary.json's content (best per family, Pareto front, configurations) instead of tables",
    )
    p.set_defaults(handler=_cmd_sweep)


def _cmd_sweep(args: argparse.Namespace) -> int:
    from depotbench.core.examples import Kind, find
    from depotbench.core.files import dumps_json
    from depotbench.eval.sweep.execute import sweep_folder
    from depotbench.eval.sweep.summary import format_best

    outcome = sweep_folder(
        find(args.spec, Kind.SWEEP),
        args.output,
        args.workers,
        dedupe=not args.no_dedupe,
        **backend_of(args),
        retry_failed=args.retry_failed,
        prune_stale=args.prune_stale,
    )
    if args.json:
        print(dumps_json(outcome.summary))
        return 0
    written, elapsed = outcome.written, outcome.seconds
    rate = f", {written / elapsed * 60:.1f} rows/min" if written and elapsed > 0 else ""
    shared = (
        f"; tracked {outcome.tracked} of them (the others keep the same keypoints in every frame "
        "as a tracked one)"
        if outcome.tracked < written
        else ""
    )
    print(f"wrote {written} rows in {elapsed:.1f} s{rate}{shared}")
    print(format_best(outcome.summary["best"], outcome.summary["unqualified"]))
    search = outcome.search
    if search is not None:
        print(
            f"search ({search['trials']} trials, {search['objective']}): best "
            f"{search.get('tracker') or search['strategy']} "
            f"{search['settings']} -> {search['value']:.5f}; study in {args.output / 'optuna.sqlite'}"
        )
    print(
        f"wrote {args.output / 'results.sqlite'}, results.csv, summary.json, plots in {args.output / 'plots'}"
    )
    print(f"the HTML page: depotbench report {args.output} -o REPORT_FOLDER")
    return 0
