"""One call from two trajectory files to ATE + RPE, as ``depotbench eval`` reports them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from depotbench.eval.metrics.accuracy import AteResult, DeltaUnit, RpeResult, ate, rpe
from depotbench.eval.metrics.alignment import Alignment
from depotbench.eval.metrics.trajectory import DEFAULT_MAX_DIFF_S, Trajectory, associate


@dataclass(frozen=True)
class ComparisonOptions:
    alignment: Alignment = Alignment.SE3
    max_diff_s: float = DEFAULT_MAX_DIFF_S
    offset_s: float = 0.0
    rpe_delta: float = 1
    rpe_unit: DeltaUnit = DeltaUnit.FRAMES
    rpe_all_pairs: bool = False


@dataclass(frozen=True, eq=False)
class Comparison:
    reference_name: str
    estimate_name: str
    pairs: int
    options: ComparisonOptions
    ate: AteResult
    rpe: RpeResult

    def to_dict(self) -> dict[str, Any]:
        """Machine-readable summary (JSON-ready)."""
        o = self.options
        return {
            "reference": self.reference_name,
            "estimate": self.estimate_name,
            "associated_pairs": self.pairs,
            "options": {
                "align": o.alignment.value,
                "max_diff_s": o.max_diff_s,
                "offset_s": o.offset_s,
                "rpe_delta": o.rpe_delta,
                "rpe_unit": o.rpe_unit.value,
                "rpe_all_pairs": o.rpe_all_pairs,
            },
            "ate_m": self.ate.statistics.to_dict(),
            "alignment_scale": self.ate.transform.scale,
            "rpe_translation_m": self.rpe.translation.to_dict(),
            "rpe_rotation_deg": self.rpe.rotation_deg.to_dict(),
        }


def compare(reference: Trajectory, estimate: Trajectory, options: ComparisonOptions) -> Comparison:
    """Associate, then ATE (aligned as asked) and RPE (on the same alignment)."""
    ref, est = associate(reference, estimate, options.max_diff_s, options.offset_s)
    ate_result = ate(ref, est, options.alignment)
    rpe_result = rpe(ref, est, options.rpe_delta, options.rpe_unit, options.rpe_all_pairs, options.alignment)
    return Comparison(reference.name, estimate.name, len(ref), options, ate_result, rpe_result)
