"""``depotbench sweep``: a sweep spec in, a results database, CSV, plots and the best settings out."""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from sim.errors import InputError


def add_sweep(sub: argparse._SubParsersAction) -> None:
    from eval.cli import _workers  # the CLI's own --workers type (eval.cli imports this module)

    p = sub.add_parser(
        "sweep",
        help="run a threshold sweep (a YAML spec) into a resumable SQLite database, with CSV and plots",
    )
    p.add_argument("spec", type=Path, help="the sweep spec (see assets/sweeps/)")
    p.add_argument("-o", "--output", type=Path, required=True, help="the sweep folder (resumed if it exists)")
    p.add_argument("--workers", type=_workers, default=max(1, os.cpu_count() or 1), help="worker processes")
    p.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="where runs execute: local worker processes, or Ray (extra [ray]; a local instance, "
        "or the cluster at --address)",
    )
    p.add_argument("--address", help="--backend ray: the cluster's address (default: start a local Ray)")
    p.add_argument(
        "--no-dedupe",
        action="store_true",
        help="track every job, even where another keeps the same keypoints in every frame",
    )
    p.set_defaults(handler=_cmd_sweep)


def _cmd_sweep(args: argparse.Namespace) -> int:
    from eval.search import run_search
    from eval.sweep import expand, open_store, run_jobs, sequences_of, validate
    from eval.sweep_report import best_per_family, configurations, format_best, pareto, plot, with_rho
    from eval.sweep_spec import load_sweep
    from sim.files import dumps_json
    from sim.output import OutputContainer, OutputKind, write_text_atomic

    if args.address and args.backend != "ray":
        raise InputError("--address applies to --backend ray only")
    spec = load_sweep(args.spec)
    validate(spec, args.spec)  # before the output folder is made
    with OutputContainer(args.output, OutputKind.SWEEP, inputs=(args.spec,)) as container:
        out = container.path
        backend = {"backend": args.backend, "address": args.address}
        sequences = sequences_of(spec, args.spec, out, args.workers, progress=True, **backend)
        jobs = expand(spec, args.spec, sequences)
        with open_store(out, spec) as store:
            done = len(store.keys() & {j.key for j in jobs})
            print(
                f"sweep {spec.sweep}: {len(jobs)} runs over {len(sequences)} sequences ({done} already done)"
            )
            started = time.perf_counter()
            ran, written = run_jobs(jobs, store, args.workers, dedupe=not args.no_dedupe, **backend)
            elapsed = time.perf_counter() - started
            # A family is how this sweep groups sequences, not part of a run's content:
            # rows carry the family of the sweep that asked for them now.
            family = {j.key: j.family for j in jobs}
            search = None
            if spec.search is not None:
                search = run_search(spec, args.spec, sequences, store, out, args.workers, **backend)
                family |= search.pop("families")
            rows = [r | {"family": family[r["key"]]} for r in store.rows() if r["key"] in family]
            store.export_csv(out / "results.csv", with_rho(rows))
        configs = configurations(rows)
        best = best_per_family(configs)
        summary = {"best": best, "pareto": pareto(configs), "configurations": configs, "search": search}
        write_text_atomic(out / "summary.json", dumps_json(summary) + "\n")
        plots = plot(configs, out / "plots")
    rate = f", {written / elapsed * 60:.1f} rows/min" if written and elapsed > 0 else ""
    print(
        f"wrote {written} rows in {elapsed:.1f} s{rate}; tracked {ran} of them "
        "(the others keep the same keypoints in every frame as a tracked one)"
    )
    print(format_best(best))
    if search is not None:
        print(
            f"search ({search['trials']} trials, {search['objective']}): best {search['strategy']} "
            f"{search['settings']} -> {search['value']:.5f}; study in {args.output / 'optuna.sqlite'}"
        )
    shown = f", plots in {args.output / 'plots'}" if plots else " (pip install 'depotbench[viz]' for plots)"
    print(f"wrote {args.output / 'results.sqlite'}, results.csv, summary.json{shown}")
    return 0
