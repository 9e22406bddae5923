"""What the test workers share, built once before they start (``make test`` runs this).

Without it the first workers build them side by side inside the timed run: the default ORB
vocabulary (a minute from an empty cache; the tests share the user's, see conftest.py) and
the compiled kernels (Numba's cache beside the package: 14 s a process to compile, 0.5 s to
load) and the package's bytecode. Where the user's vocabulary cache is off, the tests build
a private one, as before.
"""

from __future__ import annotations

import compileall
import time
import tomllib
from pathlib import Path

from depotbench.core.errors import InputError
from depotbench.eval.trackers.vocabulary import default_vocabulary
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


def main() -> None:
    started = time.perf_counter()
    compile_sources()
    try:
        vocabulary = default_vocabulary()
    except InputError as exc:
        vocabulary = f"none ({exc})"
    seconds = kernels.warm_up() if kernels.compiled() else 0.0
    print(
        f"tests/prepare.py: vocabulary {vocabulary}; kernels ready in {seconds:.1f} s; "
        f"{time.perf_counter() - started:.1f} s in all"
    )


if __name__ == "__main__":
    main()
