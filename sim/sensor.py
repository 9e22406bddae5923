"""Sensor models applied after rendering; the clean ground truth is kept beside them.

Depth follows a Kinect v1: axial noise sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 m
(Nguyen, Izadi and Lovell, 2012), disparity quantisation, no reading outside the
working range and, often, at depth edges. RGB gets sensor noise, motion blur
along each pixel's true motion during the exposure, a rolling shutter (each row
exposed later than the one above it), and slow auto-exposure and white-balance drift.

Timing (``SensorClock``): a frame is stamped when it arrives, not when it was exposed;
depth is captured a little after RGB; the driver loses some frames; the recorded
ground truth is a motion-capture sample with noise and a clock offset. Pixel shifts
over a fraction of a frame (rolling shutter, depth delay, blur) follow each pixel's
exact flow to first order: a surface moving into view is not uncovered by them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
from depotbench.core.jit import compiled
from depotbench.sim.ipp import without_ipp
from depotbench.sim.spec import SensorSpec
from scipy.spatial.transform import Rotation

KINECT_FOCAL_PX = 580.0
KINECT_BASELINE_M = 0.075
DISPARITY_STEP_PX = 1.0 / 8.0
BLUR_SAMPLES = 7
"""Instants averaged along each pixel's motion during the exposure."""
EDGE_JUMP_M = 0.05
"""Neighbouring depths further apart than this make an edge pixel."""


def kinect_sigma(z_m: np.ndarray) -> np.ndarray:
    """Axial noise standard deviation (m) at depth z (Nguyen et al., 2012)."""
    return 0.0012 + 0.0019 * (z_m - 0.4) ** 2


WHITE_BALANCE_TIME_S = 1.0
"""Correlation time of the white-balance drift: auto white balance settles over about a second."""
MAX_JITTER_PERIODS = 0.25
"""A stamp's jitter is clipped to this share of the frame period, so stamps stay in order."""
MAX_DEPTH_DELAY_PERIODS = 0.25
"""The depth delay is clipped to a quarter of a frame period: depth stamps stay in order, each
nearer its own RGB frame than the next."""


class SensorModel:
    def __init__(self, spec: SensorSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self._gain_state = 0.0
        # Streams of their own, spawned without drawing from ``rng``: the older effects'
        # draws (and so the bytes of a sequence using only them) stay as they were.
        colour, timing = rng.bit_generator.seed_seq.spawn(2)
        self._colour_rng = np.random.default_rng(colour)
        self._timing_seed = timing
        self._balance: np.ndarray | None = None

    def clock(self, frames: int, fps: float) -> SensorClock:
        """The frames' timing: stamps, depth delays, lost frames, recorded ground truth."""
        return SensorClock(self.spec, frames, fps, np.random.default_rng(self._timing_seed))

    @property
    def needs_flow(self) -> bool:
        s = self.spec
        return s.motion_blur_exposure_s > 0 or s.rolling_shutter_readout_s > 0 or s.depth_delay_mean_s > 0

    def depth(
        self, depth_m: np.ndarray, flow_px: np.ndarray | None = None, delay_frames: float = 0.0
    ) -> np.ndarray:
        """The sensor's depth map. ``delay_frames`` (the capture's delay after the RGB's,
        in frame periods) moves each reading along its pixel's flow, nearest-neighbour:
        a depth is never blended across an edge."""
        s = self.spec
        if delay_frames and flow_px is not None:
            depth_m = _shift(depth_m, np.nan_to_num(flow_px) * delay_frames, cv2.INTER_NEAREST)
        if compiled() and depth_m.dtype == np.float32:
            return self._depth_compiled(depth_m)
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

    def _depth_compiled(self, depth_m: np.ndarray) -> np.ndarray:
        """``depth``'s arithmetic in one pass (sim/kernels.py), the random draws as it makes them."""
        from depotbench.sim import kernels

        s = self.spec
        noise = self.rng.standard_normal(depth_m.shape) if s.depth_noise else np.empty((0, 0))
        dropped = self._edges(depth_m, s.edge_dropout) if s.edge_dropout > 0 else np.empty((0, 0), bool)
        near, far = (np.float32(bound) for bound in s.depth_range_m)
        return kernels.kinect_depth(
            depth_m,
            noise,
            s.disparity_quantisation,
            KINECT_FOCAL_PX * KINECT_BASELINE_M,
            DISPARITY_STEP_PX,
            near,
            far,
            dropped,
        )

    def _edges(self, depth_m: np.ndarray, probability: float) -> np.ndarray:
        grad = np.maximum(
            np.abs(np.diff(depth_m, axis=0, append=depth_m[-1:])),
            np.abs(np.diff(depth_m, axis=1, append=depth_m[:, -1:])),
        )
        edges = cv2.dilate((grad > EDGE_JUMP_M).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        return edges & (self.rng.uniform(size=depth_m.shape) < probability)

    def rgb(self, rgb: np.ndarray, flow_px: np.ndarray | None, fps: float) -> np.ndarray:
        s = self.spec
        moved = flow_px is not None and (s.motion_blur_exposure_s > 0 or s.rolling_shutter_readout_s > 0)
        if (
            compiled()
            and rgb.ndim == 3
            and (not moved or (s.motion_blur_exposure_s > 0 and flow_px.dtype == np.float32))
        ):
            return self._rgb_compiled(rgb, flow_px if moved else None, fps)
        image = rgb.astype(np.float32)
        if moved:
            flow = np.nan_to_num(flow_px)
            delays = row_delays_frames(image.shape[0], s.rolling_shutter_readout_s, fps)
            shift = flow * delays[:, None, None]
            if s.motion_blur_exposure_s > 0:
                image = self._blur(image, flow * (s.motion_blur_exposure_s * fps), shift)
            else:
                image = _shift(image, shift, cv2.INTER_LINEAR)
        gain, balance, noise = self._exposure(image.shape, fps)
        if gain is not None:
            image *= gain
        if balance is not None:
            image *= balance
        if noise is not None:
            image += noise * np.float32(s.rgb_noise_sigma)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)

    def _exposure(
        self, shape: tuple[int, ...], fps: float
    ) -> tuple[np.float32 | None, np.ndarray | None, np.ndarray | None]:
        """This frame's exposure gain, white-balance gains and RGB noise (None where the effect
        is off), drawn in this order from their streams: both RGB paths take them from here,
        since every later frame's bytes hang on the order of the draws."""
        s = self.spec
        gain = balance = noise = None
        if s.exposure_variation > 0:
            self._gain_state = 0.9 * self._gain_state + 0.1 * self.rng.standard_normal()
            gain = np.float32(np.exp(s.exposure_variation * self._gain_state * 3.0))
        if s.white_balance_drift > 0:
            balance = self._white_balance(fps).astype(np.float32)
        if s.rgb_noise_sigma > 0:
            noise = self.rng.standard_normal(shape, dtype=np.float32)
        return gain, balance, noise

    def _rgb_compiled(self, rgb: np.ndarray, flow_px: np.ndarray | None, fps: float) -> np.ndarray:
        """``rgb`` with its per-pixel arithmetic compiled (sim/kernels.py): the blur's sample
        positions and the exposure, balance, noise and rounding each in one pass; the remaps
        and the random draws as ``rgb`` makes them, in its order."""
        from depotbench.sim import kernels

        s = self.spec
        image, divisor = rgb.astype(np.float32), np.float32(1.0)
        if flow_px is not None:
            delays = row_delays_frames(image.shape[0], s.rolling_shutter_readout_s, fps)
            exposure = np.float32(s.motion_blur_exposure_s * fps)
            u, v, du, dv = kernels.blur_shifts(flow_px, delays, exposure)
            total = np.zeros_like(image)
            map_u, map_v = np.empty_like(u), np.empty_like(v)
            with without_ipp():
                for a in np.linspace(-0.5, 0.5, BLUR_SAMPLES, dtype=np.float32):
                    kernels.blur_sample(u, v, du, dv, a, map_u, map_v)
                    total += cv2.remap(image, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            image, divisor = total, np.float32(BLUR_SAMPLES)
        gain, balance, noise = self._exposure(image.shape, fps)
        return kernels.finish_rgb(
            image,
            divisor,
            np.float32(1.0) if gain is None else gain,
            np.empty(0, np.float32) if balance is None else balance,
            np.empty((0, 0, 0), np.float32) if noise is None else noise,
            np.float32(s.rgb_noise_sigma),
        )

    def _white_balance(self, fps: float) -> np.ndarray:
        """Per-channel gains: each log gain an AR(1) process whose stationary standard
        deviation is ``white_balance_drift``, with a correlation time of WHITE_BALANCE_TIME_S;
        the first frame draws from the stationary distribution."""
        sigma = self.spec.white_balance_drift
        a = float(np.exp(-1.0 / (fps * WHITE_BALANCE_TIME_S)))
        draw = self._colour_rng.standard_normal(3) * sigma
        self._balance = draw if self._balance is None else a * self._balance + draw * np.sqrt(1 - a * a)
        return np.exp(self._balance)

    @staticmethod
    def _blur(
        image: np.ndarray,
        motion_px: np.ndarray,
        shift_px: np.ndarray | None = None,
        samples: int = BLUR_SAMPLES,
    ) -> np.ndarray:
        """Average the image along each pixel's motion during the exposure, centred on the
        exposure's middle, itself moved by ``shift_px`` (the rolling shutter's row delay)."""
        v, u = _grid(*image.shape[:2])
        if shift_px is not None:
            u, v = u - shift_px[:, :, 0], v - shift_px[:, :, 1]
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


@functools.cache
def _grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's row and column (float32), made once per image size."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float32)
    v.setflags(write=False)
    u.setflags(write=False)
    return v, u


def row_delays_frames(height: int, readout_s: float, fps: float) -> np.ndarray:
    """Each row's exposure time after the middle row's, in frame periods (float32, one per
    row): the rows are read out evenly over ``readout_s``, top first."""
    if height < 2 or readout_s <= 0:
        return np.zeros(height, np.float32)
    return ((np.arange(height) / (height - 1) - 0.5) * readout_s * fps).astype(np.float32)


def _shift(image: np.ndarray, shift_px: np.ndarray, interpolation: int) -> np.ndarray:
    """``image`` as seen ``shift_px`` later along each pixel's motion: dst(x) = src(x - shift(x))."""
    v, u = _grid(*image.shape[:2])
    with without_ipp():
        return cv2.remap(
            image,
            u - shift_px[:, :, 0].astype(np.float32),
            v - shift_px[:, :, 1].astype(np.float32),
            interpolation,
            borderMode=cv2.BORDER_REPLICATE,
        )


@dataclass(frozen=True)
class FrameTiming:
    """When frame ``index`` was taken and how it was recorded (seconds of simulated time)."""

    capture_s: float
    """The RGB exposure's middle (the middle row, with a rolling shutter)."""
    stamp_s: float
    """The RGB stamp: the capture plus its arrival jitter."""
    depth_delay_s: float
    """The depth capture's delay after ``capture_s``; its stamp is ``stamp_s`` plus this."""
    dropped: bool
    recorded_s: float
    """The instant whose pose groundtruth.txt holds for this frame (motion capture's sample)."""


class SensorClock:
    """Every frame's timing, drawn at once from its own stream (so one effect's draws never
    shift another's)."""

    def __init__(self, spec: SensorSpec, frames: int, fps: float, rng: np.random.Generator) -> None:
        self.spec = spec
        period = 1.0 / fps
        self.captures = np.arange(frames) * period
        jitter = rng.standard_normal(frames) * spec.timestamp_jitter_s
        self.stamps = self.captures + np.clip(
            jitter, -MAX_JITTER_PERIODS * period, MAX_JITTER_PERIODS * period
        )
        delays = rng.exponential(1.0, frames) * spec.depth_delay_mean_s
        self.depth_delays = np.minimum(delays, MAX_DEPTH_DELAY_PERIODS * period)
        self.dropped = rng.uniform(size=frames) < spec.dropped_frame_rate
        self.dropped[0] = False  # a sequence starts with a frame
        self.position_noise = rng.standard_normal((frames, 3)) * spec.gt_position_noise_m
        self.rotation_noise = np.radians(rng.standard_normal((frames, 3)) * spec.gt_rotation_noise_deg)
        recorded = self.stamps + spec.gt_time_offset_s
        if spec.gt_rate_hz > 0:
            recorded = np.round(recorded * spec.gt_rate_hz) / spec.gt_rate_hz
        self.recorded = recorded

    def frame(self, index: int) -> FrameTiming:
        return FrameTiming(
            capture_s=float(self.captures[index]),
            stamp_s=float(self.stamps[index]),
            depth_delay_s=float(self.depth_delays[index]),
            dropped=bool(self.dropped[index]),
            recorded_s=float(self.recorded[index]),
        )

    def recorded_pose(self, index: int, true_pose: np.ndarray) -> np.ndarray:
        """groundtruth.txt's pose for frame ``index``: the true pose at its recorded instant
        with the motion capture's noise (position per axis; orientation a rotation vector
        per axis, applied in the camera frame)."""
        pose = np.array(true_pose, dtype=np.float64)
        pose[:3, 3] += self.position_noise[index]
        pose[:3, :3] = pose[:3, :3] @ Rotation.from_rotvec(self.rotation_noise[index]).as_matrix()
        return pose
