"""What every detector is: a callable from a frame to boxes.

The harness builds detectors from a ``DetectorConfig`` (``depotbench.detectors.config``);
this Protocol is what it then calls, so a user's own detector plugs in by
having a ``name`` and a ``detect``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from depotbench.detectors.detection import Detection


@dataclass(frozen=True)
class DetectorFrame:
    """One frame as a detector sees it."""

    index: int
    timestamp_s: float
    rgb: np.ndarray
    """H x W x 3, uint8, RGB."""


class Detector(Protocol):
    name: str

    def detect(self, frame: DetectorFrame) -> tuple[Detection, ...]: ...
