"""smoke-1's sequences for the tests, checked against the shipped lock wherever the lock can
hold: on a machine of a kind that froze it.

A lock's keys are some machine kinds' bytes (docs/benchmarks.md, "Where the keys hold"): a
machine with another CPU, renderer or OpenCV may draw other pixels from the same spec (an
AVX-512 EPYC did until its numpy and OpenBLAS were set to their AVX2 code,
docs/determinism.md). On a machine of a kind
the lock does not name the shipped lock must refuse the sequences naming the machines,
which is checked, and the tests that need a frozen smoke-1 use a copy frozen on this
machine by ``benchmarks/freeze.py --replace``, with a warning that says so. On a kind the
lock names the bytes must be that kind's: a difference there is the generator's, and
fails."""

from __future__ import annotations

import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from depotbench.core.errors import InputError
from depotbench.eval.benchmark.sequences import prepare
from depotbench.eval.benchmark.spec import Benchmark, load_benchmark, lock_path
from depotbench.eval.run.detections import sequence_fingerprint
from depotbench.sim.machine import machine_kind, machine_summary
from depotbench.sim.sequence import Sequence

from tests.conftest import REPO

SHIPPED = "smoke-1"


def copy_of_smoke(folder: Path, name: str = SHIPPED) -> Path:
    """smoke-1's file and its lock (the shipped ones, or those of ``name``: a copy frozen
    here) copied into ``folder``; returns the file's path."""
    source = load_benchmark(name).path
    shutil.copy(source, folder / source.name)
    shutil.copy(lock_path(source), lock_path(folder / source.name))
    return folder / source.name


def freeze(benchmark: Path, sequences: Path, *words: str) -> subprocess.CompletedProcess:
    command = [
        sys.executable,
        str(REPO / "benchmarks" / "freeze.py"),
        str(benchmark),
        "--sequences",
        str(sequences),
    ]
    return subprocess.run([*command, *words], capture_output=True, text=True, timeout=300)


def smoke_1(root: Path) -> str:
    """smoke-1 generated from empty caches into ``root/sequences``; returns what to name the
    benchmark by: ``smoke-1`` where the shipped lock holds these bytes, else the path of a
    copy frozen here (under ``root/frozen-here``)."""
    shipped = load_benchmark(SHIPPED)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("DEPOTBENCH_CACHE", "off")
        try:
            prepare(shipped, root / "sequences", workers=1, progress=False)
        except InputError as refused:
            here = machine_summary()
            assert f"; this is {here};" in str(refused)
            other = other_bytes(shipped, root / "sequences")
            kinds = {None if on is None else machine_kind(on) for ons in other.values() for on in ons}
            if not other or None in kinds or machine_kind(here) in kinds:
                raise  # made on a machine kind the lock names: the generator changed
        else:
            return SHIPPED
    (root / "frozen-here").mkdir(parents=True)
    copy = copy_of_smoke(root / "frozen-here")
    done = freeze(copy, root / "sequences", "--replace")
    assert done.returncode == 0, done.stderr
    prepare(load_benchmark(copy), root / "sequences", workers=1, progress=False)  # holds them now
    machines = "; ".join(f"{name} on {' or '.join(map(str, ons))}" for name, ons in other.items())
    warnings.warn(
        f"{SHIPPED}: this machine ({here}) makes other bytes than its lock's (frozen: {machines}), "
        f"as the lock refused them; the tests use a copy frozen here ({copy})",
        stacklevel=2,
    )
    return str(copy)


def other_bytes(benchmark: Benchmark, folder: Path) -> dict[str, tuple[str | None, ...]]:
    """The sequences of ``folder`` whose files are none of the lock's, and the machines each
    was frozen on."""
    return {
        s.folder: tuple(on for _, on in s.machines())
        for s in benchmark.sequences
        if sequence_fingerprint(Sequence.open(folder / s.folder)) not in s.frozen_keys()
    }
