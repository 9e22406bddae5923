"""A picture of a sequence frame: RGB, depth as a colour map, instances with their boxes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from depotbench.core.output import write_bytes_atomic
from depotbench.sim.ground_truth import ObjectState
from depotbench.sim.sequence import Sequence

DEPTH_RANGE_M = 8.0


def preview(
    seq: Sequence,
    index: int,
    max_depth_m: float = DEPTH_RANGE_M,
    objects: tuple[ObjectState, ...] | None = None,
) -> np.ndarray:
    """One RGB image (H, 3W, 3): the frame, its depth, and the instance overlay with boxes.

    ``objects`` are the frame's ground truth, when the caller has read them already.
    """
    rgb = seq.rgb(index)
    depth = seq.depth_m(index)
    scaled = (np.clip(depth / max_depth_m, 0, 1) * 255).astype(np.uint8)
    depth_rgb = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)[:, :, ::-1].copy()
    depth_rgb[depth == 0] = 0
    overlay = rgb.copy()
    if seq.is_generated:
        instances = seq.instances(index)
        palette = np.random.default_rng(0).integers(60, 255, (int(instances.max()) + 1, 3))
        mask = instances > 0
        overlay[mask] = (0.45 * overlay[mask] + 0.55 * palette[instances[mask]]).astype(np.uint8)
        for obj in seq.objects()[index] if objects is None else objects:
            if obj.box_xyxy is None:
                continue
            x0, y0, x1, y1 = obj.box_xyxy
            colour = (255, 60, 60) if obj.prior == "dynamic" else (255, 220, 0)
            cv2.rectangle(overlay, (x0, y0), (x1 - 1, y1 - 1), colour, 2)
            label = f"{obj.class_name}{' (moving)' if obj.moving else ''}"
            cv2.putText(
                overlay,
                label,
                (x0 + 2, max(12, y0 + 14)),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.45,
                colour,
                1,
                cv2.LINE_AA,
            )
    return np.hstack([rgb, depth_rgb, overlay])


def save_png(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB image as a PNG, atomically (never seen half-written)."""
    write_bytes_atomic(path, cv2.imencode(".png", rgb[:, :, ::-1])[1].tobytes())
