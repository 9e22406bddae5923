"""Robustness gates: budgets on a run matrix's rows, for CI.

```yaml
gates: crowd-ci
run:                                  # a sweep spec (eval/sweep/spec.py): what to run
  suite: ../../scenes/suites/demo.yaml
  strategies: [none, box_epipolar_flow]
  thresholds: {box_epipolar_flow: {epsilon_px: {grid: [1.0]}}}
reference: none                       # time_ratio: time per frame over this strategy's run
reference_settings: {}                # which of its runs, where the reference strategy is swept
checks:
  - name: crowd-keeps-tracking
    families: ["demo*"]               # globs over scenario families (default: all)
    tags: [crowd]                     # and/or the scenarios' tags
    strategies: [box_epipolar_flow]   # trackers, detectors, strategies: default all
    detectors: ["groundtruth+*"]      # detector labels, globs (groundtruth+latency=3,miss=0.5)
    settings: {epsilon_px: 1.0}       # only rows with these threshold values
    budgets:
      ate_rmse_m: {max: 0.05}
      rho_percent: {min: 20}
      rejection_recall: {min: 0.8}
      lost_fraction: {max: 0.1}
      time_ratio: {max: 3.0}
```

Every selected row (one sequence through one configuration) is checked against
every budget of its check; a failure names the check, the row and the budget.
"""

from __future__ import annotations

import fnmatch
import json
import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError
from depotbench.core.path_text import text_path
from depotbench.eval.metrics.figures import (
    BY_NAME,
    FIGURES,
    HIGHER_IS_BETTER,
    Baseline,
    ScoredRun,
    configuration_of,
    with_derived,
)
from depotbench.eval.metrics.record import (
    COMPILATION_NOTE,
    TIMING_FIELDS,
    RunRecord,
    timing_may_include_compilation,
)
from depotbench.eval.metrics.statistics import SuccessRule, paired_change, stats, summarize
from depotbench.eval.sweep.spec import SweepSpec
from depotbench.eval.sweep.summary import settings_text
from depotbench.scenes.schema import Strict, load_model
from depotbench.sim.sequence import Sequence
from pydantic import Field, model_validator

METRICS: dict[str, str] = {f.name: f.title for f in FIGURES}
"""What a budget may bound (every figure), with what the failure message calls it."""
AGGREGATES: dict[str, str] = {
    "mean": "mean over runs",
    "median": "median over runs",
    "worst": "worst run's",
    "p90": "90th-percentile run's",
    "vs_baseline": "change from the baseline, paired by sequence, of",
}
"""``METRIC.AGGREGATE`` budgets bound a configuration's runs together (its seeds); the
others bound each run. ``vs_baseline`` is the relative change of a ratio figure (ATE, RPE,
time: +0.05 is 5 % larger) or the difference of a rate (recall, rho), and fails only when
the paired test says the change is real (p < ``BASELINE_ALPHA``)."""
SUCCESS_RATE = "success_rate"
BASELINE_ALPHA = 0.05


def budget_parts(name: str) -> tuple[str, str | None]:
    """A budget's figure and its aggregate (None for a per-run budget)."""
    if name == SUCCESS_RATE:
        return name, "success"
    metric, _, aggregate = name.partition(".")
    return metric, aggregate or None


def describe(name: str) -> str:
    metric, aggregate = budget_parts(name)
    if aggregate == "success":
        return "share of runs that held (did not fail, tracked enough frames)"
    return METRICS[metric] if aggregate is None else f"{AGGREGATES[aggregate]} {METRICS[metric]}"


def budget_problem(name: str, low: float | None, high: float | None) -> str | None:
    """Why budget ``name`` with bounds ``low`` (min) and ``high`` (max) cannot be meant: an
    unknown figure, or a bound outside the values the figure takes (``Figure.low``/``high``:
    ``rejection_recall: {min: 2}`` can never hold, ``{min: -1}`` never fail). A
    ``vs_baseline`` change is a difference, not the figure itself: its bounds are free."""
    metric, aggregate = budget_parts(name)
    if aggregate == "success":
        figure_range, title = (0.0, 1.0), "a success rate"
    elif metric not in METRICS or (aggregate and aggregate not in AGGREGATES):
        return (
            f"unknown budget {name!r}; choose from {', '.join(METRICS)}, each also as "
            f"METRIC.{{{','.join(AGGREGATES)}}}, and {SUCCESS_RATE}"
        )
    elif aggregate == "vs_baseline":
        return None
    else:
        figure = BY_NAME[metric]
        figure_range, title = (figure.low, figure.high), f"{metric} ({figure.range_text()})"
    for which, value in (("min", low), ("max", high)):
        if value is None or figure_range[0] <= value <= figure_range[1]:
            continue
        never = "hold" if (which == "min") == (value > figure_range[1]) else "fail"
        return f"{which}: {value:g} is outside the values of {title}, so it can never {never}"
    return None


class Bound(Strict):
    min: float | None = None
    max: float | None = None

    @model_validator(mode="after")
    def _one(self) -> Bound:
        if self.min is None and self.max is None:
            raise ValueError("a budget needs min or max")
        for value in (self.min, self.max):
            if value is not None and not math.isfinite(value):
                raise ValueError("budget bounds must be finite")
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError("min is above max")
        return self

    def limits(self, space: str = " ") -> list[str]:
        """The bounds as ``>= min`` and ``<= max`` (those that are set)."""
        return [
            f"{op}{space}{value:g}" for op, value in ((">=", self.min), ("<=", self.max)) if value is not None
        ]


class Check(Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    families: list[str] = Field(default_factory=list)
    tags: list[str] = Field(default_factory=list)
    trackers: list[str] = Field(default_factory=list)
    detectors: list[str] = Field(default_factory=list)
    """Detector labels or globs over them: a faulted one names its faults, sorted
    (``groundtruth+latency=3,miss=0.5``), so ``groundtruth+*miss=*`` selects every missing one."""
    strategies: list[str] = Field(default_factory=list)
    settings: dict[str, float] = Field(default_factory=dict)
    parameters: dict[str, bool | float | str] = Field(default_factory=dict)
    """Only rows whose external tracker ran with these parameter values (numbers, text or
    booleans; ``bool`` first, or ``true`` would be read as the number 1)."""
    budgets: dict[str, Bound] = Field(min_length=1)

    @model_validator(mode="after")
    def _known(self) -> Check:
        for name, bound in sorted(self.budgets.items()):
            problem = budget_problem(name, bound.min, bound.max)
            if problem is not None:
                raise ValueError(f"budgets.{name}: {problem}")
        return self

    def run_budgets(self) -> dict[str, Bound]:
        return {k: b for k, b in self.budgets.items() if budget_parts(k)[1] is None}

    def group_budgets(self) -> dict[str, Bound]:
        return {k: b for k, b in self.budgets.items() if budget_parts(k)[1] is not None}


class GateFile(Strict):
    gates: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    description: str = ""
    run: SweepSpec
    reference: str = "none"
    reference_settings: dict[str, float] = Field(default_factory=dict)
    """The reference run's threshold values, where ``run`` sweeps the reference strategy:
    a time ratio is taken against one named run, never against whichever came last."""
    checks: list[Check] = Field(min_length=1)

    @model_validator(mode="before")
    @classmethod
    def _run_name(cls, data: Any) -> Any:
        """The run needs no name of its own: it is the gate file's."""
        if isinstance(data, dict) and isinstance(data.get("run"), dict) and "sweep" not in data["run"]:
            data = {**data, "run": {**data["run"], "sweep": str(data.get("gates", "gates"))}}
        return data

    @model_validator(mode="after")
    def _names(self) -> GateFile:
        names = [c.name for c in self.checks]
        if len(set(names)) != len(names):
            raise ValueError("check names must be unique")
        if self.reference != "none" and self.reference not in self.run.strategies:
            raise ValueError(f"reference {self.reference!r} is not among run.strategies")
        swept = sorted(self.run.thresholds.get(self.reference, {}))
        if sorted(self.reference_settings) != swept:
            if not swept:
                raise ValueError(f"reference_settings: {self.reference} is not swept; leave them out")
            raise ValueError(
                f"reference_settings: {self.reference} is swept over {', '.join(swept)}; give the "
                "value of each, to say which of its runs the time ratio is taken against"
            )
        return self

    def reference_label(self) -> str:
        shown = settings_text(dict(sorted(self.reference_settings.items())))
        return f"{self.reference} {shown}".strip()


def load_gates(path: Path) -> GateFile:
    return load_model(GateFile, path)


@dataclass(frozen=True)
class Verdict:
    """One budget on one row."""

    check: str
    row: str
    """Which run: family, sequence, tracker, detector, strategy, settings."""
    metric: str
    value: float | None
    bound: Bound
    passed: bool
    note: str = ""
    """What the value was measured against, where that is a choice (the time ratio's run)."""

    @property
    def message(self) -> str:
        shown = "missing" if self.value is None else f"{self.value:.4g}"
        note = f" {self.note}" if self.note else ""
        return (
            f"{self.metric} ({describe(self.metric)}) = {shown}{note}, "
            f"budget {' and '.join(self.bound.limits())}"
        )


@dataclass(frozen=True)
class CheckResult:
    check: str
    row: str
    verdicts: tuple[Verdict, ...]
    seconds: float
    configuration: bool = False
    """The budgets of a configuration (its runs together), not of one run."""

    @property
    def passed(self) -> bool:
        return all(v.passed for v in self.verdicts)


@dataclass(frozen=True)
class GateReport:
    gates: str
    results: tuple[CheckResult, ...]
    empty_checks: tuple[str, ...]
    """Checks that selected no row: they fail (a gate that checks nothing guards nothing)."""

    @property
    def failures(self) -> list[str]:
        out = [f"{c}: no run matches this check" for c in self.empty_checks]
        for result in self.results:
            out += [f"{v.check} [{v.row}]: {v.message}" for v in result.verdicts if not v.passed]
        return out

    @property
    def passed(self) -> bool:
        return not self.failures

    def to_dict(self) -> dict[str, Any]:
        """The verdicts as ``depotbench check --json`` prints them: each (check, run) with its
        budgets, values and bounds, then the failures as the text lines CI logs show."""
        return {
            "gates": self.gates,
            "passed": self.passed,
            "results": [
                {
                    "check": r.check,
                    "run": r.row,
                    "passed": r.passed,
                    "seconds": r.seconds,
                    "budgets": [
                        {
                            "metric": v.metric,
                            "value": v.value,
                            "min": v.bound.min,
                            "max": v.bound.max,
                            "passed": v.passed,
                            "note": v.note,
                        }
                        for v in r.verdicts
                    ],
                }
                for r in self.results
            ],
            "empty_checks": list(self.empty_checks),
            "failures": self.failures,
        }


def _row_name(row: ScoredRun) -> str:
    settings = json.loads(row["settings"])
    shown = settings_text(dict(sorted(settings.items())))
    parameters = settings_text(dict(sorted(json.loads(row.get("parameters") or "{}").items())))
    name = Path(row["sequence"]).name
    return " ".join(
        part
        for part in (row["family"], name, row["tracker"], parameters, row["detector"], row["strategy"], shown)
        if part
    )


def _tags(sequence: str, cache: dict[str, set[str]]) -> set[str]:
    if sequence not in cache:
        opened = Sequence.open(text_path(sequence))
        scenario = (opened.meta or {}).get("scenario") or {}
        tags = (scenario.get("tags") or []) if isinstance(scenario, dict) else []
        if not isinstance(tags, list) or not all(isinstance(tag, str) for tag in tags):
            raise InputError(
                f"{opened.root / 'meta.json'}: scenario.tags must be a list of text, got {tags!r:.80}"
            )
        cache[sequence] = set(tags)
    return cache[sequence]


def _selects(check: Check, row: ScoredRun, tags: dict[str, set[str]]) -> bool:
    if check.families and not any(fnmatch.fnmatchcase(row["family"], g) for g in check.families):
        return False
    if check.tags and not set(check.tags) & _tags(row["sequence"], tags):
        return False
    for field, allowed in (("tracker", check.trackers), ("strategy", check.strategies)):
        if allowed and row[field] not in allowed:
            return False
    if check.detectors and not any(fnmatch.fnmatchcase(row["detector"], g) for g in check.detectors):
        return False  # a label names its faults: globs select fault models by one of them
    settings = json.loads(row["settings"])
    parameters = json.loads(row.get("parameters") or "{}")
    return all(
        k in settings and math.isclose(float(settings[k]), v, rel_tol=1e-9, abs_tol=1e-12)
        for k, v in check.settings.items()
    ) and all(k in parameters and _same_value(parameters[k], v) for k, v in check.parameters.items())


def _same_value(stored: bool | float | str, wanted: bool | float | str) -> bool:
    if isinstance(wanted, bool) or isinstance(stored, bool):  # true is not the number 1
        return stored is wanted
    if isinstance(wanted, str):
        return stored == wanted
    try:
        return math.isclose(float(stored), wanted, rel_tol=1e-9, abs_tol=1e-12)
    except ValueError:
        return False


def _same_settings(row: RunRecord, wanted: dict[str, float]) -> bool:
    settings = json.loads(row["settings"])
    return set(settings) == set(wanted) and all(
        math.isclose(float(settings[k]), v, rel_tol=1e-9, abs_tol=1e-12) for k, v in wanted.items()
    )


def derived_rows(
    records: list[RunRecord],
    reference: str,
    reference_settings: dict[str, float] | None = None,
    baseline: Baseline | None = None,
) -> list[ScoredRun]:
    """The runs with rho, the fraction of frames not tracked and the time ratio: a run's time
    per frame over the one run of the ``reference`` strategy with exactly
    ``reference_settings`` on the same sequence, tracker and detector. The time is the
    tracker's own (``track_ms_mean``) where the run has it, else its wall time per frame
    (``time_basis``), taken alike of both runs: a ratio of two kinds of time means nothing."""
    wanted = reference_settings or {}
    references: dict[tuple[str, str, str], RunRecord] = {}
    for r in records:
        if r.strategy == reference and _same_settings(r, wanted):
            references[(r.sequence, r.tracker, r.detector)] = r
    out = []
    for run in with_derived(records, baseline):
        base = references.get((run.sequence, run.tracker, run.detector))
        basis = time_basis(run.record)
        mine, theirs = run.get(basis), None if base is None else base.get(basis)
        ratio = mine / theirs if theirs and mine is not None else None
        out.append(replace(run, time_ratio=ratio))
    return out


def time_basis(row: RunRecord) -> str:
    """Which time per frame a row's time ratio compares: the tracker's own where it has one
    (the built-in tracker, ORB-SLAM3, a program that writes ``{times}``), else the wall time
    per frame the bench measured around the program."""
    return "track_ms_mean" if row.track_ms_mean is not None else "wall_ms_per_frame"


def _within(value: float | None, bound: Bound) -> bool:
    if value is None or not math.isfinite(value):
        return False
    return (bound.min is None or value >= bound.min) and (bound.max is None or value <= bound.max)


def evaluate(
    gates: GateFile, records: list[RunRecord], baseline: list[RunRecord] | None = None
) -> GateReport:
    """Check every row each check selects against its per-run budgets, and each of its
    configurations (the runs of one family with one tracker, detector, strategy and
    settings: the seeds) against its aggregate budgets; ``vs_baseline`` budgets pair the
    configuration's runs with ``baseline``'s on the same sequences."""
    chosen = None if gates.run.baseline is None else gates.run.baseline.to_baseline()
    rows = derived_rows(records, gates.reference, gates.reference_settings, chosen)
    base = (
        derived_rows(baseline, gates.reference, gates.reference_settings, chosen)
        if baseline is not None
        else None
    )
    rule = SuccessRule(gates.run.statistics.min_tracked_fraction)
    reference = gates.reference_label()
    tags: dict[str, set[str]] = {}
    results, empty = [], []
    for check in gates.checks:
        selected = [r for r in rows if _selects(check, r, tags)]
        if not selected:
            empty.append(check.name)
        per_run = check.run_budgets()
        for row in sorted(selected, key=_row_name) if per_run else []:
            name = _row_name(row)
            verdicts = tuple(
                Verdict(
                    check.name,
                    name,
                    metric,
                    row.get(metric),
                    bound,
                    _within(row.get(metric), bound),
                    _note(row, metric, reference),
                )
                for metric, bound in per_run.items()
            )
            results.append(CheckResult(check.name, name, verdicts, float(row["wall_time_s"] or 0.0)))
        grouped = check.group_budgets()
        if grouped:
            for members in _configurations(selected):
                results.append(_group_result(check.name, members, grouped, rule, base))
    return GateReport(gates.gates, tuple(results), tuple(empty))


def _configurations(rows: list[ScoredRun]) -> list[list[ScoredRun]]:
    groups: dict[tuple, list[ScoredRun]] = {}
    for row in rows:
        groups.setdefault(configuration_of(row), []).append(row)
    return [groups[key] for key in sorted(groups)]


def _group_name(members: list[ScoredRun]) -> str:
    first = members[0]
    parameters = settings_text(dict(sorted(json.loads(first.get("parameters") or "{}").items())))
    settings = settings_text(dict(sorted(json.loads(first["settings"]).items())))
    parts = (first["family"], first["tracker"], parameters, first["detector"], first["strategy"], settings)
    return " ".join(p for p in parts if p) + f" over {len(members)} runs"


def _pairing(row: ScoredRun) -> str:
    """What pairs a run with the baseline's: its sequence's fingerprint (the content of its
    files and their place, relative to the sweep folder for a suite generated there), never
    its folder's name: two folders named ``seq`` are two sequences."""
    return row.get("sequence_fingerprint") or row["sequence"]


def _group_result(
    check_name: str,
    members: list[ScoredRun],
    budgets: dict[str, Bound],
    rule: SuccessRule,
    baseline: list[ScoredRun] | None,
) -> CheckResult:
    name = _group_name(members)
    summary = summarize(members, rule)
    verdicts = []
    for budget, bound in budgets.items():
        metric, aggregate = budget_parts(budget)
        note = ""
        if aggregate == "success":
            value = summary["success_rate"]
            note = f"({summary['successes']} of {summary['runs']} held)"
            passed = _within(value, bound)
        elif aggregate == "vs_baseline":
            value, passed, note = _versus_baseline(metric, bound, members, baseline)
        else:
            figures = (
                summary["stats"].get(metric)
                or stats([r.get(metric) for r in members], metric in HIGHER_IS_BETTER).to_dict()
            )
            value = figures.get(aggregate)
            note = f"(n={figures['n']}) {_compilation_note(members, metric)}".strip()
            passed = _within(value, bound)
        verdicts.append(Verdict(check_name, name, budget, value, bound, passed, note))
    seconds = sum(float(r["wall_time_s"] or 0.0) for r in members)
    return CheckResult(check_name, name, tuple(verdicts), seconds, configuration=True)


def _versus_baseline(
    metric: str, bound: Bound, members: list[ScoredRun], baseline: list[ScoredRun] | None
) -> tuple[float | None, bool, str]:
    """The paired change of ``metric`` from the baseline's runs of this configuration, and
    whether it holds: a change past the bound fails only when it is real (the paired test's
    p below ``BASELINE_ALPHA``), so that a gate does not flake on run-to-run noise."""
    if baseline is None:
        return None, False, "(no baseline given: check --baseline DIR)"
    key = configuration_of(members[0])
    theirs: dict[str, ScoredRun] = {}
    for r in baseline:
        if configuration_of(r) == key:
            if _pairing(r) in theirs:  # which of two runs stands for the sequence is unknown
                runs = sum(_pairing(b) == _pairing(r) and configuration_of(b) == key for b in baseline)
                name = Path(r["sequence"]).name
                return None, False, f"(the baseline holds {runs} runs of this configuration on {name})"
            theirs[_pairing(r)] = r
    pairs = [(theirs[_pairing(r)].get(metric), r.get(metric)) for r in members if _pairing(r) in theirs]
    if not pairs:
        return None, False, "(the baseline has no run of this configuration on these sequences)"
    change = paired_change(metric, [b for b, _ in pairs], [c for _, c in pairs])
    if change.change is None:
        return None, False, f"(no pair of the {len(pairs)} has the figure on both sides)"
    outside = not _within(change.change, bound)
    if change.p_worse is None:  # one pair: no test can be made, the bound alone decides
        return change.change, not outside, "(1 pair: no paired test, the bound alone decides)"
    real = change.p_worse < BASELINE_ALPHA
    note = f"({change.pairs} pairs, p={change.p_worse:.3g}{': within noise' if outside and not real else ''})"
    return change.change, not (outside and real), note


def _note(row: ScoredRun, metric: str, reference: str) -> str:
    if row.get("failure"):
        return f"(the run failed: {row['failure']})"
    note = ""
    if metric == "time_ratio":
        wall = time_basis(row.record) == "wall_ms_per_frame"
        note = f"against {reference}{', wall time per frame' if wall else ''}"
    return f"{note} {_compilation_note([row], metric)}".strip()


def _compilation_note(rows: list[ScoredRun], metric: str) -> str:
    """Said of a time judged on rows written before times excluded compiling the kernels."""
    timed = metric == "time_ratio" or metric in TIMING_FIELDS
    old = sum(timing_may_include_compilation(r) for r in rows) if timed else 0
    return f"({COMPILATION_NOTE}: {old} of {len(rows)} rows predate record version 7)" if old else ""


def format_report(report: GateReport) -> str:
    """A row per (check, run): the run, and under it each budget as metric value (limit),
    failures marked ``!!``; a check no run matches is a row of its own."""
    from depotbench.core.text_table import Column, render

    rows = []
    for result in report.results:
        budgets = "  ".join(
            f"{'' if v.passed else '!!'}{v.metric} {'missing' if v.value is None else f'{v.value:.4g}'} "
            f"({','.join(v.bound.limits(space=''))}{', ' + v.note if v.note else ''})"
            for v in result.verdicts
        )
        rows.append([result.check, "pass" if result.passed else "FAIL", f"{result.row}\n{budgets}"])
    rows += [[check, "FAIL", "(no run matches this check)"] for check in report.empty_checks]
    columns = [Column("check", "left"), Column("result", "left"), Column("run / budgets", "left")]
    failed = len(report.failures)
    summary = f"{report.gates}: {within_budget(report)}" + (
        f"; {failed} budget(s) failed" if failed else "; all budgets held"
    )
    return "\n".join([render(columns, rows), summary]) if rows else summary


def within_budget(report: GateReport) -> str:
    """``24/24 runs and 2/2 configurations within budget``: runs counted once however many
    checks select them (a run passes when it passes all of them), configurations apart."""
    counts = []
    for configuration, noun in ((False, "runs"), (True, "configurations")):
        held: dict[str, bool] = {}
        for r in report.results:
            if r.configuration == configuration:
                held[r.row] = held.get(r.row, True) and r.passed
        if held or not configuration:
            counts.append(f"{sum(held.values())}/{len(held)} {noun}")
    return " and ".join(counts) + " within budget"


def junit_xml(report: GateReport) -> str:
    """JUnit XML as CI systems read it: a testcase per (check, run), a failure per budget."""
    from xml.etree import ElementTree as ET

    cases = len(report.results) + len(report.empty_checks)
    failures = sum(not r.passed for r in report.results) + len(report.empty_checks)
    suite = ET.Element(
        "testsuite",
        name=_xml(f"depotbench.{report.gates}"),
        tests=str(cases),
        failures=str(failures),
        errors="0",
        time=f"{sum(r.seconds for r in report.results):.3f}",
    )
    for result in report.results:
        case = ET.SubElement(
            suite,
            "testcase",
            classname=_xml(f"depotbench.{report.gates}.{result.check}"),
            name=_xml(result.row),
            time=f"{result.seconds:.3f}",
        )
        failed = [v for v in result.verdicts if not v.passed]
        if failed:
            failure = ET.SubElement(case, "failure", message=_xml("; ".join(v.message for v in failed)))
            failure.text = _xml("\n".join(v.message for v in failed))
    for check in report.empty_checks:
        case = ET.SubElement(
            suite, "testcase", classname=_xml(f"depotbench.{report.gates}.{check}"), name="(none)"
        )
        ET.SubElement(case, "failure", message="no run matches this check")
    root = ET.Element("testsuites", tests=str(cases), failures=str(failures))
    root.append(suite)
    ET.indent(root)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


def _xml(text: str) -> str:
    """``text`` with the characters XML 1.0 forbids (control characters, from a folder's
    name say) written as ``\\xNN``: ElementTree writes them as they are, and the file then
    fails to parse in every CI system."""
    return _NOT_XML.sub(lambda m: f"\\x{ord(m.group()):02x}", text)
