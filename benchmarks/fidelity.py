"""The built-in baseline beside the real ORB-SLAM3, seed by seed: issue 40's "done when".

Usage: python benchmarks/fidelity.py -o OUT [--seeds held-out|dev|N N ...] [--frames 150]
       [--scenes ...] [--orbslam3-runs 2] [--orbslam3-pace 1] [--strategies ...] [--workers 2]
       [--vocabulary FILE] [--resume]

For each scene and seed the sequence is generated (OUT/sequences, copied from the sequence
store when held there), tracked by the built-in pipeline with ``none`` and each rejection
strategy (true boxes), and by ORB-SLAM3 without rejection ``--orbslam3-runs`` times (it is
not deterministic: one sequence gave 55 and 173 mm). Runs stay in OUT/runs.

ORB-SLAM3 is fed at the camera's rate (``--orbslam3-pace 1``, as its own rgbd_tum example
feeds a TUM sequence) and runs alone on the machine, after the built-in runs: its mapping
thread falls behind when frames come back to back or another process shares the cores, and
a mapper that falls behind lets more keyframes through (walking_static, held-out seeds,
median keyframes per 200 frames on 2 cores: 81 paced and alone, 98 paced beside the test
suite, 102 back to back beside another run; 65 with the mapper idle).

Two disjoint seed sets: DEVELOPMENT seeds are the ones whoever tunes the tracker looks at;
HELD_OUT seeds are the ones the reported figures use, and nobody tunes on them.

Per seed: each system's ATE RMSE (ORB-SLAM3: every run and their median), keyframes per
200 frames and tracked fraction. Per scene: the ratio of median ATEs (built-in ``none`` /
ORB-SLAM3), a two-sided Mann-Whitney U test of the two per-seed ATE distributions, the
per-seed verdict agreement ("fails": ATE above FAIL_FACTOR x the same system's median ATE
on static_depot over the same seeds), the keyframe ratio, and each strategy's rho. Then a
PASS/FAIL table of the criteria (CRITERIA), one plot per scene (OUT/fidelity-SCENE.png:
built-in against ORB-SLAM3, one point per seed) and OUT/fidelity.json.

Smoke run (a minute): --scenes walking_xyz static_depot --seeds 1 --frames 20
--orbslam3-runs 1 --strategies box_rule.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

DEVELOPMENT = (1, 2, 3, 5, 7, 8, 12, 13, 14, 21)
"""Seeds already looked at while developing the tracker (1-3: the 0.2.x notes; 5, 7, 8,
12-14: issue 40's table; 21: the README's ghost pictures). Tune on these."""
HELD_OUT = tuple(range(101, 111))
"""Seeds the reported figures use; no walking or static_depot sequence of these seeds was
looked at before issue 40 (the default vocabulary renders seed 101 of other scenes)."""
SEED_SETS = {"dev": DEVELOPMENT, "held-out": HELD_OUT}
WALKING = ("walking_static", "walking_xyz", "walking_rpy", "walking_halfsphere")
STATIC = "static_depot"
"""The control scene: each system's static error is its median ATE here."""
REJECTION = ("box_rule", "prior_flow", "box_epipolar_flow")
KEYFRAME_SPAN = 200
"""Keyframe counts are given per 200 frames, as the issue quotes ORB-SLAM3's 83-134."""


@dataclass(frozen=True)
class Criteria:
    """Issue 40's "done when", each bound named once."""

    ratio_low: float = 0.67
    ratio_high: float = 1.5
    """Median ATE of built-in ``none`` over ORB-SLAM3's, on each walking analog."""
    min_p: float = 0.05
    """The Mann-Whitney U test must not separate the two ATE distributions below this p."""
    fail_factor: float = 10.0
    """A run "fails" when its ATE exceeds this many times its system's static error."""
    min_agreement: float = 0.8
    """Share of seeds on which both systems give the same verdict (8 of 10)."""
    keyframe_factor: float = 1.5
    """Median keyframes per 200 frames within this factor of ORB-SLAM3's, either way."""
    min_rho_percent: float = 90.0
    """Each rejection strategy's rho (true boxes) on each walking analog."""


CRITERIA = Criteria()


def _worker_init() -> None:
    os.environ["OMP_NUM_THREADS"] = "1"
    import cv2

    cv2.setNumThreads(1)


@dataclass(frozen=True)
class Job:
    """One sequence's built-in runs (all strategies, sharing its features), or one ORB-SLAM3 run."""

    scene: str
    seed: int
    sequence: Path
    tracker: str
    strategies: tuple[str, ...]
    repeat: int
    runs: Path
    stages: Path | None
    vocabulary: Path | None
    resume: bool
    pace: float = 0.0
    """ORB-SLAM3's ``pace`` parameter (0: back to back)."""

    def target(self, strategy: str) -> Path:
        """Runs at another pace are other runs: ``--resume`` reads back only its own."""
        tracker = f"{self.tracker}-pace{self.pace:g}" if self.pace else self.tracker
        return self.runs / self.sequence.name / f"{tracker}-{strategy}-{self.repeat}"


def _run(job: Job) -> tuple[Job, dict[str, dict], float, int]:
    """The job's metrics per strategy, its seconds and how many runs it read back (``--resume``);
    a tracker that fails is recorded as a failure, not dropped."""
    from depotbench.eval.run.cache import StageCache
    from depotbench.eval.run.harness import run_sequence
    from depotbench.eval.trackers.base import TrackerError
    from depotbench.eval.trackers.orbslam3 import PACE
    from depotbench.eval.trackers.registry import TrackerConfig, tracker_parameters

    started = time.perf_counter()
    cache = StageCache(job.stages) if job.stages is not None else None
    parameters = tracker_parameters(job.tracker, {PACE: str(job.pace)} if job.pace else {})
    config = TrackerConfig(job.tracker, vocabulary=job.vocabulary, parameters=parameters)
    out, resumed = {}, 0
    for strategy in job.strategies:
        target = job.target(strategy)
        if job.resume and (target / "metrics.json").is_file():
            out[strategy] = json.loads((target / "metrics.json").read_text(encoding="utf-8"))
            resumed += 1
            continue
        try:
            out[strategy] = run_sequence(
                job.sequence, target, strategy, progress=False, overwrite=True, tracker=config, cache=cache
            )
        except TrackerError as exc:  # ORB-SLAM3 crashed or timed out: a failed run, counted as one
            out[strategy] = {"failure": str(exc)}
    return job, out, time.perf_counter() - started, resumed


@dataclass(frozen=True)
class Run:
    """What the report needs of one run."""

    ate_m: float
    """inf for a run without an ATE (failed, or fewer than 3 tracked frames): it ranks worst."""
    tracked: float
    keyframes_per_span: float | None
    failure: str | None = None

    @classmethod
    def of(cls, metrics: dict) -> Run:
        if "failure" in metrics:
            return cls(math.inf, 0.0, None, metrics["failure"])
        ate = (metrics.get("ate_m") or {}).get("rmse")
        keyframes = metrics.get("keyframes")
        frames = metrics["frames"]
        return cls(
            math.inf if ate is None else float(ate),
            metrics["tracked_frames"] / frames,
            None if keyframes is None else keyframes * KEYFRAME_SPAN / frames,
        )


def _median(values) -> float:
    import numpy as np

    values = [v for v in values if v is not None and not math.isnan(v)]
    return float(np.median(values)) if values else math.nan


def _spread(values: list[float]) -> dict:
    return {"n": len(values), "median": _median(values), "min": min(values), "max": max(values)}


def _ratio(a: float, b: float) -> float:
    return a / b if b and math.isfinite(b) and not math.isnan(a) else math.nan


def _ratio_interval(builtin: list[float], orb: list[float]) -> tuple[float, float] | None:
    """The 95 % bootstrap interval of the ratio of medians, seeds resampled in pairs (percentile;
    seeded, as eval.metrics.statistics is). Ten seeds give a wide one: the same tracker's ratio
    on walking_static was 0.70 on the held-out seeds and 1.52 on the development seeds."""
    import numpy as np
    from depotbench.eval.metrics.statistics import BOOTSTRAP_SEED, CONFIDENCE, RESAMPLES
    from scipy.stats import bootstrap

    finite = [(a, b) for a, b in zip(builtin, orb, strict=True) if math.isfinite(a) and math.isfinite(b)]
    if len(finite) < 3 or len(finite) < len(builtin):
        return None  # a failed run has no finite ratio to resample

    def ratio(a, b):
        return np.median(a) / np.median(b)

    interval = bootstrap(
        (np.array([a for a, _ in finite]), np.array([b for _, b in finite])),
        ratio,
        paired=True,
        vectorized=False,
        n_resamples=RESAMPLES,
        confidence_level=CONFIDENCE,
        method="percentile",
        random_state=np.random.default_rng(BOOTSTRAP_SEED),
    ).confidence_interval
    return float(interval.low), float(interval.high)


def _rho(base: float, mine: float) -> float:
    """rho = (mu - gamma) / mu x 100 % (design card), nan where the baseline has no finite ATE."""
    return (base - mine) / base * 100 if math.isfinite(base) and base > 0 else math.nan


def _seed_rows(scene_seeds: list[tuple[int, str]], results: dict, strategies: tuple[str, ...]) -> list:
    rows = []
    for seed, name in scene_seeds:
        builtin = {s: Run.of(results[(name, "builtin", 0)][s]) for s in ("none", *strategies)}
        orb = [Run.of(m["none"]) for (n, t, _), m in sorted(results.items()) if n == name and t == "orbslam3"]
        rows.append({"seed": seed, "builtin": builtin, "orbslam3": orb})
    return rows


def _scene_summary(scene: str, rows: list, strategies: tuple[str, ...], static: dict | None) -> dict:
    """Per scene: the figures of issue 40's "done when", each with its inputs."""
    from scipy.stats import mannwhitneyu, spearmanr, wilcoxon

    bi = [r["builtin"]["none"].ate_m for r in rows]
    orb = [_median([run.ate_m for run in r["orbslam3"]]) for r in rows]
    summary: dict = {"n_seeds": len(rows)}
    summary["builtin_none_ate_median_m"] = _median(bi)
    summary["orbslam3_ate_median_m"] = _median(orb)
    summary["ate_ratio"] = _ratio(summary["builtin_none_ate_median_m"], summary["orbslam3_ate_median_m"])
    summary["ate_ratio_ci95"] = _ratio_interval(bi, orb)
    paired = [(a, b) for a, b in zip(bi, orb, strict=True) if not math.isnan(b)]
    if len(paired) >= 2 and any(a != b for a, b in paired):
        summary["mannwhitney_p"] = float(
            mannwhitneyu([a for a, _ in paired], [b for _, b in paired], alternative="two-sided").pvalue
        )
        # Informative only: the seeds pair the two systems, which the unpaired test ignores.
        finite = [(a, b) for a, b in paired if math.isfinite(a) and math.isfinite(b)]
        summary["wilcoxon_p"] = (
            float(wilcoxon([a for a, _ in finite], [b for _, b in finite]).pvalue)
            if len(finite) >= 2 and any(a != b for a, b in finite)
            else None
        )
        # Informative: do the two agree on which seeds are hard (when nearly every seed "fails")?
        summary["spearman_r"] = float(spearmanr([a for a, _ in paired], [b for _, b in paired]).statistic)
    else:
        summary["mannwhitney_p"] = summary["wilcoxon_p"] = summary["spearman_r"] = None
    bi_kf = [r["builtin"]["none"].keyframes_per_span for r in rows]
    orb_kf = [_median([run.keyframes_per_span for run in r["orbslam3"]]) for r in rows]
    summary["builtin_keyframes_per_200"] = _median(bi_kf)
    summary["orbslam3_keyframes_per_200"] = _median(orb_kf)
    summary["keyframe_ratio"] = _ratio(
        summary["builtin_keyframes_per_200"], summary["orbslam3_keyframes_per_200"]
    )
    summary["builtin_tracked_min"] = min(r["builtin"]["none"].tracked for r in rows)
    summary["orbslam3_tracked_min"] = min((run.tracked for r in rows for run in r["orbslam3"]), default=None)
    if static is not None:
        limit_bi = CRITERIA.fail_factor * static["builtin"]
        limit_orb = CRITERIA.fail_factor * static["orbslam3"]
        verdicts = [(a > limit_bi, b > limit_orb) for a, b in zip(bi, orb, strict=True)]
        summary["fail_limit_m"] = {"builtin": limit_bi, "orbslam3": limit_orb}
        summary["builtin_fails"] = sum(a for a, _ in verdicts)
        summary["orbslam3_fails"] = sum(b for _, b in verdicts)
        summary["verdicts_agree"] = sum(a == b for a, b in verdicts)
    strategy_rho = {}
    for strategy in strategies:
        mine = [r["builtin"][strategy].ate_m for r in rows]
        per_seed = [_rho(a, b) for a, b in zip(bi, mine, strict=True)]
        per_seed = [v for v in per_seed if not math.isnan(v)]
        strategy_rho[strategy] = {
            "ate_median_m": _median(mine),
            "rho_of_medians_percent": _rho(_median(bi), _median(mine)),
            "rho_per_seed_percent": _spread(per_seed) if per_seed else None,
            "tracked_min": min(r["builtin"][strategy].tracked for r in rows),
        }
    summary["strategies"] = strategy_rho
    summary["criteria"] = _criteria(scene, summary)
    return summary


def _criteria(scene: str, s: dict) -> dict[str, bool | None]:
    """Issue 40's checks for one scene: None where a check does not apply to it or cannot be made."""
    walking = scene in WALKING
    ratio, p = s["ate_ratio"], s["mannwhitney_p"]
    checks: dict[str, bool | None] = {
        "ate_ratio": (CRITERIA.ratio_low <= ratio <= CRITERIA.ratio_high)
        if walking and not math.isnan(ratio)
        else None,
        "rank_test": (p >= CRITERIA.min_p if p is not None else None) if walking else None,
        "verdicts": (
            s["verdicts_agree"] >= CRITERIA.min_agreement * s["n_seeds"]
            if walking and "verdicts_agree" in s
            else None
        ),
        "static_not_worse": (
            s["builtin_none_ate_median_m"] <= s["orbslam3_ate_median_m"] if scene == STATIC else None
        ),
    }
    kf = s["keyframe_ratio"]
    checks["keyframes"] = (
        (1 / CRITERIA.keyframe_factor <= kf <= CRITERIA.keyframe_factor) if not math.isnan(kf) else None
    )
    for strategy, figures in s["strategies"].items():
        rho = figures["rho_of_medians_percent"]
        checks[f"rho_{strategy}"] = (
            (rho >= CRITERIA.min_rho_percent) if walking and not math.isnan(rho) else None
        )
    return checks


def _mm(value: float) -> str:
    return "fail" if math.isinf(value) else ("-" if math.isnan(value) else f"{value * 1000:.1f}")


def _print_seeds(scene: str, rows: list, strategies: tuple[str, ...], static: dict | None) -> None:
    from depotbench.core.text_table import Column, render

    print(f"\n{scene}: ATE RMSE mm (tracked %), keyframes per {KEYFRAME_SPAN} frames; F: fails")
    columns = [
        Column("seed"),
        Column("built-in none"),
        Column("ORB-SLAM3 runs (median)"),
        Column("kf bi"),
        Column("kf orb"),
        *(Column(s) for s in strategies),
    ]
    table, failures = [], []
    for r in rows:
        bi, orb = r["builtin"]["none"], r["orbslam3"]
        orb_median = _median([run.ate_m for run in orb])
        flag_bi = flag_orb = ""
        if static is not None:
            flag_bi = " F" if bi.ate_m > CRITERIA.fail_factor * static["builtin"] else "  "
            flag_orb = " F" if orb_median > CRITERIA.fail_factor * static["orbslam3"] else "  "
        orb_text = ", ".join(_mm(run.ate_m) for run in orb) + f" ({_mm(orb_median)})"
        orb_kf = _median([run.keyframes_per_span for run in orb])
        cells = [f"{_mm(r['builtin'][s].ate_m)} ({r['builtin'][s].tracked * 100:.0f}%)" for s in strategies]
        bi_cell = f"{_mm(bi.ate_m)} ({bi.tracked * 100:.0f}%)"
        kf_bi = "-" if bi.keyframes_per_span is None else f"{bi.keyframes_per_span:.0f}"
        kf_orb = "-" if math.isnan(orb_kf) else f"{orb_kf:.0f}"
        table.append([str(r["seed"]), bi_cell + flag_bi, orb_text + flag_orb, kf_bi, kf_orb, *cells])
        failures += [f"seed {r['seed']}: ORB-SLAM3 failed: {run.failure}" for run in orb if run.failure]
    print(render(columns, table))
    for line in failures:
        print(line)


def _print_summary(summaries: dict, strategies: tuple[str, ...]) -> None:
    from depotbench.core.text_table import Column, cell, render

    print("\nper scene: medians over seeds (ORB-SLAM3: median of each seed's runs first), ATE mm")
    headers = ("bi none", "ORB", "ratio", "95% CI", "MWU p", "Wilc p", "Spear", "agree", "F bi", "F orb")
    columns = [
        Column("scene", "left"),
        *(Column(h) for h in (*headers, "kf bi", "kf orb", "kf ratio")),
    ]
    rows = []
    for scene, s in summaries.items():
        ci = "-" if s["ate_ratio_ci95"] is None else "{:.2f}-{:.2f}".format(*s["ate_ratio_ci95"])
        r = "-" if s["spearman_r"] is None or math.isnan(s["spearman_r"]) else f"{s['spearman_r']:.2f}"
        agree = f"{s['verdicts_agree']}/{s['n_seeds']}" if "verdicts_agree" in s else "-"
        rows.append(
            [
                scene,
                _mm(s["builtin_none_ate_median_m"]),
                _mm(s["orbslam3_ate_median_m"]),
                f"{s['ate_ratio']:.2f}",
                ci,
                cell(s["mannwhitney_p"], ".3f"),
                cell(s["wilcoxon_p"], ".3f"),
                r,
                agree,
                str(s.get("builtin_fails", "-")),
                str(s.get("orbslam3_fails", "-")),
                f"{s['builtin_keyframes_per_200']:.1f}",
                f"{s['orbslam3_keyframes_per_200']:.1f}",
                f"{s['keyframe_ratio']:.2f}",
            ]
        )
    print(render(columns, rows))
    print(
        "\nrho per strategy (true boxes): of the medians [per seed: median, min..max]; its ATE median mm; "
        "the fewest frames one of its runs tracked"
    )
    rows = []
    for scene, s in summaries.items():
        cells = []
        for strategy in strategies:
            f = s["strategies"][strategy]
            spread = f["rho_per_seed_percent"]
            per_seed = (
                ""
                if spread is None
                else f" [{spread['median']:.0f}, {spread['min']:.0f}..{spread['max']:.0f}]"
            )
            cells.append(
                f"{f['rho_of_medians_percent']:.1f} %{per_seed} {_mm(f['ate_median_m'])} "
                f"{f['tracked_min'] * 100:.0f}%"
            )
        rows.append([scene, *cells])
    print(render([Column("scene", "left"), *(Column(s) for s in strategies)], rows))


def _print_criteria(summaries: dict) -> dict:
    from depotbench.core.text_table import Column, render

    names = list(dict.fromkeys(k for s in summaries.values() for k in s["criteria"]))
    print("\nissue 40's done-when (PASS/FAIL; '-': does not apply to the scene)")
    every = True
    rows = []
    for scene, s in summaries.items():
        cells = []
        for name in names:
            verdict = s["criteria"].get(name)
            every &= verdict is not False
            cells.append("-" if verdict is None else ("PASS" if verdict else "FAIL"))
        rows.append([scene, *cells])
    print(render([Column("scene", "left"), *(Column(n) for n in names)], rows))
    print(f"all: {'PASS' if every else 'FAIL'}")
    return {"all_pass": every}


def _plot(scene: str, rows: list, summary: dict, static: dict | None, path: Path) -> None:
    """Built-in ATE against ORB-SLAM3's, one point per seed (a bar spans ORB-SLAM3's runs)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from depotbench.core.output import write_bytes_atomic
    from matplotlib.ticker import FormatStrFormatter, NullFormatter

    bi = np.array([r["builtin"]["none"].ate_m for r in rows]) * 1000
    runs = [np.array([run.ate_m for run in r["orbslam3"]]) * 1000 for r in rows]
    orb = np.array([np.median(v) if len(v) else np.nan for v in runs])
    limits = [] if static is None else [CRITERIA.fail_factor * v * 1000 for v in static.values()]
    finite = np.concatenate([bi[np.isfinite(bi)], *[v[np.isfinite(v)] for v in runs], limits])
    finite = finite[np.isfinite(finite)]
    low = max(float(finite.min()) / 2, 0.1) if len(finite) else 0.1
    high = float(finite.max()) * 2 if len(finite) else 1000.0
    clip = high  # a run without an ATE is drawn at the top edge, as a cross
    fig, ax = plt.subplots(figsize=(5.5, 5.2), dpi=110)
    line = np.array([low, high])
    ax.fill_between(
        line, line * CRITERIA.ratio_low, line * CRITERIA.ratio_high, color="0.9", label="0.67x-1.5x"
    )
    ax.plot(line, line, color="0.4", lw=1, label="y = x")
    if static is not None:
        ax.axvline(CRITERIA.fail_factor * static["orbslam3"] * 1000, color="tab:red", ls=":", lw=1)
        ax.axhline(
            CRITERIA.fail_factor * static["builtin"] * 1000, color="tab:red", ls=":", lw=1, label="fails"
        )
    for r, y, x, v in zip(rows, bi, orb, runs, strict=True):
        yy, xx = (y if np.isfinite(y) else clip), (x if np.isfinite(x) else clip)
        shown = np.where(np.isfinite(v), v, clip)
        if len(shown) > 1:
            ax.plot([shown.min(), shown.max()], [yy, yy], color="tab:blue", lw=1, alpha=0.6)
        marker = "o" if np.isfinite(y) and np.isfinite(x) else "x"
        ax.plot([xx], [yy], marker, color="tab:blue", ms=5)
        ax.annotate(str(r["seed"]), (xx, yy), textcoords="offset points", xytext=(4, 3), fontsize=7)
    ax.set(xscale="log", yscale="log", xlim=(low, high), ylim=(low, high))
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(FormatStrFormatter("%g"))
        axis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("ORB-SLAM3 ATE RMSE, mm (median of runs; bar: the runs)")
    ax.set_ylabel("built-in none ATE RMSE, mm")
    p = summary["mannwhitney_p"]
    ax.set_title(
        f"{scene}: median ratio {summary['ate_ratio']:.2f}, MWU p {'-' if p is None else f'{p:.3f}'}",
        fontsize=10,
    )
    ax.legend(loc="upper left", fontsize=7)
    ax.grid(True, which="both", alpha=0.2)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", bbox_inches="tight")
    plt.close(fig)
    write_bytes_atomic(path, buffer.getvalue())


def _jsonable(value):
    """Infinite ATEs (failed runs) as the string "inf", NaN as null: JSON has neither."""
    if isinstance(value, float):
        return None if math.isnan(value) else ("inf" if math.isinf(value) else value)
    if isinstance(value, Run):
        return _jsonable(value.__dict__)
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value


def _revision() -> str:
    """The commit of the checkout the tracker was imported from ('+changes' when its tracked
    files differ from it): a run of a snapshot (PYTHONPATH) names the snapshot, not this one."""
    import depotbench.slam

    root = Path(depotbench.slam.__file__).resolve().parents[1]
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(["git", "diff", "--quiet", "HEAD"], cwd=root, check=False).returncode
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return f"{head}{'+changes' if dirty else ''} ({root})"


def _seeds(values: list[str], parser: argparse.ArgumentParser) -> tuple[str, tuple[int, ...]]:
    if len(values) == 1 and values[0] in SEED_SETS:
        return values[0], SEED_SETS[values[0]]
    try:
        seeds = tuple(int(v) for v in values)
    except ValueError:
        parser.error(f"--seeds: give {' or '.join(SEED_SETS)}, or seeds as integers; got {' '.join(values)}")
    if len(set(seeds)) != len(seeds):
        parser.error(f"--seeds: {' '.join(values)} repeats a seed")
    if set(seeds) & set(DEVELOPMENT) and set(seeds) & set(HELD_OUT):
        parser.error(f"--seeds: {' '.join(values)} mixes development and held-out seeds; run them apart")
    named = (
        "dev" if set(seeds) <= set(DEVELOPMENT) else "held-out" if set(seeds) <= set(HELD_OUT) else "other"
    )
    return named, seeds


def main() -> None:
    from depotbench.eval.run.harness import STRATEGY_CHOICES

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "-o", "--output", type=Path, required=True, help="sequences, runs, plots and JSON go here"
    )
    parser.add_argument("--scenes", nargs="+", default=[*WALKING, STATIC], help="library scenes")
    parser.add_argument(
        "--seeds",
        nargs="+",
        default=["held-out"],
        help="held-out (101-110), dev, or seeds (default: held-out)",
    )
    parser.add_argument("--frames", type=int, default=150, help="frames per sequence (default 150)")
    parser.add_argument(
        "--orbslam3-runs", type=int, default=2, help="ORB-SLAM3 runs per sequence (default 2)"
    )
    parser.add_argument(
        "--orbslam3-pace",
        type=float,
        default=1.0,
        help="ORB-SLAM3's pace: 1 feeds frames at the camera's rate, as its rgbd_tum example "
        "(default); 0 back to back",
    )
    parser.add_argument(
        "--strategies",
        nargs="*",
        default=list(REJECTION),
        choices=[s for s in STRATEGY_CHOICES if s != "none"],
        help="built-in strategies beside none, true boxes (default: the three rejection strategies)",
    )
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--vocabulary", type=Path, help="ORB-SLAM3's vocabulary (default: the bench's)")
    parser.add_argument(
        "--resume",
        action="store_true",
        help="keep runs already in OUT/runs (same code!) instead of running again",
    )
    args = parser.parse_args()
    seed_set, seeds = _seeds(args.seeds, parser)
    if args.frames < 10:
        parser.error(f"--frames: at least 10, got {args.frames}")
    if args.orbslam3_runs < 1 or args.workers < 1:
        parser.error("--orbslam3-runs and --workers: at least 1")
    from depotbench.core.errors import InputError
    from depotbench.core.parameters import parameter_text
    from depotbench.eval.trackers.orbslam3 import PACE, pace_of

    try:  # checked as the tracker checks its pace parameter
        pace_of(((PACE, parameter_text(args.orbslam3_pace)),))
    except InputError as exc:
        parser.error(f"--orbslam3-pace: {exc}")

    from depotbench.eval.trackers.orbslam3 import available
    from depotbench.eval.trackers.vocabulary import default_vocabulary
    from depotbench.scenes import library
    from depotbench.scenes.generation import run_suite
    from depotbench.scenes.suite import Suite

    known = set(library.names())
    unknown = [s for s in args.scenes if s not in known]
    if unknown:
        parser.error(f"--scenes: {', '.join(unknown)} not in the scene library (depotbench scenarios)")
    if not available():
        sys.exit("fidelity.py: ORB-SLAM3 is not installed (pip install 'depotbench[orbslam3]')")
    strategies = tuple(args.strategies)
    out = args.output
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    vocabulary = args.vocabulary or default_vocabulary()
    sequences: list[tuple[str, int, Path]] = []
    for scene in args.scenes:
        suite = Suite(suite=scene, base=scene, overrides={"frames": args.frames}, seeds=list(seeds))
        print(f"{scene}: {len(seeds)} sequences of {args.frames} frames", flush=True)
        with tempfile.TemporaryDirectory() as tmp:  # the suite exists only here; its path names it
            index = run_suite(
                suite, Path(tmp) / f"{scene}.yaml", out / "sequences" / scene, args.workers, progress=False
            )
        sequences += [(scene, e["seed"], out / "sequences" / scene / e["name"]) for e in index["sequences"]]
    generated_s = time.perf_counter() - started
    print(f"{len(sequences)} sequences ready in {generated_s:.0f} s", flush=True)

    with tempfile.TemporaryDirectory(dir=out, prefix=".stages-") as stages:
        common = {"runs": out / "runs", "vocabulary": None, "resume": args.resume}
        jobs = [
            Job(scene, seed, path, "builtin", ("none", *strategies), 0, stages=Path(stages), **common)
            for scene, seed, path in sequences
        ]
        jobs += [
            Job(
                scene,
                seed,
                path,
                "orbslam3",
                ("none",),
                r,
                stages=None,
                pace=args.orbslam3_pace,
                **common | {"vocabulary": vocabulary},
            )
            for r in range(args.orbslam3_runs)
            for scene, seed, path in sequences
        ]
        results: dict[tuple[str, str, int], dict] = {}
        busy = {"builtin": 0.0, "orbslam3": 0.0, "runs_read_back": 0}
        done = 0
        # The built-in runs side by side, then ORB-SLAM3's one at a time (see the docstring).
        for tracker, workers in (("builtin", args.workers), ("orbslam3", 1)):
            with ProcessPoolExecutor(
                workers, mp_context=get_context("spawn"), initializer=_worker_init
            ) as pool:
                futures = [pool.submit(_run, job) for job in jobs if job.tracker == tracker]
                for future in as_completed(futures):
                    job, metrics, seconds, read_back = future.result()
                    done += 1
                    busy["runs_read_back"] += read_back
                    results[(job.sequence.name, job.tracker, job.repeat)] = metrics
                    busy[job.tracker] += seconds
                    ates = ", ".join(f"{s} {_mm(Run.of(m).ate_m)}" for s, m in metrics.items())
                    elapsed = time.perf_counter() - started
                    print(
                        f"[{done}/{len(jobs)}] {job.scene} seed {job.seed} {job.tracker}"
                        f"{'' if job.tracker == 'builtin' else f' run {job.repeat + 1}'}: {ates} mm "
                        f"({seconds:.0f} s; {elapsed / 60:.1f} min elapsed)",
                        flush=True,
                    )
    _report(
        args, seed_set, seeds, strategies, sequences, results, out, vocabulary, started, generated_s, busy
    )


def _report(
    args, seed_set, seeds, strategies, sequences, results, out, vocabulary, started, generated_s, busy
):
    from depotbench.core.output import write_text_atomic

    per_scene = {}
    for scene in dict.fromkeys(s for s, _, _ in sequences):
        scene_seeds = [(seed, p.name) for s, seed, p in sequences if s == scene]
        per_scene[scene] = _seed_rows(scene_seeds, results, strategies)
    static = None
    if STATIC in per_scene:
        rows = per_scene[STATIC]
        static = {
            "builtin": _median([r["builtin"]["none"].ate_m for r in rows]),
            "orbslam3": _median([_median([run.ate_m for run in r["orbslam3"]]) for r in rows]),
        }
    summaries = {}
    print(
        f"\nseeds: {seed_set} {' '.join(map(str, seeds))}; {args.frames} frames; "
        f"{args.orbslam3_runs} ORB-SLAM3 runs at pace {args.orbslam3_pace:g}"
    )
    if static is None:
        print(f"no {STATIC} in --scenes: no static error, so no fail verdicts")
    else:
        print(
            f"static error (median ATE on {STATIC}): built-in {_mm(static['builtin'])} mm, "
            f"ORB-SLAM3 {_mm(static['orbslam3'])} mm; fails: ATE > {CRITERIA.fail_factor:g}x its system's"
        )
    for scene, rows in per_scene.items():
        summaries[scene] = _scene_summary(scene, rows, strategies, static)
        _print_seeds(scene, rows, strategies, static)
        _plot(scene, rows, summaries[scene], static, out / f"fidelity-{scene}.png")
    _print_summary(summaries, strategies)
    verdict = _print_criteria(summaries)
    failed = []
    for scene, rows in per_scene.items():
        for r in rows:
            named = [*r["builtin"].items(), *(("ORB-SLAM3", run) for run in r["orbslam3"])]
            failed += [
                f"{scene} seed {r['seed']} {name}: {run.failure}" for name, run in named if run.failure
            ]
    if failed:  # counted as failures above; a bench fault (a traceback) shows here, not as figures
        print(f"\n{len(failed)} runs failed, each counted as a failure (ATE inf):")
        print("\n".join(f"  {line}" for line in failed))
    total_s = time.perf_counter() - started
    print(
        f"\ntime: {total_s / 60:.1f} min in all; sequences {generated_s / 60:.1f} min; worker time "
        f"built-in {busy['builtin'] / 60:.1f} min ({args.workers} workers), "
        f"ORB-SLAM3 {busy['orbslam3'] / 60:.1f} min (alone)"
        + (
            f"; {busy['runs_read_back']} runs read back (--resume), not timed"
            if busy["runs_read_back"]
            else ""
        )
    )
    document = {
        "meta": {
            "seed_set": seed_set,
            "seeds": list(seeds),
            "development_seeds": list(DEVELOPMENT),
            "held_out_seeds": list(HELD_OUT),
            "frames": args.frames,
            "orbslam3_runs": args.orbslam3_runs,
            "orbslam3_pace": args.orbslam3_pace,
            "strategies": list(strategies),
            "vocabulary": str(vocabulary),
            "revision": _revision(),
            "criteria": CRITERIA.__dict__,
            "static_error": static,
            "static_error_reading": f"each system's median ATE on {STATIC} over the same seeds",
            "time_s": {
                "total": total_s,
                "sequences": generated_s,
                "worker_builtin": busy["builtin"],
                "worker_orbslam3": busy["orbslam3"],
                "runs_read_back": busy["runs_read_back"],
            },
        },
        "scenes": {scene: {"summary": summaries[scene], "seeds": per_scene[scene]} for scene in per_scene},
        "failed_runs": failed,
        **verdict,
    }
    write_text_atomic(out / "fidelity.json", json.dumps(_jsonable(document), indent=2, sort_keys=True) + "\n")
    print(f"{out / 'fidelity.json'} and {len(per_scene)} plots (fidelity-SCENE.png) written")


if __name__ == "__main__":
    main()
