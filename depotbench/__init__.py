"""depotbench: a simulation-backed test bench for dynamic visual SLAM.

``import depotbench`` gives the command line's jobs as functions on typed values
(``depotbench.api``): ``scenario``, ``generate``, ``generate_suite``, ``run``, ``sweep``,
``check``, ``compare``, ``report``, ``benchmark`` and ``evaluate``, and the typed results
they return (``SweepResult``, ``SweepSummary``, ``Configuration``, ``Comparisons``,
``BenchmarkResult``). The import itself
stays light (no MuJoCo, OpenCV or ONNX Runtime): the API loads at the first use of one of
its names (about 1 s, the types its signatures name), MuJoCo and ONNX Runtime when a
function needs them.

The parts are subpackages, in the order of the pipeline: ``depotbench.sim`` (worlds,
rendering, the sequence format), ``depotbench.scenes`` (scenario specs and suites),
``depotbench.detectors``, ``depotbench.slam`` (the built-in tracker), ``depotbench.eval``
(metrics, trackers, runs, sweeps, gates, reports, the command line), and ``depotbench.core``
(the plumbing they share).
"""

from __future__ import annotations

import importlib
import sys

if "numpy" not in sys.modules:  # numpy and OpenBLAS read their CPU switches as they load
    from depotbench.core.numerics import apply_reference_environment

    apply_reference_environment()  # on an AVX-512 CPU, their AVX2 code: the bytes CI froze
    del apply_reference_environment

TYPE_CHECKING = False  # typing itself costs 5 ms of the time before Ctrl-C is handled
if TYPE_CHECKING:
    from depotbench.api import (
        BenchmarkResult,
        Comparisons,
        Configuration,
        MissingExtra,
        SweepResult,
        SweepSummary,
        benchmark,
        check,
        compare,
        evaluate,
        generate,
        generate_suite,
        report,
        run,
        scenario,
        sweep,
    )


__all__ = [
    "BenchmarkResult",
    "Comparisons",
    "Configuration",
    "MissingExtra",
    "SweepResult",
    "SweepSummary",
    "__version__",
    "benchmark",
    "check",
    "compare",
    "evaluate",
    "generate",
    "generate_suite",
    "report",
    "run",
    "scenario",
    "sweep",
]


def __getattr__(name: str) -> object:
    """The API's names and ``__version__``, loaded at first use (PEP 562): every module of the
    package imports this one first, the command line's first module too, and a Ctrl-C is the
    command line's to report only once that module has run (importing ``depotbench.api`` and
    the package metadata here cost 40 ms, the window of probe C15's tracebacks)."""
    if name == "__version__":
        from depotbench.core.version import package_version

        return package_version()
    if name in __all__:
        return getattr(importlib.import_module("depotbench.api"), name)
    raise AttributeError(f"module 'depotbench' has no attribute {name!r}")
