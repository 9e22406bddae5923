"""``depotbench check``: robustness gates for CI (exit 1 naming each failed budget)."""

from __future__ import annotations

import argparse
from pathlib import Path

from depotbench.eval.cli.args import WORKERS_HELP, add_backend, backend_of, workers

EXIT_FAILED = 1


def add_check(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "check",
        help="run a gate file's matrix and check its budgets (exit 1 naming each failed budget)",
    )
    p.add_argument(
        "gates",
        help="the gate file: a file, or the name of a shipped one (depotbench examples lists them; "
        "a path that exists wins over a name)",
    )
    p.add_argument("--junit", type=Path, help="also write JUnit XML here (a new file, or see --overwrite)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --junit file")
    p.add_argument(
        "--baseline",
        type=Path,
        metavar="DIR",
        help="an earlier check's or sweep's folder (its results.sqlite): METRIC.vs_baseline budgets "
        "compare each configuration's runs with its runs there, paired by sequence",
    )
    p.add_argument(
        "--baseline-fingerprint",
        action="append",
        default=[],
        metavar="FINGERPRINT",
        help="of a --baseline folder holding rows of several versions of one tracker's program, use "
        "those with this tracker fingerprint (repeat for several trackers)",
    )
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        help="the run matrix's folder, resumed if it exists (default: runs/check-NAME)",
    )
    p.add_argument("--workers", type=workers, default=None, help=WORKERS_HELP)
    p.add_argument(
        "--retry-failed",
        action="store_true",
        help="run the folder's failed rows again (a program's exit, time limit or unreadable output) "
        "instead of reusing them",
    )
    add_backend(p)
    p.add_argument(
        "--json", action="store_true", help="print the verdicts as JSON (each run's budgets, the failures)"
    )
    p.set_defaults(handler=_cmd_check)


def _cmd_check(args: argparse.Namespace) -> int:
    from depotbench.core.errors import InputError
    from depotbench.core.examples import Kind, find
    from depotbench.core.files import dumps_json
    from depotbench.core.output import check_output_file, write_text_atomic
    from depotbench.eval.gates.budgets import format_report, junit_xml
    from depotbench.eval.gates.check import check_folder, open_gates

    where = backend_of(args)
    if args.baseline_fingerprint and args.baseline is None:
        raise InputError("--baseline-fingerprint applies to --baseline DIR only")
    path = find(args.gates, Kind.GATES)  # a file, or a shipped gate file's name
    gates = open_gates(path, args.baseline, tuple(args.baseline_fingerprint))  # before any folder
    if args.junit is not None:  # the verdict must not be lost to a place found unwritable after the run
        check_output_file(args.junit, overwrite=args.overwrite, inputs=gates.inputs, option="--junit")
    out = args.output or Path("runs") / f"check-{gates.gates.gates}"
    report = check_folder(gates, out, args.workers, where["backend"], where["address"], args.retry_failed)
    if args.junit is not None:
        write_text_atomic(args.junit, junit_xml(report))
    if args.json:
        print(dumps_json(report.to_dict()))
        return 0 if report.passed else EXIT_FAILED
    print(format_report(report))
    if args.junit is not None:
        print(f"wrote {args.junit}")
    for failure in report.failures:
        print(f"FAILED {failure}")
    return 0 if report.passed else EXIT_FAILED
