"""``depotbench benchmark``: list the frozen benchmarks, score a tracker on one, print the
papers' tables from results files, and check a results file by recomputing it."""

from __future__ import annotations

import argparse
from pathlib import Path

from depotbench.core.errors import InputError
from depotbench.eval.cli.args import WORKERS_HELP, add_backend, backend_of, workers
from depotbench.eval.cli.conventions import add_json, add_verbosity, add_version, print_result
from depotbench.eval.cli.detectors import add_detector_options, detector_config
from depotbench.eval.cli.trackers import add_tracker_options, tracker_from_args


def add_benchmark(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "benchmark",
        help="frozen benchmarks: score a tracker (with repeats), print the papers' tables, verify results",
    )
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")

    listing = actions.add_parser("list", help="the shipped benchmarks: scenarios, seeds, frames, version")
    listing.set_defaults(handler=_cmd_list)

    run = actions.add_parser(
        "run",
        help="generate (or reuse) a benchmark's sequences, check their bytes against its lock, "
        "score one tracker configuration on each, write results.json",
    )
    run.add_argument("benchmark", help="a shipped benchmark (benchmark list) or a benchmark file")
    run.add_argument("-o", "--output", type=Path, required=True, help="sequences, runs and results.json")
    add_tracker_options(run)
    add_detector_options(run)
    run.add_argument(
        "--repeats",
        type=int,
        help="runs per sequence of a tracker that is not deterministic (ORB-SLAM3, --not-deterministic); "
        "default and least 3; the built-in tracker runs once",
    )
    run.add_argument(
        "--not-deterministic",
        action="store_true",
        help="--slam cmd: the program's runs differ from one another (threads, random draws): repeat them",
    )
    run.add_argument(
        "--fresh-seeds",
        type=int,
        default=0,
        metavar="N",
        help="also score N new seeds a scenario, drawn now: the table sets the frozen seeds' figures "
        "beside theirs with a paired test, so a tuning fitted to the frozen seeds shows",
    )
    run.add_argument(
        "--fresh-entropy",
        type=int,
        metavar="E",
        help="--fresh-seeds: draw them from this number, to draw them again (results.json records it)",
    )
    run.add_argument(
        "--sequences",
        type=Path,
        metavar="DIR",
        help="keep the benchmark's sequences here, not in OUTPUT/sequences: one folder serves the runs of "
        "several trackers (made once, checked against the lock by each run)",
    )
    run.add_argument("--workers", type=workers, default=None, help=WORKERS_HELP)
    add_backend(run)
    run.set_defaults(handler=_cmd_run)

    table = actions.add_parser(
        "table",
        help="the papers' table (ATE, RPE-t, RPE-r: RMSE, mean, median, STD; tracked share; rho) of "
        "results files, as Markdown, LaTeX (booktabs) and CSV",
    )
    table.add_argument("results", nargs="+", type=Path, help="results.json files (or their folders)")
    table.add_argument(
        "--baseline",
        type=Path,
        help="results of the baseline rho is taken against (any tracker: builtin none, ORB-SLAM3, "
        "your program's reject=0, an earlier release); without it no rho",
    )
    table.add_argument(
        "-o", "--output", type=Path, help="write OUTPUT.md, OUTPUT.tex and OUTPUT.csv (e.g. -o tables/tum)"
    )
    table.set_defaults(handler=_cmd_table)

    board = actions.add_parser(
        "leaderboard",
        help="a static HTML page over results files of one benchmark: a row per tracker, sortable, "
        "with the spread over seeds",
    )
    board.add_argument("results", nargs="+", type=Path, help="results.json files (or their folders)")
    board.add_argument("--baseline", type=Path, help="results rho is taken against (a column of its own)")
    board.add_argument("-o", "--output", type=Path, required=True, help="the page to write (an .html file)")
    board.add_argument("--overwrite", action="store_true", help="replace an existing page")
    board.set_defaults(handler=_cmd_leaderboard)

    verify = actions.add_parser(
        "verify",
        help="recompute every figure of a results file from the trajectories and sequences it names",
    )
    verify.add_argument("results", type=Path, help="a results.json (or its folder)")
    verify.set_defaults(handler=_cmd_verify)
    for child, what, examples in (
        (listing, "the benchmarks, their scenarios, seeds and state", ["depotbench benchmark list"]),
        (run, "results.json's content", ["depotbench benchmark run smoke-1 -o bench/none"]),
        (table, "the table's rows", ["depotbench benchmark table bench/flow --baseline bench/none -o t"]),
        (
            board,
            "the page written",
            ["depotbench benchmark leaderboard bench/* --baseline bench/none -o board.html"],
        ),
        (
            verify,
            "the problems found (none: every figure recomputed)",
            ["depotbench benchmark verify bench/flow"],
        ),
    ):
        add_json(child, what)
        add_verbosity(child, top=False)
        add_version(child)
        child.epilog = "examples:\n" + "\n".join(f"  {e}" for e in examples)
        child.formatter_class = argparse.RawDescriptionHelpFormatter


def _cmd_list(args: argparse.Namespace) -> int:
    from depotbench.core.examples import Kind, examples
    from depotbench.eval.benchmark.spec import load_benchmark
    from depotbench.sim.machine import machine_kind, machine_summary

    here = machine_kind(machine_summary())
    found, lines = [], []
    for example in examples().values():
        if example.kind is not Kind.BENCHMARK:
            continue
        b = load_benchmark(example.path)
        frozen = sum(s.files_key is not None for s in b.sequences)
        state = "frozen" if b.frozen else f"{frozen} of {len(b.sequences)} sequences frozen"
        kinds: dict[str, int] = {}  # machine kind: how many sequences hold its bytes
        for sequence in b.sequences:
            for kind in {machine_kind(on) for _, on in sequence.machines() if on}:
                kinds[kind] = kinds.get(kind, 0) + 1
        found.append(
            {
                "name": b.name,
                "description": " ".join(b.spec.description.split()),
                "generator": b.spec.generator,
                "cite": b.spec.cite,
                "sequences": len(b.sequences),
                "frozen": frozen,
                "frames": sum(s.frames for s in b.sequences),
                "scenarios": [e.model_dump() for e in b.spec.scenarios],
                "machines": kinds,
                "here": kinds.get(here, 0),
            }
        )
        lines.append(
            f"{b.name}: {len(b.sequences)} sequences, {sum(s.frames for s in b.sequences)} frames; "
            f"generator {b.spec.generator}; {state}; {kinds.get(here, 0)} frozen on this kind of machine"
        )
        for kind, count in kinds.items():
            lines.append(f"  frozen on {kind}{' (this kind)' if kind == here else ''}: {count}")
        for entry in b.spec.scenarios:
            length = "its own length" if entry.frames is None else f"{entry.frames} frames"
            seeds = entry.seeds
            shown = f"{seeds[0]}-{seeds[-1]}" if seeds == list(range(seeds[0], seeds[-1] + 1)) else seeds
            lines.append(f"  {entry.scenario}: seeds {shown}, {length}")
    print_result(args, {"machine": here, "benchmarks": found}, "\n".join(lines))
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from depotbench.detectors.config import DetectorConfig
    from depotbench.eval.benchmark.runner import Plan, repeats_for, run_benchmark
    from depotbench.eval.benchmark.spec import load_benchmark
    from depotbench.eval.benchmark.table import (
        fresh_comparison,
        fresh_markdown,
        markdown,
        parameter_notes,
        rows,
        tracker_labels,
    )
    from depotbench.eval.run.harness import RunJob

    tracker, settings = tracker_from_args(args)
    if args.not_deterministic and not tracker.type.command:
        raise InputError("--not-deterministic applies to --slam cmd (ORB-SLAM3 is repeated anyway)")
    deterministic = tracker.kind == "builtin" or (tracker.type.command and not args.not_deterministic)
    repeats = repeats_for(deterministic, args.repeats)
    if args.fresh_seeds < 0 or args.fresh_seeds > 1000:
        raise InputError(f"--fresh-seeds: 0 to 1000 a scenario, got {args.fresh_seeds}")
    if args.fresh_entropy is not None and (not args.fresh_seeds or args.fresh_entropy < 0):
        raise InputError("--fresh-entropy: a number of 0 or more, with --fresh-seeds")
    benchmark = load_benchmark(args.benchmark)
    detector = detector_config(args) or DetectorConfig()
    job = RunJob(Path("."), args.strategy, detector, tuple(sorted(settings.items())), tracker)
    plan = Plan(job, repeats, deterministic)
    results = run_benchmark(
        benchmark,
        plan,
        args.output,
        args.workers,
        fresh_seeds=args.fresh_seeds,
        entropy=args.fresh_entropy,
        sequences_root=args.sequences,
        **backend_of(args),
    )
    results["_path"] = str(args.output / "results.json")
    failed = sum(r["status"] != "ok" for s in results["sequences"] for r in s["runs"])
    (label,) = tracker_labels([results])
    title = f"{benchmark.name}: {results['tracker']['label']}"
    text = markdown(rows(results, label=label), title, repeats > 1, parameter_notes([results]))
    comparison = fresh_comparison(results)
    if comparison is not None:
        text += "\n" + fresh_markdown(comparison, args.fresh_seeds)
    text += f"\nwrote {args.output / 'results.json'} ({failed} failed runs) in {results['seconds']:.0f} s"
    print_result(args, {k: v for k, v in results.items() if k != "_path"}, text)
    return 0


def _cmd_table(args: argparse.Namespace) -> int:
    from depotbench.core.output import write_text_atomic
    from depotbench.eval.benchmark.results import load_results
    from depotbench.eval.benchmark.table import (
        csv_text,
        fresh_comparison,
        fresh_markdown,
        latex,
        markdown,
        parameter_notes,
        rows,
        tracker_labels,
    )

    loaded = [load_results(p) for p in args.results]
    names = {r["benchmark"] for r in loaded}
    if len(names) > 1:
        raise InputError(
            f"the results score different benchmarks ({', '.join(sorted(names))}): one table each"
        )
    baseline = load_results(args.baseline) if args.baseline is not None else None
    labels = tracker_labels(loaded)
    all_rows = [
        row for results, label in zip(loaded, labels, strict=True) for row in rows(results, baseline, label)
    ]
    notes = parameter_notes(loaded)
    order = list(dict.fromkeys(r.scenario for r in all_rows))
    all_rows.sort(key=lambda r: order.index(r.scenario))
    repeats = any(r["repeats"] > 1 for r in loaded)
    title = f"{loaded[0]['benchmark']}" + (
        f", rho against {baseline['tracker']['label']} {baseline['tracker']['strategy']}" if baseline else ""
    )
    text = markdown(all_rows, title, repeats, notes)
    fresh = {}
    for results in loaded:
        comparison = fresh_comparison(results)
        if comparison is not None:
            fresh[results["_path"]] = comparison.to_dict()
            count = len(next(iter(results["fresh"]["seeds"].values())))
            text += f"\n{results['_path']}:\n" + fresh_markdown(comparison, count)
    written = []
    if args.output is not None:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        for suffix, content in (
            (".md", text),
            (".tex", latex(all_rows, title, repeats, notes)),
            (".csv", csv_text(loaded, baseline)),
        ):
            written.append(args.output.with_name(args.output.name + suffix))
            write_text_atomic(written[-1], content)
        text += f"\nwrote {args.output}.md, .tex and .csv"
    result = {"rows": [row.to_dict() for row in all_rows], "fresh": fresh, "files": written}
    print_result(args, result, text)
    return 0


def _cmd_leaderboard(args: argparse.Namespace) -> int:
    from depotbench.core.output import write_text_atomic
    from depotbench.eval.benchmark.leaderboard import page
    from depotbench.eval.benchmark.results import load_results

    if args.output.exists() and not args.overwrite:
        raise InputError(f"{args.output}: exists; --overwrite replaces it")
    if args.output.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"{args.output}: the page is an .html file")
    loaded = [load_results(p) for p in args.results]
    baseline = load_results(args.baseline) if args.baseline is not None else None
    text = page(loaded, baseline)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output, text)
    print_result(
        args,
        {"page": args.output, "results": len(loaded)},
        f"wrote {args.output} ({len(loaded)} results files)",
    )
    return 0


def _cmd_verify(args: argparse.Namespace) -> int:
    from depotbench.eval.benchmark.results import load_results, verify_results

    results = load_results(args.results)
    problems = verify_results(results)
    sequences = [*results["sequences"], *((results.get("fresh") or {}).get("sequences") or [])]
    runs = sum(len(s["runs"]) for s in sequences)
    if problems:
        text = "\n".join([*problems, f"{results['_path']}: {len(problems)} problems in {runs} runs"])
    else:
        count = len(sequences)
        text = f"{results['_path']}: every figure of {runs} runs on {count} sequences recomputed"
    print_result(args, {"results": Path(results["_path"]), "runs": runs, "problems": problems}, text)
    return 1 if problems else 0
