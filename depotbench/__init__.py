"""depotbench: a simulation-backed test bench for dynamic visual SLAM.

``import depotbench`` gives the command line's jobs as functions on typed values
(``depotbench.api``): ``scenario``, ``generate``, ``generate_suite``, ``run``, ``sweep``,
``check``, ``compare``, ``report`` and ``evaluate``. They load the parts they use when
called, so the import itself stays light (no MuJoCo, OpenCV or ONNX Runtime).

The parts are subpackages, in the order of the pipeline: ``depotbench.sim`` (worlds,
rendering, the sequence format), ``depotbench.scenes`` (scenario specs and suites),
``depotbench.detectors``, ``depotbench.slam`` (the built-in tracker), ``depotbench.eval``
(metrics, trackers, runs, sweeps, gates, reports, the command line), and ``depotbench.core``
(the plumbing they share).
"""

from depotbench.api import (
    SweepResult,
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
from depotbench.core.version import generator_version

__version__ = generator_version()

__all__ = [
    "SweepResult",
    "__version__",
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
