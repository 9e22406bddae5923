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
    peer = statistics.median(next(iter(times.values())))
    print(f"{'command':32s} {'median ms':>10s} {'fastest':>8s} {'x peer':>7s}")
    for name, values in times.items():
        median = statistics.median(values)
        print(f"{name:32s} {median:10.0f} {min(values):8.0f} {median / peer:7.1f}")


if __name__ == "__main__":
    main()
