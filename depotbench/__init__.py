"""depotbench: a simulation-backed test bench for dynamic visual SLAM.

The package's parts are its subpackages, in the order of the pipeline: ``depotbench.sim``
(worlds, rendering, the sequence format), ``depotbench.scenes`` (scenario specs and suites),
``depotbench.detectors``, ``depotbench.slam`` (the built-in tracker), ``depotbench.eval``
(metrics, trackers, runs, sweeps, gates, reports, the command line), and ``depotbench.core``
(the plumbing they share).
"""

from depotbench.core.version import generator_version

__version__ = generator_version()
