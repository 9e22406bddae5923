"""Argument types the command line's modules share: numbers checked where they are parsed,
with a message that names the rule (argparse would name the function instead)."""

from __future__ import annotations

import argparse
import math
import os


def finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def positive_float(text: str) -> float:
    value = finite_float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


WORKERS_VARIABLE = "DEPOTBENCH_WORKERS"
MAX_WORKERS = 256
WORKERS_HELP = f"worker processes (default: {WORKERS_VARIABLE} where set, else one per core)"


def one_per_core() -> int:
    """The default ``--workers``: ``DEPOTBENCH_WORKERS`` where set, else one per core this
    process may run on (its affinity: a container or a ``taskset`` limited to 2 of a host's
    64 cores started 64 workers, as ``os.cpu_count`` counts the host's)."""
    from depotbench.core.errors import InputError

    raw = os.environ.get(WORKERS_VARIABLE, "").strip()
    if not raw:
        cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else range(os.cpu_count() or 1)
        return max(1, len(cores))
    if not raw.isdigit() or not 1 <= int(raw) <= MAX_WORKERS:
        raise InputError(f"{WORKERS_VARIABLE}={raw!r}: give the default worker count, 1 to {MAX_WORKERS}")
    return int(raw)


def workers(text: str) -> int:
    """A worker count; argparse would name this function in its message ("invalid _workers
    value"), so a word is refused here."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number of workers, got {text!r}") from None
    if not 1 <= value <= MAX_WORKERS:
        raise argparse.ArgumentTypeError(f"must be between 1 and {MAX_WORKERS}, got {text}")
    return value


def add_backend(parser: argparse.ArgumentParser) -> None:
    """``--backend`` and ``--address``: where jobs run (``docs/cluster.md``)."""
    parser.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="where runs execute: local worker processes, or Ray (extra [ray]; a local instance, "
        "or the cluster at --address)",
    )
    parser.add_argument("--address", help="--backend ray: the cluster's address (default: start a local Ray)")


def backend_of(args: argparse.Namespace) -> dict[str, str | None]:
    """The parsed ``add_backend`` options, checked together."""
    from depotbench.core.errors import InputError

    if args.address and args.backend != "ray":
        raise InputError("--address applies to --backend ray only")
    return {"backend": args.backend, "address": args.address}
