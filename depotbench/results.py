"""What the Python API returns for a sweep and a comparison: typed values a script reads by
attribute, with reprs of a few lines and ``to_pandas()`` tables.

summary.json stays the file's shape (what ``depotbench sweep --json`` prints); here each of
its configurations is a frozen ``Configuration`` with its settings and parameters as typed
values and its statistics as ``Stats``. A repr names counts and the best configuration per
family instead of every row: an 8-run sweep's dataclass repr was 56 KB of nested records.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from depotbench.eval.gates.compare import SetComparison
from depotbench.eval.metrics.figures import Baseline, ScoredRun
from depotbench.eval.metrics.record import RunRecord
from depotbench.eval.metrics.statistics import Stats

if TYPE_CHECKING:  # pandas is an extra: only to_pandas imports it
    import pandas

Value = int | float | str | bool
"""A setting's, parameter's or knob's value as the spec gave it (``{"k": 2.5}``)."""


class MissingExtra(ImportError):
    """An optional dependency is not installed; the message names the extra that brings it."""


def _pandas() -> Any:
    try:
        import pandas
    except ImportError:
        raise MissingExtra("to_pandas needs pandas: pip install 'depotbench[pandas]'") from None
    return pandas


_SHAPE = (
    "family",
    "tracker",
    "parameters",
    "label",
    "detector",
    "strategy",
    "settings",
    "sequences",
    "runs",
    "successes",
    "success_rate",
    "failed",
    "stats",
    "timing",
)
"""summary.json's keys of a configuration that are not a figure's mean."""


@dataclass(frozen=True)
class Configuration:
    """One configuration of one family over its runs (the family's sequences and seeds): a
    summary.json configuration, typed."""

    family: str
    label: str
    """How tables and plots name it (``prior_flow k=2``)."""
    tracker: str
    detector: str
    strategy: str
    settings: dict[str, Value]
    parameters: dict[str, Value]
    """An external tracker's parameters (empty for the built-in one)."""
    sequences: int
    runs: int
    successes: int
    """Runs that held (``SuccessRule``: no failure, an ATE, enough frames tracked)."""
    success_rate: float | None
    failed: int
    stats: dict[str, Stats]
    """Each figure over the runs: n, mean, median, std, worst, p90, 95 % interval."""
    means: dict[str, float | None]
    """Each figure's mean over the runs (``means["ate_rmse_m"]``), as the plots read them."""
    timing: str | None = None
    """Set where some rows' times may include compiling the kernels (not comparable)."""

    @classmethod
    def of(cls, entry: Mapping[str, Any]) -> Configuration:
        """summary.json's dict of a configuration as its typed value."""
        return cls(
            family=entry["family"],
            label=entry["label"],
            tracker=entry["tracker"],
            detector=entry["detector"],
            strategy=entry["strategy"],
            settings=dict(entry.get("settings") or {}),
            parameters=dict(entry.get("parameters") or {}),
            sequences=entry["sequences"],
            runs=entry["runs"],
            successes=entry["successes"],
            success_rate=entry["success_rate"],
            failed=entry["failed"],
            stats={name: Stats(**values) for name, values in entry["stats"].items()},
            means={name: value for name, value in entry.items() if name not in _SHAPE},
            timing=entry.get("timing"),
        )

    def to_dict(self) -> dict[str, Any]:
        """The configuration as summary.json holds it."""
        out = {name: getattr(self, name) for name in _SHAPE if name not in ("stats", "timing")}
        out["stats"] = {name: s.to_dict() for name, s in self.stats.items()}
        return out | self.means | ({"timing": self.timing} if self.timing is not None else {})

    def __getitem__(self, name: str) -> Any:
        """A figure's mean by the name budgets and tables use (``best["ate_rmse_m"]``)."""
        return self.means[name]

    def __repr__(self) -> str:
        return f"Configuration({self.family} · {self.label}: {_figures_text(self)})"


def _figures_text(c: Configuration) -> str:
    ate, rho = c.means.get("ate_rmse_m"), c.means.get("rho_percent")
    parts = ["ATE -" if ate is None else f"ATE {ate:.4g} m"]
    if rho is not None:
        parts.append(f"rho {rho:.1f} %")
    parts.append(f"held {c.successes}/{c.runs}")
    return ", ".join(parts)


@dataclass(frozen=True)
class SweepSummary:
    """summary.json, typed: every configuration, the best per family and the Pareto front."""

    configurations: list[Configuration]
    best: dict[str, Configuration]
    """Per family, the configuration with the lowest mean ATE of those that held on enough seeds."""
    unqualified: dict[str, float]
    """Families with no configuration that held often enough, and the best success rate seen."""
    pareto: list[Configuration]
    """Per family, the configurations no other beats on both mean ATE and tracking time."""
    min_tracked_fraction: float
    best_min_success_rate: float
    search: dict[str, Any] | None = None
    """The search section's trials and result, where the spec had one (as summary.json's)."""
    baseline: Baseline | None = None
    """The configuration every rho is against (the spec's ``baseline:``); None: each run's own none."""

    @classmethod
    def of(cls, summary: Mapping[str, Any]) -> SweepSummary:
        """summary.json's content as its typed value."""
        rule = summary["success_rule"]
        return cls(
            configurations=[Configuration.of(c) for c in summary["configurations"]],
            best={family: Configuration.of(c) for family, c in summary["best"].items()},
            unqualified=dict(summary["unqualified"]),
            pareto=[Configuration.of(c) for c in summary["pareto"]],
            min_tracked_fraction=rule["min_tracked_fraction"],
            best_min_success_rate=rule["best_min_success_rate"],
            search=summary.get("search"),
            baseline=Baseline.from_dict(summary.get("baseline")),
        )

    def to_dict(self) -> dict[str, Any]:
        """summary.json's content."""
        return {
            "best": {family: c.to_dict() for family, c in self.best.items()},
            "unqualified": self.unqualified,
            "success_rule": {
                "min_tracked_fraction": self.min_tracked_fraction,
                "best_min_success_rate": self.best_min_success_rate,
            },
            "pareto": [c.to_dict() for c in self.pareto],
            "configurations": [c.to_dict() for c in self.configurations],
            "search": self.search,
            "baseline": None if self.baseline is None else self.baseline.to_dict(),
        }

    def to_pandas(self) -> pandas.DataFrame:
        """One row per configuration: what identifies it, settings and parameters spread to
        ``setting.NAME`` and ``param.NAME`` columns, its counts and each figure's mean."""
        pd = _pandas()
        rows = []
        for c in self.configurations:
            row: dict[str, Any] = {
                name: getattr(c, name) for name in ("family", "label", "tracker", "detector", "strategy")
            }
            row |= _spread("setting", c.settings) | _spread("param", c.parameters)
            row |= {name: getattr(c, name) for name in ("sequences", "runs", "successes", "failed")}
            row |= {"success_rate": c.success_rate} | c.means
            rows.append(row)
        ints = ("sequences", "runs", "successes", "failed")
        return _typed_frame(pd, rows, ints=ints, texts=("family", "label", "tracker", "detector", "strategy"))

    def __repr__(self) -> str:
        return (
            f"SweepSummary({len(self.configurations)} configurations in {len(_families(self))} families, "
            f"best of {len(self.best)}, {len(self.pareto)} on the Pareto front)"
        )


def _families(summary: SweepSummary) -> set[str]:
    return {c.family for c in summary.configurations}


@dataclass(frozen=True, repr=False)
class SweepResult:
    """A sweep done (or resumed): its runs, what was best, and where its files are."""

    folder: Path
    records: list[RunRecord]
    """Every run of the matrix, failed ones included (``failure`` says why)."""
    runs: list[ScoredRun]
    """The same runs with rho against their none run and the fraction of frames lost."""
    summary: SweepSummary
    """summary.json, typed: every configuration's statistics over its seeds, the Pareto front."""
    written: int
    """Runs done now (the others were in the folder already)."""
    plots: list[Path] = field(default_factory=list)

    @property
    def best(self) -> dict[str, Configuration]:
        """The best configuration of each family (summary.json's ``best``)."""
        return self.summary.best

    def to_pandas(self) -> pandas.DataFrame:
        """One row per run, as results.csv: the record's columns, rho and the lost fraction,
        and each knob, setting and parameter in a column of its own (``knob.seed``,
        ``setting.k``, ``param.window``); figures are floats (NaN where a run has none)."""
        return runs_frame(self.runs)

    def __repr__(self) -> str:
        failed = sum(1 for r in self.records if r.failure)
        sequences = len({r.sequence_fingerprint for r in self.records})
        lines = [
            f"SweepResult({str(self.folder)!r}: {len(self.records)} runs ({failed} failed, "
            f"{self.written} done now) over {sequences} sequences, "
            f"{len(self.summary.configurations)} configurations, {len(self.plots)} plots"
        ]
        lines += [
            f"  best {family}: {c.label} ({_figures_text(c)})" for family, c in sorted(self.best.items())
        ]
        lines += [
            f"  no best {family}: the best held on {rate:.0%}"
            for family, rate in self.summary.unqualified.items()
        ]
        return "\n".join(lines) + ")"


_SPREAD = {"knobs": "knob", "settings": "setting", "parameters": "param"}
"""A record's JSON columns whose entries get columns of their own, and their prefixes (as the CSV's)."""


def _spread(prefix: str, values: Mapping[str, Any]) -> dict[str, Any]:
    return {f"{prefix}.{name}": value for name, value in values.items()}


def runs_frame(runs: list[ScoredRun]) -> pandas.DataFrame:
    """Runs as a table with typed columns (results.csv's columns and order)."""
    pd = _pandas()
    rows = []
    for run in runs:
        row = run.to_row()
        for column, prefix in _SPREAD.items():
            row |= _spread(prefix, json.loads(row[column] or "{}"))
        rows.append(row)
    ints = tuple(f.name for f in fields(RunRecord) if f.type in ("int", "int | None"))
    texts = tuple(f.name for f in fields(RunRecord) if f.type in ("str", "str | None"))
    frame = _typed_frame(pd, rows, ints=ints, texts=texts)
    spread = sorted(
        (c for c in frame.columns if c.split(".", 1)[0] in _SPREAD.values()),
        key=lambda c: (list(_SPREAD.values()).index(c.split(".", 1)[0]), c),
    )
    return frame[[c for c in frame.columns if c not in spread] + spread]


def _typed_frame(
    pd: Any, rows: list[dict[str, Any]], ints: tuple[str, ...] = (), texts: tuple[str, ...] = ()
) -> pandas.DataFrame:
    """Rows as a frame whose columns have the values' types: ``ints`` as pandas' nullable
    Int64, every other column of numbers (or of None only, unless in ``texts``) as float64
    with NaN for None, true/false as nullable boolean, text as object."""
    frame = pd.DataFrame.from_records(rows)
    for column in frame.columns:
        values = [v for v in frame[column] if v is not None and not (isinstance(v, float) and v != v)]
        if column in ints:
            frame[column] = frame[column].astype("Int64")
        elif values and all(isinstance(v, bool) for v in values):
            frame[column] = frame[column].astype("boolean")
        elif values and all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
            frame[column] = pd.to_numeric(frame[column], errors="raise").astype("float64")
        elif not values and column not in texts:
            frame[column] = frame[column].astype("float64")
    return frame


@dataclass(frozen=True, repr=False)
class Comparisons(Mapping[Path, SetComparison]):
    """Each compared folder's ``SetComparison`` against the base folder, by folder."""

    base: Path
    sets: dict[Path, SetComparison]

    def __getitem__(self, folder: Path) -> SetComparison:
        return self.sets[Path(folder)]

    def __iter__(self) -> Iterator[Path]:
        return iter(self.sets)

    def __len__(self) -> int:
        return len(self.sets)

    def to_pandas(self) -> pandas.DataFrame:
        """One row per folder, configuration and figure: the means, the change, its 95 %
        interval, p(worse), the pairs and whether the change is significant."""
        pd = _pandas()
        rows = [
            {"folder": str(folder)} | c.to_dict()
            for folder, found in self.sets.items()
            for c in found.comparisons
        ]
        return _typed_frame(pd, rows, ints=("pairs",), texts=("differs",))

    def __repr__(self) -> str:
        lines = [f"Comparisons(against {str(self.base)!r}:"]
        for folder, found in self.sets.items():
            significant = sum(c.significant for c in found.comparisons)
            lines.append(
                f"  {str(folder)!r}: {len(found.comparisons)} figures compared, {significant} significant, "
                f"{len(found.regressions(0.0))} worse"
            )
        return "\n".join(lines) + ")"


@dataclass(frozen=True, repr=False)
class BenchmarkResult:
    """A benchmark's results file (``depotbench benchmark run``): its tracker, sequences and
    every run's figures, with the papers' table and one row per run as a DataFrame."""

    path: Path
    data: dict[str, Any]
    """results.json's content (docs/benchmarks.md)."""

    @classmethod
    def read(cls, path: str | Path) -> BenchmarkResult:
        from depotbench.eval.benchmark.results import load_results

        data = load_results(Path(path))
        return cls(Path(data["_path"]), data)

    @property
    def benchmark(self) -> str:
        return self.data["benchmark"]

    @property
    def fingerprint(self) -> str:
        """The tracker's: its program's bytes, command, vocabulary (``tracker_fingerprint``)."""
        return self.data["tracker"]["fingerprint"]

    def rows(self, baseline: BenchmarkResult | None = None) -> list[Any]:
        """The table's rows (``eval.benchmark.table.Row``): per scenario each figure's median,
        spread over seeds and repeats, and rho against ``baseline``."""
        from depotbench.eval.benchmark.table import rows

        return rows(self.data, None if baseline is None else baseline.data)

    def table(self, baseline: BenchmarkResult | None = None) -> str:
        """The papers' table as Markdown (``depotbench benchmark table``)."""
        from depotbench.eval.benchmark.table import markdown

        title = f"{self.benchmark}: {self.data['tracker']['label']}"
        return markdown(self.rows(baseline), title, self.data["repeats"] > 1)

    def verify(self) -> list[str]:
        """Every figure recomputed from the trajectories and sequences it names: the problems."""
        from depotbench.eval.benchmark.results import verify_results

        return verify_results(self.data)

    def to_pandas(self) -> pandas.DataFrame:
        """One row per run (fresh seeds' too, ``fresh`` True): benchmark, tracker, fingerprint,
        scenario, sequence, seed, repeat, status, each error's RMSE, mean, median and STD
        (``ate_m_rmse``...), and the tracked share; figures NaN where a run failed."""
        from depotbench.eval.benchmark.results import METRICS, STATISTICS

        pd = _pandas()
        fresh = (self.data.get("fresh") or {}).get("sequences") or []
        rows = []
        for sequence, is_fresh in [
            *((s, False) for s in self.data["sequences"]),
            *((s, True) for s in fresh),
        ]:
            for run in sequence["runs"]:
                figures = run.get("figures") or {}
                errors = figures.get("errors") or {}
                row: dict[str, Any] = {
                    "benchmark": self.benchmark,
                    "tracker": self.data["tracker"]["label"],
                    "strategy": self.data["tracker"]["strategy"],
                    "fingerprint": self.fingerprint,
                    "scenario": sequence["scenario"],
                    "sequence": sequence["name"],
                    "seed": sequence["seed"],
                    "fresh": is_fresh,
                    "repeat": run["repeat"],
                    "status": run["status"],
                }
                for metric in METRICS:
                    for stat in STATISTICS:
                        row[f"{metric}_{stat}"] = (errors.get(metric) or {}).get(stat)
                row["tracked_share"] = figures.get("tracked_share")
                rows.append(row)
        texts = ("benchmark", "tracker", "strategy", "fingerprint", "scenario", "sequence", "status")
        return _typed_frame(pd, rows, ints=("seed", "repeat"), texts=texts)

    def __repr__(self) -> str:
        sequences = self.data["sequences"]
        runs = sum(len(s["runs"]) for s in sequences)
        failed = sum(r["status"] != "ok" for s in sequences for r in s["runs"])
        fresh = self.data.get("fresh")
        extra = f", {len(fresh['sequences'])} fresh sequences" if fresh else ""
        return (
            f"BenchmarkResult({self.benchmark}, {self.data['tracker']['label']} "
            f"{self.data['tracker']['strategy']}: {len(sequences)} sequences x {self.data['repeats']} "
            f"({runs} runs, {failed} failed){extra}; {str(self.path)!r})"
        )
