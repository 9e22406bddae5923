"""The named sensor profiles a scenario (``sensor: tum``) or ``generate --sensor`` chooses,
and the name of the one a spec matches (meta.json's ``sensor_profile``)."""

from __future__ import annotations

import dataclasses

from depotbench.sim.spec import SensorSpec

KINECT = SensorSpec(
    depth_noise=True,
    disparity_quantisation=True,
    depth_range_m=(0.4, 8.0),
    edge_dropout=0.5,
    rgb_noise_sigma=2.0,
    motion_blur_exposure_s=0.01,
    exposure_variation=0.05,
)
"""A Kinect v1's depth (Nguyen et al. 2012 noise, disparity steps, range and edge dropout) and RGB."""

TUM_ADDITIONS = {
    # Ringaby and Forssen (IJCV 2011): VGA consumer CMOS sensors at 30 Hz read out in 30-31 ms.
    "rolling_shutter_readout_s": 0.030,
    # No published figure: auto white balance moving a channel's gain by ~2 %.
    "white_balance_drift": 0.02,
    # TUM fr3 associations (office_val, nstr_tex_near): depth stamped 0.10-0.12 ms after RGB.
    "depth_delay_mean_s": 0.00012,
    # Same files: frame intervals vary by 2.0-2.1 ms (std), 1.5 ms per stamp.
    "timestamp_jitter_s": 0.0015,
    # Same files: 3.0-4.1 % of the 30 Hz frames are missing.
    "dropped_frame_rate": 0.035,
    # Sturm et al. (IROS 2012): motion capture at 100 Hz, millimetre accuracy.
    "gt_rate_hz": 100.0,
    "gt_position_noise_m": 0.001,
    "gt_rotation_noise_deg": 0.1,
    # Half a motion-capture sample: what aligning two clocks at 100 Hz can leave.
    "gt_time_offset_s": 0.005,
}
"""The TUM profile's additions to ``KINECT``; docs/scenarios.md gives each one's source."""

TUM = dataclasses.replace(KINECT, **TUM_ADDITIONS)
"""A Kinect v1 recorded as TUM fr3 was: the TUM analogs' sensor."""

PROFILES = {"perfect": SensorSpec(), "kinect": KINECT, "tum": TUM}

CUSTOM = "custom"
"""The profile name of a sensor that is none of ``PROFILES``."""


def profile_name(spec: SensorSpec) -> str:
    """The name of the profile ``spec`` is, or ``custom``."""
    return next((name for name, profile in PROFILES.items() if profile == spec), CUSTOM)
