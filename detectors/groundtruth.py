"""The ground-truth detector: the true visible boxes of a generated sequence.

Priors come from the class table (``detectors.priors``), as a real detector's
would, not from the simulator's own labels.
"""

from __future__ import annotations

from detectors.detection import Detection
from detectors.priors import prior_of
from sim.errors import InputError
from sim.sequence import Sequence


class GroundTruthDetector:
    name = "groundtruth"

    def __init__(self, sequence: Sequence, min_visible_pixels: int = 20) -> None:
        if not sequence.is_generated:
            raise InputError(
                f"{sequence.root}: the groundtruth detector needs a generated sequence "
                "(use --detector none on a real TUM folder)"
            )
        self._objects = sequence.objects()
        self.min_visible_pixels = min_visible_pixels

    def detect(self, index: int) -> tuple[Detection, ...]:
        return tuple(
            Detection(tuple(float(v) for v in o.box_xyxy), o.class_name, prior_of(o.class_name), 1.0)
            for o in self._objects[index]
            if o.box_xyxy is not None and o.visible_pixels >= self.min_visible_pixels
        )
