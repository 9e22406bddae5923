"""The placeholders of an external program's command template (docs/external-trackers.md).

A module without imports: ``depotbench run --help`` lists them from here, and building the
parsers imports no NumPy (``depotbench.eval.trackers.command`` fills them in).
"""

from __future__ import annotations

PLACEHOLDERS = (
    "sequence",
    "associations",
    "settings",
    "vocabulary",
    "trajectory",
    "detections",
    "keypoints",
    "parameters",
    "map",
    "times",
)
"""Each reaches the program as one whole word and as ``DEPOTBENCH_`` + its upper case."""
