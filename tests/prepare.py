"""What the test workers share, built once before they start (``make test`` runs this).

Without it the first workers build them side by side inside the timed run: the default ORB
vocabulary (a minute from an empty cache; the tests share the user's, see conftest.py) and
the compiled kernels (Numba's cache beside the package: 40-50 s to compile the tracker's and
5 s the generator's, 0.5 s to load) and the package's bytecode. The kernels compile in two
processes side by side, split by their measured compile times (about 26 and 30 s). Where
the user's vocabulary cache is off, the tests build a private one, as before.
"""

from __future__ import annotations

import compileall
import multiprocessing
import time
import tomllib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from depotbench.core.errors import InputError
from depotbench.eval.trackers.vocabulary import default_vocabulary
from depotbench.sim import kernels as generator_kernels
from depotbench.slam import kernels

REPO = Path(__file__).resolve().parents[1]


def compile_sources() -> None:
    """The package's own bytecode, written beside its sources (an editable install): where
    PYTHONDONTWRITEBYTECODE is set, as in CI, Python never writes it, and each of the
    hundreds of processes the tests start would compile every module it imports. Only files
    newer than their bytecode are compiled (0.3 s when none changed)."""
    folders = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    for folder in sorted(set(folders.values())):
        compileall.compile_dir(REPO / folder, quiet=1)


KERNEL_HALVES = (("optimize", "rejection"), ("matching", "features"))
"""The tracker's kernel modules in two halves of about the same compile time (20 + 1 s with
the generator's 5 s, against 13 + 17 s)."""


def compile_kernels(parts: tuple[str, ...], generator: bool) -> None:
    kernels.warm_up(parts)
    if generator:
        generator_kernels.warm_up()


def main() -> None:
    started = time.perf_counter()
    compile_sources()
    try:
        vocabulary = default_vocabulary()
    except InputError as exc:
        vocabulary = f"none ({exc})"
    seconds = 0.0
    if kernels.compiled():
        began = time.perf_counter()
        spawn = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(len(KERNEL_HALVES), mp_context=spawn) as pool:
            # list() takes every result, so a half that failed raises here
            list(pool.map(compile_kernels, KERNEL_HALVES, (True, False)))
        seconds = time.perf_counter() - began
    print(
        f"tests/prepare.py: vocabulary {vocabulary}; kernels ready in {seconds:.1f} s; "
        f"{time.perf_counter() - started:.1f} s in all"
    )


if __name__ == "__main__":
    main()
