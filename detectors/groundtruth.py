"""The ground-truth detector: the true visible boxes of a generated sequence.

Priors come from the class table (``depotbench.detectors.priors``), as a real detector's
would, not from the simulator's own labels. Beside the boxes it knows what makes
each object hard to see (``Difficulty``: size, occlusion, image motion), which
fault injection and detector evaluation use.
"""

from __future__ import annotations

import cv2
import numpy as np
from depotbench.core.errors import InputError
from depotbench.detectors.base import DetectorFrame
from depotbench.detectors.detection import Detection
from depotbench.detectors.faults import Difficulty
from depotbench.detectors.priors import DEFAULT_PRIORS, PriorTable
from depotbench.sim.ground_truth import ObjectState
from depotbench.sim.sequence import Sequence

OCCLUDER_MARGIN_M = 0.05
"""A neighbouring pixel occludes when it is this much nearer than the object beside it."""
_RING = np.ones((5, 5), np.uint8)


class GroundTruthDetector:
    name = "groundtruth"

    def __init__(
        self, sequence: Sequence, min_visible_pixels: int = 20, priors: PriorTable = DEFAULT_PRIORS
    ) -> None:
        if not sequence.is_generated:
            raise InputError(
                f"{sequence.root}: the groundtruth detector needs a generated sequence "
                "(use --detector none or onnx on a real TUM folder)"
            )
        self.sequence = sequence
        self._objects = sequence.objects()
        self.min_visible_pixels = min_visible_pixels
        self.priors = priors

    def visible(self, index: int) -> tuple[ObjectState, ...]:
        """The objects that get a box in frame ``index``, in the order of ``detect``."""
        return tuple(
            o
            for o in self._objects[index]
            if o.box_xyxy is not None and o.visible_pixels >= self.min_visible_pixels
        )

    def detect(self, frame: DetectorFrame) -> tuple[Detection, ...]:
        return tuple(
            Detection(tuple(float(v) for v in o.box_xyxy), o.class_name, self.priors.prior(o.class_name), 1.0)
            for o in self.visible(frame.index)
        )

    def difficulties(self, index: int) -> tuple[Difficulty, ...]:
        """Per box of ``detect``: area, occlusion and image speed (reads depth and instances)."""
        objects = self.visible(index)
        if not objects:
            return ()
        exact = all(o.visible_fraction is not None for o in objects)
        instances = None if exact else self.sequence.instances(index)
        depth = None if exact else self.sequence.depth_m(index)
        return tuple(
            Difficulty(
                area_px=float((o.box_xyxy[2] - o.box_xyxy[0]) * (o.box_xyxy[3] - o.box_xyxy[1])),
                occlusion=1.0 - o.visible_fraction
                if o.visible_fraction is not None
                else occlusion(instances, depth, o.instance_id, o.box_xyxy),
                speed_px=self._speed_px(index, o),
            )
            for o in objects
        )

    def _speed_px(self, index: int, obj: ObjectState) -> float:
        """How far the object's origin moves in the image to the next frame (the previous, at the end)."""
        other = index + 1 if index + 1 < len(self._objects) else index - 1
        if other < 0:
            return 0.0
        match = [o for o in self._objects[other] if o.instance_id == obj.instance_id]
        if not match:
            return 0.0
        a = self._project(index, np.array(obj.position_m))
        b = self._project(other, np.array(match[0].position_m))
        if a is None or b is None:
            return 0.0
        return float(np.linalg.norm(a - b))

    def _project(self, index: int, point_w: np.ndarray) -> np.ndarray | None:
        pose = self.sequence.world_from_camera(index)
        p = pose[:3, :3].T @ (point_w - pose[:3, 3])
        if p[2] <= 1e-3:
            return None
        k = self.sequence.intrinsics
        return np.array([k.fx * p[0] / p[2] + k.cx, k.fy * p[1] / p[2] + k.cy])


def occlusion(
    instances: np.ndarray, depth_m: np.ndarray, instance_id: int, box_xyxy: tuple[int, int, int, int]
) -> float:
    """The share of the object's outline that borders a nearer surface: the occlusion of
    sequences that do not record the visible fraction.

    Each pixel in a 2-px ring around the object's mask is compared with the
    object's nearest depth within 2 px of it: nearer by more than 5 cm is an
    occluder (the desk in front of a seated person, another person). The image
    border is truncation, not occlusion, and does not count.
    """
    height, width = instances.shape
    x0, y0, x1, y1 = box_xyxy
    c0, r0 = max(0, x0 - 3), max(0, y0 - 3)
    c1, r1 = min(width, x1 + 3), min(height, y1 + 3)
    mask = instances[r0:r1, c0:c1] == instance_id
    if not mask.any():
        return 0.0
    depth = depth_m[r0:r1, c0:c1].astype(np.float32)
    ring = (cv2.dilate(mask.astype(np.uint8), _RING) > 0) & ~mask
    if not ring.any():
        return 0.0
    own = np.where(mask & (depth > 0), depth, np.float32(np.inf)).astype(np.float32)
    nearest_own = cv2.erode(own, _RING, borderType=cv2.BORDER_CONSTANT, borderValue=float(np.inf))
    occluder = ring & (depth > 0) & (depth < nearest_own - OCCLUDER_MARGIN_M)
    return float(occluder.sum() / ring.sum())


def is_truncated(obj: ObjectState, width: int, height: int) -> bool:
    """Whether the image border cuts the object: recorded by the generator, or for older
    sequences (and TUM folders) guessed from its visible box touching the border."""
    if obj.truncated is not None:
        return obj.truncated
    assert obj.box_xyxy is not None
    return truncated(obj.box_xyxy, width, height)


def truncated(box_xyxy: tuple[float, float, float, float], width: int, height: int) -> bool:
    """Whether a visible box touches the image border (the object is cut by it)."""
    x0, y0, x1, y1 = box_xyxy
    return x0 <= 0 or y0 <= 0 or x1 >= width or y1 >= height
