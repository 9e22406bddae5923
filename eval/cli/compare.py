"""``depotbench compare``: two or more sweeps (or runs) side by side, each against the first."""

from __future__ import annotations

import argparse
from pathlib import Path

from depotbench.eval.cli.args import finite_float

EXIT_REGRESSION = 1


def tolerance(text: str) -> float:
    """A finite tolerance of 0 or more: NaN compares false with every change and inf or
    1e999 exceed all, so either would silently disarm --fail-on-regression."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {text}")
    return value


def add_compare(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare",
        help="compare sweeps or runs: per configuration, each figure's paired change from the first, "
        "with its 95 %% interval and p",
    )  # its description and examples: conventions.USAGE
    p.add_argument("folders", nargs="+", type=Path, help="sweep, check or run folders; the first is the base")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.add_argument("--html", type=Path, metavar="FILE", help="also write the tables as an HTML page")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --html file")
    p.add_argument(
        "--fail-on-regression",
        action="store_true",
        help="exit 1 when a figure got worse beyond --tolerance and the paired test says it is real",
    )
    p.add_argument(
        "--tolerance",
        type=tolerance,
        default=0.0,
        help="a regression must exceed this: relative for errors and time (0.05: 5 %%), absolute for "
        "rates (default 0)",
    )
    p.add_argument(
        "--time",
        action="store_true",
        help="count a slower frame time as a regression too (only when both sets ran on the same "
        "machine under the same load)",
    )
    p.add_argument(
        "--fingerprint",
        action="append",
        default=[],
        metavar="FINGERPRINT",
        help="of a folder holding rows of several versions of one tracker's program, use those with "
        "this tracker fingerprint (repeat for several trackers)",
    )
    p.set_defaults(handler=_cmd_compare)


def _cmd_compare(args: argparse.Namespace) -> int:
    from depotbench.core.errors import InputError
    from depotbench.core.files import dumps_json
    from depotbench.core.output import check_output_file, write_text_atomic
    from depotbench.eval.gates.compare import compare_rows, format_comparisons, load_set

    if len(args.folders) < 2:
        raise InputError("compare needs two folders or more: the base, then what to compare with it")
    if args.html is not None:
        check_output_file(args.html, overwrite=args.overwrite, inputs=tuple(args.folders), option="--html")
    chosen = tuple(args.fingerprint)
    base = load_set(args.folders[0], chosen)
    results = {str(folder): compare_rows(base, load_set(folder, chosen)) for folder in args.folders[1:]}
    regressions = {name: found.regressions(args.tolerance, time=args.time) for name, found in results.items()}
    if args.json:
        print(
            dumps_json(
                {
                    name: found.to_dict() | {"regressions": [c.to_dict() for c in regressions[name]]}
                    for name, found in results.items()
                }
            )
        )
    else:
        for name, found in results.items():
            print(format_comparisons(f"{name} against {args.folders[0]}", found))
            for c in regressions[name]:
                print(f"REGRESSION {name}: {c.text()}")
    if args.html is not None:
        write_text_atomic(args.html, _page(args.folders[0], results))
    return EXIT_REGRESSION if args.fail_on_regression and any(regressions.values()) else 0


def _page(base: Path, results: dict) -> str:
    from depotbench.eval.gates.compare import change_text, value_text
    from depotbench.eval.metrics.figures import RATIO
    from depotbench.eval.report.html import Notes
    from depotbench.eval.report.page import Table, render

    header = ["family", "configuration", "figure", "first", "this", "change", "95 % interval", "pairs"]
    header += ["p(worse)", ""]
    sections = []
    for name, found in results.items():
        rows = []
        for c in found.comparisons:
            ratio, ch = c.figure in RATIO, c.change
            rows.append(
                [
                    c.family,
                    c.base if c.base == c.other else f"{c.base} → {c.other}",
                    c.figure,
                    value_text(c.base_mean),
                    value_text(c.other_mean),
                    change_text(ch.change, ratio),
                    f"[{change_text(ch.ci_low, ratio)}, {change_text(ch.ci_high, ratio)}]",
                    ch.pairs,
                    "-" if ch.p_worse is None else f"{ch.p_worse:.3g}",
                    "significant" if c.significant else "",
                ]
            )
        sections.append({"heading": f"{name} against {base}", "table": Table(header, rows)})
    notes = Notes()
    for name, found in results.items():
        if not found.comparisons:
            notes.add(f"{name}: no configuration of {base} ran on the same sequences there")
        for where, items in ((base, found.only_first), (name, found.only_this)):
            if items:
                notes.add(f"only in {where}, not compared: " + "; ".join(items))
        if found.duplicates:
            twice = "; ".join(found.duplicates)
            notes.add(f"{name}: more than one run on one sequence, not compared: {twice}")
    return render(
        "compare_page.html.j2",
        title="depotbench compare",
        subtitle=f"each set against {base}, paired by sequence",
        notes=notes.items,
        sections=sections,
    )
