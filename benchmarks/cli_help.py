"""How long the command line takes to answer --help and --version, beside the interpreter
starting and doing nothing, in the same run (issue 39: --help under 0.5 s).

Usage: python benchmarks/cli_help.py [--repeat 20]

Each command runs ``--repeat`` times as a fresh process; the table gives the median and the
fastest wall time in milliseconds, and the median over the bare interpreter's.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

COMMANDS = {
    "python -c pass (the peer)": [sys.executable, "-c", "pass"],
    "python -c 'import numpy'": [sys.executable, "-c", "import numpy"],
    "depotbench --version": [sys.executable, "-m", "depotbench.eval.cli", "--version"],
    "depotbench --help": [sys.executable, "-m", "depotbench.eval.cli", "--help"],
    "depotbench run --help": [sys.executable, "-m", "depotbench.eval.cli", "run", "--help"],
    "depotbench completion bash": [sys.executable, "-m", "depotbench.eval.cli", "completion", "bash"],
}


def wall_ms(command: list[str]) -> float:
    started = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return (time.perf_counter() - started) * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    args = parser.parse_args()
    times = {name: [] for name in COMMANDS}
    for _ in range(args.repeat):  # interleaved, so that a busy moment hits every command alike
        for name, command in COMMANDS.items():
            times[name].append(wall_ms(command))
    print(table(times))


def table(times: dict[str, list[float]]) -> str:
    """Each command's median and fastest wall time, and its median over the first's (the peer)."""
    from depotbench.core.text_table import Column, render

    peer = statistics.median(next(iter(times.values())))
    columns = [Column("command", "left"), Column("median ms"), Column("fastest"), Column("x peer")]
    rows = [
        [name, f"{statistics.median(v):.0f}", f"{min(v):.0f}", f"{statistics.median(v) / peer:.1f}"]
        for name, v in times.items()
    ]
    return render(columns, rows)


if __name__ == "__main__":
    main()
