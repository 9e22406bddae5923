"""One run's result as a typed, versioned row: what sweeps store and compare.

``RunRecord.from_metrics`` is the one place that reads the harness's metrics
dictionary for results; stores, exports and plots use these fields by name.
Timing fields vary from run to run; ``DETERMINISTIC_FIELDS`` are the ones that
must be equal when a job runs twice (the built-in tracker is deterministic).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

RECORD_VERSION = 3
"""2: adds the sequence fingerprint and relocalised frames; 3: an external tracker's
parameters, a failed run's reason, peak memory."""


@dataclass(frozen=True)
class RunRecord:
    key: str
    """Content hash of the job (sequence files, tracker, detector, strategy, settings, versions)."""
    family: str
    """The scenario family (the generated scenario's name, or the folder name)."""
    sequence: str
    """The sequence folder's absolute path: a row is read from other working directories
    (``report``, a resumed ``check``), where a relative one pointed elsewhere or nowhere."""
    sequence_fingerprint: str
    """``detections.sequence_fingerprint`` when it ran: its folder and the bytes of its files."""
    tracker: str
    detector: str
    strategy: str
    settings: str
    """The job's threshold overrides, as sorted JSON."""
    parameters: str
    """An external tracker's parameter values, as sorted JSON (``{}`` for the built-in one)."""
    failure: str | None
    """Why the run failed (the program's exit, its time limit, an unreadable trajectory),
    or None: a failed run is a row, counted, with no figures."""
    frames: int
    tracked_fraction: float
    lost_frames: int
    relocalized_frames: int
    keyframes: int | None
    ate_rmse_m: float | None
    ate_mean_m: float | None
    ate_max_m: float | None
    rpe_translation_rmse_m: float | None
    rpe_rotation_rmse_deg: float | None
    rejection_precision: float | None
    rejection_recall: float | None
    moving_inliers: int | None
    track_ms_mean: float | None
    track_ms_median: float | None
    detector_ms_mean: float | None
    wall_time_s: float
    peak_memory_mb: float | None
    """An external program's peak resident memory (with what it waited for)."""
    bench_version: str
    signature: str | None = None
    """Which keypoints the run kept in every frame (a hash); None where not computed."""
    computed_by: str = ""
    """The key of the job whose tracking made this row: itself, or an earlier job of this
    sweep with the same signature (the same run, so it was tracked once)."""
    record_version: int = RECORD_VERSION

    @classmethod
    def from_metrics(
        cls,
        key: str,
        family: str,
        settings: dict[str, Any],
        metrics: dict[str, Any],
        bench_version: str,
        fingerprint: str,
        signature: str | None = None,
    ) -> RunRecord:
        ate = metrics.get("ate_m") or {}
        rpe_t = metrics.get("rpe_translation_m") or {}
        rpe_r = metrics.get("rpe_rotation_deg") or {}
        rejection = metrics.get("rejection") or {}
        total = metrics["stage_time"]["tracking_total"]
        detector_time = metrics.get("detector_time") or {}
        return cls(
            key=key,
            family=family,
            sequence=str(Path(metrics["sequence"]).resolve()),
            sequence_fingerprint=fingerprint,
            tracker=metrics["tracker"],
            detector=metrics["detector"],
            strategy=metrics["strategy"],
            settings=json.dumps(settings, sort_keys=True),
            parameters=json.dumps(metrics.get("parameters") or {}, sort_keys=True),
            failure=None,
            frames=metrics["frames"],
            tracked_fraction=metrics["tracked_frames"] / max(1, metrics["frames"]),
            lost_frames=metrics["lost_frames"],
            relocalized_frames=metrics["relocalized_frames"],
            keyframes=metrics["keyframes"],
            ate_rmse_m=ate.get("rmse"),
            ate_mean_m=ate.get("mean"),
            ate_max_m=ate.get("max"),
            rpe_translation_rmse_m=rpe_t.get("rmse"),
            rpe_rotation_rmse_deg=rpe_r.get("rmse"),
            rejection_precision=rejection.get("precision"),
            rejection_recall=rejection.get("recall"),
            moving_inliers=rejection.get("moving_inliers"),
            track_ms_mean=total.get("mean_ms"),
            track_ms_median=total.get("median_ms"),
            detector_ms_mean=detector_time.get("mean_ms"),
            wall_time_s=metrics["wall_time_s"],
            peak_memory_mb=metrics.get("peak_memory_mb"),
            bench_version=bench_version,
            signature=signature,
            computed_by=key,
        )

    @classmethod
    def failed(
        cls,
        key: str,
        family: str,
        identity: dict[str, Any],
        reason: str,
        frames: int,
        wall_time_s: float,
        bench_version: str,
        fingerprint: str,
    ) -> RunRecord:
        """The row of a run that failed: what it was (``identity``: sequence, tracker,
        detector, strategy, settings, parameters) and why, with no figures."""
        return cls(
            key=key,
            family=family,
            sequence=str(Path(identity["sequence"]).resolve()),
            sequence_fingerprint=fingerprint,
            tracker=identity["tracker"],
            detector=identity["detector"],
            strategy=identity["strategy"],
            settings=json.dumps(identity["settings"], sort_keys=True),
            parameters=json.dumps(identity["parameters"], sort_keys=True),
            failure=reason,
            frames=frames,
            tracked_fraction=0.0,
            lost_frames=0,
            relocalized_frames=0,
            keyframes=None,
            ate_rmse_m=None,
            ate_mean_m=None,
            ate_max_m=None,
            rpe_translation_rmse_m=None,
            rpe_rotation_rmse_deg=None,
            rejection_precision=None,
            rejection_recall=None,
            moving_inliers=None,
            track_ms_mean=None,
            track_ms_median=None,
            detector_ms_mean=None,
            wall_time_s=wall_time_s,
            peak_memory_mb=None,
            bench_version=bench_version,
            computed_by=key,
        )

    def to_row(self) -> dict[str, Any]:
        return asdict(self)


FIELDS = tuple(f.name for f in fields(RunRecord))
TIMING_FIELDS = ("track_ms_mean", "track_ms_median", "detector_ms_mean", "wall_time_s", "peak_memory_mb")
DETERMINISTIC_FIELDS = tuple(f for f in FIELDS if f not in TIMING_FIELDS)
