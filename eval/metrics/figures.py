"""The figures a run is judged by, in one table that the statistics over seeds, the gates'
budgets, ``compare`` and the sweep summary read: a new metric is its entry here, its field on
the run record (``record.py``) and the line of the run that computes it.

Three figures are derived from rows rather than measured by one run: rho (the ATE
improvement over the run without rejection on the same sequence, tracker and detector),
the fraction of frames lost, and the gates' time ratio (which needs a reference run that
a gate file names).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from depotbench.eval.metrics.record import RunRecord

BASELINE_STRATEGY = "none"
"""The run every rho is taken against: the same sequence, tracker, parameters and detector,
tracked with no rejection."""


@dataclass(frozen=True)
class Figure:
    name: str
    """The column (a run record's field, or a derived one)."""
    title: str
    """What a table, a plot axis or a failed budget calls it."""
    higher_is_better: bool = False
    """Its worst seed is the lowest (rates); else the highest (errors, time, lost frames)."""
    ratio: bool = False
    """Compared as a ratio: a positive quantity whose 10 % change means the same at any scale
    (errors, time); the others as differences (rates, rho)."""
    time: bool = False
    """Measured in time on this machine: comparable only under the same load."""
    derived: bool = False
    """Computed from the rows (``with_derived``), not stored with one run."""
    compared: bool = True
    """``depotbench compare`` shows it (a derived time ratio needs a gate file's reference)."""
    low: float = 0.0
    high: float = math.inf
    """The values it can take (errors, times and ratios are >= 0; rates and fractions lie in
    [0, 1]; rho is at most 100 %): a budget outside them can never hold or never fail, and
    ``depotbench validate`` and ``check`` refuse it."""

    def range_text(self) -> str:
        if not math.isfinite(self.low):
            return f"<= {self.high:g}"
        return f"[{self.low:g}, {self.high:g}]" if math.isfinite(self.high) else f">= {self.low:g}"


FIGURES: tuple[Figure, ...] = (
    Figure("ate_rmse_m", "ATE RMSE (m)", ratio=True),
    Figure("ate_median_m", "median ATE (m)", ratio=True),
    Figure("ate_max_m", "largest ATE (m)", ratio=True),
    Figure("rpe_translation_rmse_m", "RPE translation RMSE (m)", ratio=True),
    Figure("rpe_rotation_rmse_deg", "RPE rotation RMSE (deg)", ratio=True, high=180.0),
    Figure(
        "rho_percent",
        "ATE improvement over the none run (%)",
        higher_is_better=True,
        derived=True,
        low=-math.inf,
        high=100.0,
    ),
    Figure("rejection_precision", "rejection precision", higher_is_better=True, high=1.0),
    Figure("rejection_recall", "rejection recall", higher_is_better=True, high=1.0),
    Figure("tracked_fraction", "fraction of frames tracked", higher_is_better=True, high=1.0),
    Figure("map_f_score", "dense map F-score at 5 cm", higher_is_better=True, high=1.0),
    Figure("ghost_fraction", "share of the dense map that is ghost, at 5 cm", high=1.0),
    Figure("lost_fraction", "fraction of frames not tracked", derived=True, compared=False, high=1.0),
    Figure("track_ms_mean", "tracking time per frame (ms)", ratio=True, time=True),
    Figure("track_ms_median", "median tracking time per frame (ms)", ratio=True, time=True),
    Figure(
        "wall_ms_per_frame",
        "wall time per frame, start-up included (ms)",
        ratio=True,
        time=True,
        compared=False,
    ),
    Figure("cpu_ms_per_frame", "program's CPU time per frame (ms)", ratio=True, time=True, compared=False),
    Figure(
        "time_ratio",
        "time per frame over the reference run's (the tracker's own, else wall time)",
        ratio=True,
        derived=True,
        compared=False,
    ),
)
BY_NAME = {f.name: f for f in FIGURES}
HIGHER_IS_BETTER = frozenset(f.name for f in FIGURES if f.higher_is_better)
RATIO = frozenset(f.name for f in FIGURES if f.ratio)
TIME = frozenset(f.name for f in FIGURES if f.time)


def is_baseline(row: dict[str, Any]) -> bool:
    """The run rho is taken against: no rejection and no threshold (a none run with
    settings would be some other experiment)."""
    return row["strategy"] == BASELINE_STRATEGY and row["settings"] in ("{}", {}, None)


def parameters_of(row: Any) -> str:
    """A run's tracker parameters as its row holds them (JSON; ``{}`` for none)."""
    return row.get("parameters") or "{}"


def configuration_of(run: Any) -> tuple[str, str, str, str, str, str]:
    """What makes runs one configuration (its seeds and sequences): family, tracker with its
    parameters, detector, strategy and settings, as a row holds them. Summaries group by it,
    gates check each group together, and compare pairs them across result sets."""
    return (
        run["family"],
        run["tracker"],
        parameters_of(run),
        run["detector"],
        run["strategy"],
        run["settings"],
    )


@dataclass(frozen=True)
class ScoredRun:
    """One run as it is judged: its record, and the figures derived from the runs beside it
    (rho against its none run, the fraction of frames lost, the time ratio to a reference).

    Fields read through: ``run.ate_rmse_m`` is the record's, ``run.rho_percent`` derived;
    ``run["name"]`` reads any figure or column by name (how budgets and tables name them).
    """

    record: RunRecord
    rho_percent: float | None = None
    lost_fraction: float | None = None
    time_ratio: float | None = None

    @classmethod
    def of_row(cls, row: dict[str, Any]) -> ScoredRun:
        """A row with its derived columns (an exported table's) as its typed run."""
        return cls(
            RunRecord.from_row(row),
            row.get("rho_percent"),
            row.get("lost_fraction"),
            row.get("time_ratio"),
        )

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):  # copy and pickle probe dunders before fields exist
            raise AttributeError(name)
        return getattr(self.record, name)

    def __getitem__(self, name: str) -> Any:
        if name in DERIVED_COLUMNS:
            return getattr(self, name)
        return self.record[name]

    def get(self, name: str, default: Any = None) -> Any:
        """A figure or column by name, or ``default`` for a name that is neither."""
        return getattr(self, name) if name in DERIVED_COLUMNS else self.record.get(name, default)

    def __contains__(self, name: object) -> bool:
        return name in DERIVED_COLUMNS or name in self.record

    def to_row(self) -> dict[str, Any]:
        """The record's columns and rho and the lost fraction: a row of results.csv."""
        return self.record.to_row() | {"rho_percent": self.rho_percent, "lost_fraction": self.lost_fraction}


DERIVED_COLUMNS = ("rho_percent", "lost_fraction", "time_ratio")
"""The figures ``ScoredRun`` adds to a record."""


@dataclass(frozen=True)
class Baseline:
    """A configuration chosen as every rho's baseline (a sweep's or gate file's ``baseline:``):
    on each sequence, the one run matching every field given here is the baseline of every
    run on that sequence, whatever its tracker, parameters or detector. ORB-SLAM3, a user's
    program with its own rejection off (``parameters: {reject: 0}``) or a strategy with tuned
    settings can be the baseline; without one, each run's is its own ``none``."""

    tracker: str | None = None
    parameters: tuple[tuple[str, str], ...] | None = None
    """Values as text (``parameter_text``): rows store them typed."""
    detector: str | None = None
    strategy: str | None = None
    settings: tuple[tuple[str, float | int | bool], ...] | None = None

    def matches(self, run: Any) -> bool:
        from depotbench.core.parameters import parameter_text

        if self.tracker is not None and run["tracker"] != self.tracker:
            return False
        if self.detector is not None and run["detector"] != self.detector:
            return False
        if self.strategy is not None and run["strategy"] != self.strategy:
            return False
        if self.parameters is not None:
            given = {k: parameter_text(v) for k, v in _json(parameters_of(run)).items()}
            if given != dict(self.parameters):
                return False
        return self.settings is None or _json(run["settings"]) == dict(self.settings)

    def label(self) -> str:
        parts = [
            f"{name} {value}"
            for name, value in (("tracker", self.tracker), ("strategy", self.strategy))
            if value
        ]
        parts += [f"detector {self.detector}"] if self.detector else []
        parts += [f"{k}={v}" for k, v in self.parameters or ()] + [f"{k}={v}" for k, v in self.settings or ()]
        return ", ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        return {
            "tracker": self.tracker,
            "parameters": None if self.parameters is None else dict(self.parameters),
            "detector": self.detector,
            "strategy": self.strategy,
            "settings": None if self.settings is None else dict(self.settings),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> Baseline | None:
        if not data:
            return None
        parameters, settings = data.get("parameters"), data.get("settings")
        return cls(
            data.get("tracker"),
            None if parameters is None else tuple(sorted(parameters.items())),
            data.get("detector"),
            data.get("strategy"),
            None if settings is None else tuple(sorted(settings.items())),
        )


def _json(value: Any) -> dict[str, Any]:
    import json

    if isinstance(value, dict):
        return value
    return json.loads(value) if value else {}


def _chosen_baselines(records: list[RunRecord], baseline: Baseline) -> dict[str, float | None]:
    """The chosen baseline's ATE on each sequence; two runs of one sequence matching it are
    one line naming them (the baseline must say more)."""
    from depotbench.core.errors import InputError

    found: dict[str, RunRecord] = {}
    for r in records:
        if not baseline.matches(r):
            continue
        other = found.setdefault(r.sequence, r)
        if other is not r:
            raise InputError(
                f"baseline ({baseline.label()}): two runs on {r.sequence} match it ({other.tracker} "
                f"{other.strategy} {other.settings} {parameters_of(other)} {other.detector}; {r.tracker} "
                f"{r.strategy} {r.settings} {parameters_of(r)} {r.detector}): name its tracker, parameters, "
                "detector, strategy and settings"
            )
    return {sequence: r.ate_rmse_m for sequence, r in found.items()}


def with_derived(records: Iterable[RunRecord], baseline: Baseline | None = None) -> list[ScoredRun]:
    """The runs with rho (against the run of ``baseline`` on their sequence, or without one
    against the ``none`` run of their sequence, tracker, parameters and detector; None
    without one or without an ATE) and the fraction of frames lost."""
    from depotbench.eval.metrics.accuracy import improvement_rate  # numpy and scipy: when used

    records = list(records)
    chosen = _chosen_baselines(records, baseline) if baseline is not None else None
    own = {
        (r.sequence, r.tracker, parameters_of(r), r.detector): r.ate_rmse_m for r in records if is_baseline(r)
    }
    out = []
    for r in records:
        if chosen is not None:
            base = chosen.get(r.sequence)
        else:
            base = own.get((r.sequence, r.tracker, parameters_of(r), r.detector))
        rho = None
        if base is not None and r.ate_rmse_m is not None and base > 0:
            rho = improvement_rate(base, r.ate_rmse_m)
        lost = None if r.tracked_fraction is None else 1.0 - r.tracked_fraction
        out.append(ScoredRun(r, rho, lost))
    return out
