"""Run records for tests that build result sets by hand: every column a test does not name
takes a neutral value (a finished run of the built-in tracker with no figures)."""

from __future__ import annotations

from typing import Any

from depotbench.eval.metrics.record import FIELDS, RECORD_VERSION, RunRecord

NEUTRAL: dict[str, Any] = {
    "key": "k",
    "family": "f",
    "sequence": "seq",
    "sequence_fingerprint": "fp",
    "seed": None,
    "knobs": "{}",
    "tracker": "builtin",
    "parameters": "{}",
    "detector": "groundtruth",
    "detector_config": "{}",
    "strategy": "none",
    "settings": "{}",
    "failure": None,
    "frames": 10,
    "tracked_fraction": 1.0,
    "lost_frames": 0,
    "relocalized_frames": 0,
    "keyframes": None,
    "wall_time_s": 1.0,
    "bench_version": "test",
    "computed_by": "",
    "record_version": RECORD_VERSION,
}


def record(**columns: Any) -> RunRecord:
    """A record with ``columns`` set and the rest neutral (figures not named are None)."""
    unknown = sorted(set(columns) - set(FIELDS))
    if unknown:
        raise KeyError(f"not a record column: {unknown[0]}")
    row = {name: None for name in FIELDS} | NEUTRAL | columns
    if "sequence_fingerprint" not in columns:  # one sequence, one fingerprint: runs pair by it
        row["sequence_fingerprint"] = f"fp:{row['sequence']}"
    return RunRecord(**row)
