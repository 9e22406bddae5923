"""The plain detection type that crosses from detectors into SLAM.

This module imports nothing from the project: ``slam`` may import it and nothing
else outside its own package (the import graph, tests/test_architecture.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum


class Prior(StrEnum):
    """How likely a class is to move (docs/methods.md, method 1)."""

    DYNAMIC = "dynamic"
    POTENTIAL = "potential"
    STATIC = "static"


@dataclass(frozen=True)
class Detection:
    """One 2D box in pixel-edge coordinates (pixel u covers [u, u+1))."""

    box_xyxy: tuple[float, float, float, float]
    class_name: str
    prior: Prior
    confidence: float

    def __post_init__(self) -> None:
        x0, y0, x1, y1 = self.box_xyxy
        if not all(math.isfinite(v) for v in self.box_xyxy) or x1 <= x0 or y1 <= y0:
            raise ValueError(f"box {self.box_xyxy} must be finite with x0 < x1 and y0 < y1")
        if not 0.0 <= self.confidence <= 1.0:
            raise ValueError(f"confidence {self.confidence} must lie in [0, 1]")
