"""One run's result as a typed, versioned row: what sweeps store and compare.

A row is what ran (``RunIdentity``: the sequence, its seed and suite knobs, the tracker
with its parameters, the detector with its faults, the strategy with its settings) and
what came of it. ``RunRecord.of_run`` is the one place that reads the harness's metrics
dictionary; stores, exports and plots use these fields by name. Timing fields vary from
run to run; ``DETERMINISTIC_FIELDS`` are the ones that must be equal when a job runs
twice (the built-in tracker is deterministic).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from typing import Any

RECORD_VERSION = 8
"""2: the sequence fingerprint and relocalised frames; 3: an external tracker's parameters,
a failed run's reason, peak memory; 4: seed, suite knobs and the whole detector
configuration, settings and parameters as typed JSON, sequences relative to the sweep;
5: the median ATE; 6: the dense map's figures; 7: the tracker fingerprint (and keys that
cover every file a command names), and times that exclude compiling the kernels; 8: wall
and CPU time per frame (an external program's time budgets)."""

UNKNOWN_FINGERPRINT = "unknown"
"""The tracker fingerprint of a row written before record version 7: one version of its own,
never taken for the fingerprint of any program."""


BOOLEAN_TEXT = {"true": True, "false": False}
"""A parameter's text that stands for a boolean: as YAML and JSON spell one (``parameter_text``
writes a spec's ``true`` so); ``True`` or ``yes`` stay text."""


def typed(text: str) -> bool | int | float | str:
    """A setting's or parameter's text as the value it stands for: a boolean, an integer, a
    number, or text (``2`` and ``2.5`` are numbers in SQLite's JSON and in CSV, ``true`` a
    boolean, ``fast`` stays text)."""
    if text in BOOLEAN_TEXT:
        return BOOLEAN_TEXT[text]
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            continue
    return text


def typed_json(pairs) -> str:
    """An external tracker's parameters (texts) as sorted JSON of typed values."""
    return json.dumps({name: typed(str(value)) for name, value in dict(pairs).items()}, sort_keys=True)


def settings_json(settings) -> str:
    """Threshold values (typed) as a row's sorted JSON: a whole number is written without a
    point (a float field's 3.0 reads as 3, as the spec wrote it), so SQLite's json_type and
    the CSV show it as the number it was given."""

    def plain(value):
        if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
            return int(value)
        return value

    return json.dumps({name: plain(value) for name, value in dict(settings).items()}, sort_keys=True)


@dataclass(frozen=True)
class RunIdentity:
    """What a run was: everything a row needs besides its results."""

    key: str
    family: str
    sequence: str
    """The folder, relative to the sweep folder when it lies inside it (a copied or moved
    sweep keeps every figure), else absolute."""
    fingerprint: str
    tracker: str
    detector: str
    strategy: str
    settings: tuple[tuple[str, int | float | bool], ...] = ()
    """Threshold values, typed (``depotbench.slam.config.Setting``)."""
    parameters: tuple[tuple[str, str], ...] = ()
    """An external tracker's parameters: text, as the program takes them."""
    detector_config: dict[str, Any] = field(default_factory=dict)
    seed: int | None = None
    knobs: dict[str, Any] = field(default_factory=dict)
    tracker_fingerprint: str | None = None


@dataclass(frozen=True)
class RunRecord:
    key: str
    """Content hash of the job (sequence files, tracker, detector, strategy, settings, versions)."""
    family: str
    """The scenario family (the generated scenario's name with its knobs, or the folder name)."""
    sequence: str
    """The sequence folder: relative to the sweep folder when inside it, else absolute (a
    row is read from other working directories: ``report``, a resumed ``check``)."""
    sequence_fingerprint: str
    """``detections.sequence_fingerprint`` when it ran: its folder and the bytes of its files."""
    seed: int | None
    """The scenario's seed (generated sequences)."""
    knobs: str
    """The suite variation's knobs, as sorted JSON (``{"actors.0.count": 6, "seed": 3}``)."""
    tracker: str
    parameters: str
    """An external tracker's parameter values, as sorted typed JSON (``{}`` for the built-in one)."""
    detector: str
    """The detector's label, fault settings included (``groundtruth+latency=3,miss=0.5``)."""
    detector_config: str
    """The whole detector configuration (model hash, onnx settings, faults, priors), as JSON."""
    strategy: str
    settings: str
    """The job's threshold overrides, as sorted typed JSON."""
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
    ate_median_m: float | None
    ate_max_m: float | None
    rpe_translation_rmse_m: float | None
    rpe_rotation_rmse_deg: float | None
    rejection_precision: float | None
    rejection_recall: float | None
    moving_inliers: int | None
    track_ms_mean: float | None
    """The tracker's own time per frame: the built-in one's, ORB-SLAM3's, or what a program
    wrote to ``{times}``; None for a program that wrote none."""
    track_ms_median: float | None
    detector_ms_mean: float | None
    map_f_score: float | None
    """The run's dense map (``dense_map`` runs) against the exact static world, at 5 cm:
    F-score, accuracy, completeness, and the share of its points that are ghosts."""
    map_accuracy: float | None
    map_completeness: float | None
    ghost_fraction: float | None
    wall_time_s: float
    peak_memory_mb: float | None
    """An external program's peak resident memory (with what it waited for)."""
    bench_version: str
    signature: str | None = None
    """Which keypoints the run kept in every frame (a hash); None where not computed."""
    computed_by: str = ""
    """The key of the job whose tracking made this row: itself, or an earlier job of this
    sweep with the same signature (the same run, so it was tracked once)."""
    tracker_fingerprint: str | None = None
    """A short hash of the tracker's identity (``harness.tracker_fingerprint``: its command,
    program and named files, vocabulary, settings template, parameters): rows of one tracker
    label with two fingerprints came from two versions of its program. None in a row written
    before record version 7 (read as ``UNKNOWN_FINGERPRINT``)."""
    wall_ms_per_frame: float | None = None
    """The run's wall time over its frames, start-up included: what any tracker is timed by
    from outside (a program's loading of its vocabulary counts too). None in a failed row and
    in one written before record version 8."""
    cpu_ms_per_frame: float | None = None
    """An external program's user plus system CPU time (with the processes it waited for)
    over its frames; None for the built-in tracker, in a failed row and before version 8."""
    record_version: int = RECORD_VERSION

    @property
    def program_version(self) -> str:
        """The tracker fingerprint, ``UNKNOWN_FINGERPRINT`` for a row written before them."""
        return self.tracker_fingerprint or UNKNOWN_FINGERPRINT

    @property
    def setting_values(self) -> dict[str, int | float | bool]:
        """``settings`` as typed values (``{"k": 2.5}``): the column stays JSON text, as stored."""
        return json.loads(self.settings or "{}")

    @property
    def knob_values(self) -> dict[str, Any]:
        """``knobs`` as typed values (``{"actors.0.count": 6, "seed": 3}``)."""
        return json.loads(self.knobs or "{}")

    @property
    def parameter_values(self) -> dict[str, int | float | str | bool]:
        """``parameters`` as typed values (``{"window": 5, "mode": "fast"}``)."""
        return json.loads(self.parameters or "{}")

    @staticmethod
    def identity_columns(run: RunIdentity) -> dict[str, Any]:
        """The columns a row takes from what ran (``computed_by``: the run itself)."""
        return {
            "key": run.key,
            "family": run.family,
            "sequence": run.sequence,
            "sequence_fingerprint": run.fingerprint,
            "seed": run.seed,
            "knobs": json.dumps(run.knobs, sort_keys=True),
            "tracker": run.tracker,
            "parameters": typed_json(run.parameters),
            "detector": run.detector,
            "detector_config": json.dumps(run.detector_config, sort_keys=True, default=str),
            "strategy": run.strategy,
            "settings": settings_json(run.settings),
            "computed_by": run.key,
            "tracker_fingerprint": run.tracker_fingerprint,
        }

    @classmethod
    def of_run(
        cls, run: RunIdentity, metrics: dict[str, Any], bench_version: str, signature: str | None = None
    ) -> RunRecord:
        ate = metrics.get("ate_m") or {}
        rpe_t = metrics.get("rpe_translation_m") or {}
        rpe_r = metrics.get("rpe_rotation_deg") or {}
        rejection = metrics.get("rejection") or {}
        total = metrics["stage_time"]["tracking_total"]
        detector_time = metrics.get("detector_time") or {}
        dense = metrics.get("map") or {}
        return cls(
            **cls.identity_columns(run),
            failure=None,
            frames=metrics["frames"],
            tracked_fraction=metrics["tracked_frames"] / max(1, metrics["frames"]),
            lost_frames=metrics["lost_frames"],
            relocalized_frames=metrics["relocalized_frames"],
            keyframes=metrics["keyframes"],
            ate_rmse_m=ate.get("rmse"),
            ate_mean_m=ate.get("mean"),
            ate_median_m=ate.get("median"),
            ate_max_m=ate.get("max"),
            rpe_translation_rmse_m=rpe_t.get("rmse"),
            rpe_rotation_rmse_deg=rpe_r.get("rmse"),
            rejection_precision=rejection.get("precision"),
            rejection_recall=rejection.get("recall"),
            moving_inliers=rejection.get("moving_inliers"),
            track_ms_mean=total.get("mean_ms"),
            track_ms_median=total.get("median_ms"),
            detector_ms_mean=detector_time.get("mean_ms"),
            map_f_score=dense.get("f_score"),
            map_accuracy=dense.get("accuracy"),
            map_completeness=dense.get("completeness"),
            ghost_fraction=dense.get("ghost_fraction"),
            wall_time_s=metrics["wall_time_s"],
            peak_memory_mb=metrics.get("peak_memory_mb"),
            wall_ms_per_frame=_per_frame_ms(metrics["wall_time_s"], metrics["frames"]),
            cpu_ms_per_frame=_per_frame_ms(metrics.get("cpu_time_s"), metrics["frames"]),
            bench_version=bench_version,
            signature=signature,
        )

    @classmethod
    def failed(
        cls, run: RunIdentity, reason: str, frames: int, wall_time_s: float, bench_version: str
    ) -> RunRecord:
        """The row of a run that failed: what it was and why, with no figures."""
        return cls(
            **cls.identity_columns(run),
            failure=reason,
            frames=frames,
            tracked_fraction=0.0,
            lost_frames=0,
            relocalized_frames=0,
            keyframes=None,
            ate_rmse_m=None,
            ate_mean_m=None,
            ate_median_m=None,
            ate_max_m=None,
            rpe_translation_rmse_m=None,
            rpe_rotation_rmse_deg=None,
            rejection_precision=None,
            rejection_recall=None,
            moving_inliers=None,
            track_ms_mean=None,
            track_ms_median=None,
            detector_ms_mean=None,
            map_f_score=None,
            map_accuracy=None,
            map_completeness=None,
            ghost_fraction=None,
            wall_time_s=wall_time_s,
            peak_memory_mb=None,
            bench_version=bench_version,
        )

    def to_row(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_row(cls, row: dict[str, Any]) -> RunRecord:
        """A stored row as its record: its columns by name (columns a table derives, such
        as rho, are not the record's and are left out; those a later version added,
        ``ADDED_FIELDS``, are empty in a row written before them). KeyError names a
        column the row lacks."""
        missing = [name for name in FIELDS if name not in row and name not in ADDED_FIELDS]
        if missing:
            raise KeyError(missing[0])
        return cls(**{name: row.get(name) for name in FIELDS if name in row or name in ADDED_FIELDS})

    def __getitem__(self, name: str) -> Any:
        """A column by the name tables, budgets and gate files use (``run["ate_rmse_m"]``)."""
        if name not in _FIELD_SET:
            raise KeyError(name)
        return getattr(self, name)

    def get(self, name: str, default: Any = None) -> Any:
        """A column by name, or ``default`` for a name that is not a column."""
        return getattr(self, name) if name in _FIELD_SET else default

    def __contains__(self, name: object) -> bool:
        return name in _FIELD_SET


def _per_frame_ms(seconds: float | None, frames: int) -> float | None:
    return None if seconds is None or frames <= 0 else 1000.0 * seconds / frames


FIELDS = tuple(f.name for f in fields(RunRecord))
_FIELD_SET = frozenset(FIELDS)
ADDED_FIELDS = {
    "ate_median_m": 5,
    "map_f_score": 6,
    "map_accuracy": 6,
    "map_completeness": 6,
    "ghost_fraction": 6,
    "tracker_fingerprint": 7,
    "wall_ms_per_frame": 8,
    "cpu_ms_per_frame": 8,
}
"""Columns a later record version added, with that version: rows and stores written before
them read with them empty (a baseline kept from version 4 still serves compare and check)."""
TIMING_FIELDS = (
    "track_ms_mean",
    "track_ms_median",
    "detector_ms_mean",
    "wall_time_s",
    "peak_memory_mb",
    "wall_ms_per_frame",
    "cpu_ms_per_frame",
)
DETERMINISTIC_FIELDS = tuple(f for f in FIELDS if f not in TIMING_FIELDS)
TIMED_WITHOUT_COMPILING = 7
"""The first record version whose times exclude compiling the kernels (``kernels.ready``
runs before the clock starts). An earlier row's first frames may hold the 14 s of a first
run after an install: its per-frame means read up to 10x too high."""
COMPILATION_NOTE = "timing may include compilation"


def timing_may_include_compilation(row: RunRecord) -> bool:
    """Whether a row's times may hold kernel compilation (written before record version 7)."""
    return int(row.get("record_version") or 0) < TIMED_WITHOUT_COMPILING
