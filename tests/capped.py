"""Commands run in a child with an address-space cap, and their peak memory: the fuzz
suite's bound of 300 MB for any input, however large or endless."""

from __future__ import annotations

import os
import subprocess
import sys

from tests.conftest import REPO

MEMORY_CAP_BYTES = 2 << 30
"""Address-space cap of the child: a guard that stops a runaway before it eats the machine."""
MAX_RSS_MB = 300

_MEASURE = """
import resource, subprocess, sys
cap = int(sys.argv[1])
def limit():
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
proc = subprocess.run(sys.argv[2:], preexec_fn=limit, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
sys.stderr.buffer.write(proc.stderr[-100000:])
print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
sys.exit(proc.returncode if proc.returncode >= 0 else 128 - proc.returncode)
"""
"""Runs a command in a capped child and prints its peak RSS (KiB). A child's ru_maxrss starts
at its parent's resident size when it forks and execs, so measuring straight from pytest
reported pytest's own size (375 MB once earlier tests had grown it); this small fresh
process forks the command instead. The last 100 kB of the command's stderr are passed on."""


def peak_rss_mb(args: list[str], timeout_s: float | None = None) -> tuple[int, str, float]:
    """Exit code, stderr and peak resident memory (MB) of ``depotbench ARGS`` in a capped child."""
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            _MEASURE,
            str(MEMORY_CAP_BYTES),
            sys.executable,
            "-m",
            "depotbench.eval.cli.main",
            *args,
        ],
        cwd=REPO,
        capture_output=True,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
        timeout=timeout_s,
    )
    err = proc.stderr.decode("utf-8", "replace")
    return proc.returncode, err, int(proc.stdout.decode().strip().splitlines()[-1]) / 1024
