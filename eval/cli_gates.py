"""``depotbench check``: robustness gates for CI (exit 1 naming each failed budget)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from depotbench.eval.gates import GateFile, GateReport

EXIT_FAILED = 1


def add_check(sub: argparse._SubParsersAction) -> None:
    from depotbench.eval.cli import (
        _workers,  # the CLI's own --workers type (depotbench.eval.cli imports this module)
    )

    p = sub.add_parser(
        "check",
        help="run a gate file's matrix and check its budgets (exit 1 naming each failed budget)",
    )
    p.add_argument("gates", type=Path, help="the gate file (see assets/gates/)")
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
        "-o",
        "--output",
        type=Path,
        help="the run matrix's folder, resumed if it exists (default: runs/check-NAME)",
    )
    p.add_argument("--workers", type=_workers, default=max(1, os.cpu_count() or 1), help="worker processes")
    p.add_argument("--backend", choices=("local", "ray"), default="local", help="where runs execute")
    p.add_argument("--address", help="--backend ray: the cluster's address")
    p.set_defaults(handler=_cmd_check)


def _cmd_check(args: argparse.Namespace) -> int:
    from depotbench.core.errors import InputError
    from depotbench.core.output import OutputContainer, OutputKind, check_output_file, write_text_atomic
    from depotbench.eval.gates import format_report, junit_xml, load_gates
    from depotbench.eval.sweep import spec_inputs, validate

    if args.address and args.backend != "ray":
        raise InputError("--address applies to --backend ray only")
    gates = load_gates(args.gates)
    if args.baseline is None and any(b.endswith(".vs_baseline") for c in gates.checks for b in c.budgets):
        raise InputError(
            f"{args.gates}: its vs_baseline budgets need --baseline DIR (an earlier run's folder)"
        )
    validate(gates.run, args.gates)  # before any folder is made
    inputs = spec_inputs(gates.run, args.gates)
    baseline = load_baseline(args.baseline) if args.baseline is not None else None
    if args.junit is not None:  # the verdict must not be lost to a place found unwritable after the run
        check_output_file(args.junit, overwrite=args.overwrite, inputs=inputs, option="--junit")
    out = args.output or Path("runs") / f"check-{gates.gates}"
    with OutputContainer(out, OutputKind.SWEEP, inputs=inputs) as container:
        report = run_gates(
            gates, args.gates, container.path, args.workers, args.backend, args.address, baseline
        )
    print(format_report(report))
    if args.junit is not None:
        write_text_atomic(args.junit, junit_xml(report))
        print(f"wrote {args.junit}")
    for failure in report.failures:
        print(f"FAILED {failure}")
    return 0 if report.passed else EXIT_FAILED


def run_gates(
    gates: GateFile,
    gates_path: Path,
    out: Path,
    workers: int,
    backend: str = "local",
    address: str | None = None,
    baseline: list[dict] | None = None,
) -> GateReport:
    """The gate file's matrix through the sweep engine (cache and stored rows reused), checked
    (``baseline``: an earlier run's rows, for ``vs_baseline`` budgets)."""
    from depotbench.eval.gates import evaluate
    from depotbench.eval.sweep_run import execute_sweep

    outcome = execute_sweep(gates.run, gates_path, out, workers, backend=backend, address=address)
    return evaluate(gates, outcome.rows, baseline)


def load_baseline(folder: Path) -> list[dict]:
    """An earlier check's or sweep's rows (read only), as the gates compare against them."""
    from depotbench.core.errors import InputError
    from depotbench.eval.store import ResultStore

    database = folder / "results.sqlite"
    if not database.is_file():
        raise InputError(
            f"--baseline {folder}: no results.sqlite there (give an earlier check's or sweep's -o folder)"
        )
    with ResultStore(database, readonly=True) as store:
        return store.rows()
