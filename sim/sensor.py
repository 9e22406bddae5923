"""Sensor models applied after rendering; the clean ground truth is kept beside them.

Depth follows a Kinect v1: axial noise sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 m
(Nguyen, Izadi and Lovell, 2012), disparity quantisation, no reading outside the
working range and, often, at depth edges. RGB gets sensor noise, motion blur
along each pixel's true motion during the exposure, and slow auto-exposure drift.
"""

from __future__ import annotations

import cv2
import numpy as np
from depotbench.sim.ipp import without_ipp
from depotbench.sim.spec import SensorSpec

KINECT_FOCAL_PX = 580.0
KINECT_BASELINE_M = 0.075
DISPARITY_STEP_PX = 1.0 / 8.0
EDGE_JUMP_M = 0.05
"""Neighbouring depths further apart than this make an edge pixel."""


def kinect_sigma(z_m: np.ndarray) -> np.ndarray:
    """Axial noise standard deviation (m) at depth z (Nguyen et al., 2012)."""
    return 0.0012 + 0.0019 * (z_m - 0.4) ** 2


class SensorModel:
    def __init__(self, spec: SensorSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self._gain_state = 0.0

    @property
    def needs_flow(self) -> bool:
        return self.spec.motion_blur_exposure_s > 0

    def depth(self, depth_m: np.ndarray) -> np.ndarray:
        s = self.spec
        z = depth_m.astype(np.float64)
        valid = z > 0
        if s.depth_noise:
            z = z + self.rng.standard_normal(z.shape) * kinect_sigma(z)
        if s.disparity_quantisation:
            fb = KINECT_FOCAL_PX * KINECT_BASELINE_M
            disparity = np.round(fb / np.maximum(z, 1e-6) / DISPARITY_STEP_PX) * DISPARITY_STEP_PX
            z = fb / np.maximum(disparity, DISPARITY_STEP_PX)
        valid &= (depth_m >= s.depth_range_m[0]) & (depth_m <= s.depth_range_m[1])
        if s.edge_dropout > 0:
            valid &= ~self._edges(depth_m, s.edge_dropout)
        return np.where(valid, z, 0.0).astype(np.float32)

    def _edges(self, depth_m: np.ndarray, probability: float) -> np.ndarray:
        grad = np.maximum(
            np.abs(np.diff(depth_m, axis=0, append=depth_m[-1:])),
            np.abs(np.diff(depth_m, axis=1, append=depth_m[:, -1:])),
        )
        edges = cv2.dilate((grad > EDGE_JUMP_M).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        return edges & (self.rng.uniform(size=depth_m.shape) < probability)

    def rgb(self, rgb: np.ndarray, flow_px: np.ndarray | None, fps: float) -> np.ndarray:
        s = self.spec
        image = rgb.astype(np.float32)
        if s.motion_blur_exposure_s > 0 and flow_px is not None:
            image = self._blur(image, np.nan_to_num(flow_px) * (s.motion_blur_exposure_s * fps))
        if s.exposure_variation > 0:
            self._gain_state = 0.9 * self._gain_state + 0.1 * self.rng.standard_normal()
            image *= float(np.exp(s.exposure_variation * self._gain_state * 3.0))
        if s.rgb_noise_sigma > 0:
            image += self.rng.standard_normal(image.shape).astype(np.float32) * s.rgb_noise_sigma
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)

    @staticmethod
    def _blur(image: np.ndarray, motion_px: np.ndarray, samples: int = 7) -> np.ndarray:
        """Average the image along each pixel's motion during the exposure (centred)."""
        h, w = image.shape[:2]
        v, u = np.mgrid[0:h, 0:w].astype(np.float32)
        total = np.zeros_like(image)
        with without_ipp():  # the same bits on every CPU (sim/ipp.py)
            for a in np.linspace(-0.5, 0.5, samples, dtype=np.float32):
                total += cv2.remap(
                    image,
                    u + a * motion_px[:, :, 0],
                    v + a * motion_px[:, :, 1],
                    cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE,
                )
        return total / samples
