"""``depotbench report``: one self-contained HTML page for a run or a sweep.

The page needs no network and no script: plots are PNGs drawn by matplotlib and
frames are PNGs drawn by OpenCV, all inlined as data URIs. For a run it shows the
trajectory against ground truth from above, the error over time with the
tracking state, a strip of frames with keypoints coloured by decision and by
true dynamic label, and the scenario's difficulty. For a sweep it adds the best
configuration per family, ATE and rejection precision/recall against each swept
threshold, the accuracy/time Pareto plot, and the run detail of each family's
best configuration (tracked again from the cache; runs are deterministic, so it
is the stored run).
"""

from __future__ import annotations

import base64
import html
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from eval.alignment import Alignment, align
from eval.sweep_report import pareto_figure, pyplot, settings_text, threshold_figures, with_rho
from eval.trajectory import Trajectory, associate, read_tum
from sim.errors import InputError
from sim.sequence import Sequence
from slam.types import Rejection, TrackingState

DECISION_COLOURS: dict[str, tuple[int, int, int]] = {
    Rejection.KEPT.value: (40, 200, 60),
    Rejection.DYNAMIC_BOX.value: (230, 40, 40),
    Rejection.EPIPOLAR.value: (255, 160, 0),
    Rejection.FLOW_OUTLIER.value: (200, 60, 220),
    Rejection.MOVING_FLOW.value: (0, 170, 255),
}
"""RGB per rejection decision (the legend of the frame strip)."""
MOVING_COLOUR = (255, 40, 40)
STATIC_COLOUR = (60, 120, 255)
STATE_COLOURS = {
    TrackingState.OK.value: None,
    TrackingState.RELOCALIZED.value: "#fde68a",
    TrackingState.LOST.value: "#fca5a5",
    TrackingState.NOT_INITIALIZED.value: "#e5e7eb",
}
STRIP_FRAMES = 5
STRIP_WIDTH_PX = 320


@dataclass(frozen=True)
class RunView:
    """Everything the page shows of one run."""

    title: str
    metrics: dict[str, Any]
    timestamps_s: np.ndarray
    states: tuple[str, ...]
    estimate: Trajectory | None
    sequence: Sequence | None
    diagnostics: dict[str, np.ndarray] | None


def load_run(folder: Path) -> RunView:
    """A run folder written by ``depotbench run``; a missing or damaged file is named."""
    metrics_path = folder / "metrics.json"
    try:
        metrics = json.loads(metrics_path.read_text(encoding="utf-8"))
        title = f"{metrics['tracker']} · {metrics['strategy']} · {metrics['detector']}"
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{metrics_path}: cannot read the run's metrics ({exc!r})") from None
    frames_path = folder / "frames.csv"
    try:
        frames = np.atleast_1d(
            np.genfromtxt(frames_path, delimiter=",", names=True, dtype=None, encoding="utf-8")
        )
        timestamps = np.asarray(frames["timestamp_s"], float)
        states = tuple(str(s) for s in frames["state"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{frames_path}: cannot read the run's frames ({exc!r})") from None
    trajectory = folder / "trajectory.txt"
    estimate = read_tum(trajectory) if trajectory.is_file() else None
    diagnostics = None
    diagnostics_path = folder / "diagnostics.npz"
    if diagnostics_path.is_file():
        try:
            with np.load(diagnostics_path) as data:
                diagnostics = {k: data[k] for k in data.files}
        except (OSError, ValueError) as exc:
            raise InputError(f"{diagnostics_path}: cannot read the run's diagnostics ({exc!r})") from None
    return RunView(
        title=title,
        metrics=metrics,
        timestamps_s=timestamps,
        states=states,
        estimate=estimate,
        sequence=_open_sequence(metrics.get("sequence")),
        diagnostics=diagnostics,
    )


def view_of(title: str, tracked) -> RunView:
    """A run tracked in this process (``eval.harness.Tracked``)."""
    from eval.harness import diagnostics_arrays

    run = tracked.run
    return RunView(
        title=title,
        metrics=tracked.metrics,
        timestamps_s=np.asarray(run.timestamps_s, float),
        states=tuple(s.value for s in run.states),
        estimate=run.trajectory(),
        sequence=_open_sequence(tracked.metrics.get("sequence")),
        diagnostics=diagnostics_arrays(run.results, run.labels or []) if run.results is not None else None,
    )


def _open_sequence(path: str | None) -> Sequence | None:
    if not path or not Path(path).is_dir():
        return None
    return Sequence.open(Path(path))


# -- figures -----------------------------------------------------------------


def figure_png(fig) -> bytes:
    from io import BytesIO

    buffer = BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    pyplot().close(fig)
    return buffer.getvalue()


def _reference(sequence: Sequence | None) -> Trajectory | None:
    if sequence is None or sequence.groundtruth is None:
        return None
    gt = sequence.groundtruth
    return Trajectory.from_quaternions(gt.timestamps_s, gt.positions_m, gt.quats_xyzw, "groundtruth")


def aligned_trajectories(view: RunView) -> tuple[Trajectory, Trajectory] | None:
    """Ground truth and the estimate associated with it, SE(3)-aligned as ATE aligns them."""
    reference = _reference(view.sequence)
    if reference is None or view.estimate is None or len(view.estimate) < 3:
        return None
    ref, est = associate(reference, view.estimate)
    aligned, _ = align(est, ref, Alignment.SE3)
    return ref, aligned


def trajectory_figure(view: RunView):
    """Top view: the two axes along which the ground truth moves most."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(4.6, 4.2))
    reference = _reference(view.sequence)
    pair = aligned_trajectories(view)
    if reference is not None:
        extent = np.ptp(reference.positions_m, axis=0)
        a, b = sorted(np.argsort(-extent)[:2])
        ax.plot(
            reference.positions_m[:, a], reference.positions_m[:, b], "-", c="0.3", lw=2, label="ground truth"
        )
        if pair is not None:
            est = pair[1].positions_m
            ax.plot(est[:, a], est[:, b], "-", c="C3", lw=1.2, label="estimate (SE(3)-aligned)")
            ax.plot(est[0, a], est[0, b], "o", c="C3", ms=5)
        names = "xyz"
        ax.set(xlabel=f"{names[a]} (m)", ylabel=f"{names[b]} (m)", aspect="equal")
        ax.xaxis.set_major_locator(plt.MaxNLocator(5))
        ax.yaxis.set_major_locator(plt.MaxNLocator(6))
    elif view.estimate is not None:
        ax.plot(
            view.estimate.positions_m[:, 0], view.estimate.positions_m[:, 1], "-", c="C3", label="estimate"
        )
    ax.set_title("trajectory from above")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def error_figure(view: RunView):
    """Translational error per tracked frame, with the tracking state shaded behind it."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.0, 3.0))
    t0 = float(view.timestamps_s[0]) if len(view.timestamps_s) else 0.0
    times = view.timestamps_s - t0
    step = float(np.median(np.diff(times))) if len(times) > 1 else 1.0
    for time, state in zip(times, view.states, strict=True):
        colour = STATE_COLOURS.get(state)
        if colour:
            ax.axvspan(time - step / 2, time + step / 2, color=colour, lw=0)
    pair = aligned_trajectories(view)
    if pair is not None:
        ref, est = pair
        errors = np.linalg.norm(est.positions_m - ref.positions_m, axis=1)
        ax.plot(est.timestamps_s - t0, errors * 100, ".-", c="C3", ms=3, lw=1)
    for state, colour in STATE_COLOURS.items():
        if colour:
            ax.plot([], [], "s", c=colour, label=state.lower())
    ax.set(xlabel="time (s)", ylabel="position error (cm)", title="error over time (SE(3)-aligned)")
    ax.set_xlim(times.min() - step if len(times) else 0, times.max() + step if len(times) else 1)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return fig


def _strip_frames(view: RunView) -> list[int]:
    """Evenly spread frames, preferring ones with true movers when labels are known."""
    d = view.diagnostics
    n = len(d["keypoint_counts"])
    if n <= STRIP_FRAMES:
        return list(range(n))
    candidates = np.linspace(0, n - 1, STRIP_FRAMES * 3).round().astype(int)
    if "moving" in d:
        starts = np.r_[0, np.cumsum(d["keypoint_counts"])]
        movers = np.array([d["moving"][starts[i] : starts[i + 1]].sum() for i in range(n)])
        with_movers = [int(i) for i in candidates if movers[i] > 0]
        if len(with_movers) >= STRIP_FRAMES:
            picks = np.linspace(0, len(with_movers) - 1, STRIP_FRAMES).round().astype(int)
            return [with_movers[p] for p in picks]
    return list(np.linspace(0, n - 1, STRIP_FRAMES).round().astype(int))


def frame_strip(view: RunView) -> bytes | None:
    """Frames with keypoints coloured by decision (top row) and by true label (bottom row), as JPEG."""
    d, sequence = view.diagnostics, view.sequence
    if d is None or sequence is None or len(d["keypoint_counts"]) != len(sequence):
        return None
    starts = np.r_[0, np.cumsum(d["keypoint_counts"])]
    names = [str(n) for n in d["rejection_names"]]
    tiles_decision, tiles_truth = [], []
    for i in _strip_frames(view):
        rgb = sequence.rgb(i)
        scale = STRIP_WIDTH_PX / rgb.shape[1]
        base = cv2.resize(rgb, (STRIP_WIDTH_PX, round(rgb.shape[0] * scale)), interpolation=cv2.INTER_AREA)
        base = (base * 0.75).astype(np.uint8)  # dimmed, so the keypoints stand out
        points = d["keypoints_px"][starts[i] : starts[i + 1]] * scale
        codes = d["rejection"][starts[i] : starts[i + 1]]
        decision, truth = base.copy(), base.copy()
        moving = d["moving"][starts[i] : starts[i + 1]] if "moving" in d else None
        for j, (u, v) in enumerate(np.rint(points).astype(int)):
            colour = DECISION_COLOURS.get(names[codes[j]], (255, 255, 255))
            cv2.circle(decision, (int(u), int(v)), 2, colour, -1, cv2.LINE_AA)
            if moving is not None:
                cv2.circle(truth, (int(u), int(v)), 2, MOVING_COLOUR if moving[j] else STATIC_COLOUR, -1)
        label = f"frame {i}  {view.states[i].lower()}"
        for tile in (decision, truth):
            cv2.putText(tile, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        tiles_decision.append(decision)
        tiles_truth.append(truth)
    rows = [np.hstack(tiles_decision)]
    if "moving" in d:
        rows.append(np.hstack(tiles_truth))
    # JPEG: rendered frames are photographs to the codec (a PNG strip weighs ~1 MB).
    ok, jpeg = cv2.imencode(".jpg", np.vstack(rows)[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 88])
    return jpeg.tobytes() if ok else None


# -- page ----------------------------------------------------------------------

STYLE = """
body{font:14px/1.45 system-ui,sans-serif;margin:0;color:#1f2937;background:#f8fafc}
header{background:#0f172a;color:#f8fafc;padding:18px 28px}header h1{margin:0;font-size:22px}
header p{margin:4px 0 0;color:#cbd5e1}main{padding:8px 28px 40px;max-width:1700px}
section{background:#fff;border:1px solid #e2e8f0;border-radius:8px;padding:14px 18px;margin:16px 0}
h2{font-size:17px;margin:0 0 10px}h3{font-size:15px;margin:14px 0 6px}
table{border-collapse:collapse;font-size:13px}
td,th{border-bottom:1px solid #e5e7eb;padding:3px 10px;text-align:right}
th{background:#f1f5f9}td:first-child,th:first-child{text-align:left}
img{max-width:100%;height:auto;border:1px solid #e2e8f0}.plots{display:flex;flex-wrap:wrap;gap:12px}
.legend span{display:inline-block;margin-right:14px}.swatch{display:inline-block;width:11px;height:11px;
border-radius:50%;margin-right:4px;vertical-align:-1px}.fail{color:#b91c1c;font-weight:600}.pass{color:#15803d}
"""


def _img(data: bytes, alt: str) -> str:
    kind = "jpeg" if data[:2] == b"\xff\xd8" else "png"
    encoded = base64.b64encode(data).decode("ascii")
    return f'<img alt="{html.escape(alt)}" src="data:image/{kind};base64,{encoded}">'


def _fmt(value: Any, digits: int = 4) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return "–" if not math.isfinite(value) else f"{value:.{digits}g}"
    return html.escape(str(value))


def percent(value: float | None) -> float | None:
    """A percentage shown to 0.01 %: rho of a run that matches its reference to the
    micrometre is 0, not 1.304e-06 (what four significant digits make of it)."""
    return None if value is None else round(value, 2)


def table(header: list[str], rows: list[list[Any]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_fmt(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _legend() -> str:
    parts = [
        f'<span><i class="swatch" style="background:rgb{colour}"></i>{name.replace("_", " ")}</span>'
        for name, colour in DECISION_COLOURS.items()
    ]
    truth = (
        f'<span><i class="swatch" style="background:rgb{MOVING_COLOUR}"></i>truly moving</span>'
        f'<span><i class="swatch" style="background:rgb{STATIC_COLOUR}"></i>static</span>'
    )
    return (
        f'<p class="legend">Top row, decision: {"".join(parts)}</p>'
        f'<p class="legend">Bottom row, truth: {truth}</p>'
    )


def difficulty_table(sequence: Sequence | None) -> str:
    difficulty = (sequence.meta or {}).get("difficulty") if sequence is not None else None
    if not isinstance(difficulty, dict) or not difficulty:
        return "<p>No difficulty recorded (not a generated sequence).</p>"
    return table(["measure", "value"], [[k.replace("_", " "), v] for k, v in sorted(difficulty.items())])


def run_section(view: RunView, heading: str) -> str:
    m = view.metrics
    ate, rpe = m.get("ate_m") or {}, m.get("rpe_translation_m") or {}
    rejection = m.get("rejection") or {}
    total = (m.get("stage_time") or {}).get("tracking_total") or {}
    summary = table(
        [
            "ATE RMSE (m)",
            "ATE max (m)",
            "RPE RMSE (m)",
            "tracked",
            "lost",
            "keyframes",
            "precision",
            "recall",
            "ms/frame",
        ],
        [
            [
                ate.get("rmse"),
                ate.get("max"),
                rpe.get("rmse"),
                f"{m.get('tracked_frames')}/{m.get('frames')}",
                m.get("lost_frames"),
                m.get("keyframes"),
                rejection.get("precision"),
                rejection.get("recall"),
                total.get("mean_ms"),
            ]
        ],
    )
    plots = [
        _img(figure_png(trajectory_figure(view)), "trajectory from above"),
        _img(figure_png(error_figure(view)), "error over time"),
    ]
    strip = frame_strip(view)
    strip_html = (
        (_legend() + _img(strip, "frames with keypoints"))
        if strip is not None
        else "<p>No frames to show.</p>"
    )
    where = html.escape(str(view.sequence.root)) if view.sequence is not None else "?"
    return (
        f"<section><h2>{html.escape(heading)}</h2><p>{html.escape(view.title)} on <code>{where}</code></p>"
        f"{summary}<div class='plots'>{''.join(plots)}</div><h3>Frames</h3>{strip_html}"
        f"<h3>Scenario difficulty</h3>{difficulty_table(view.sequence)}</section>"
    )


def page(title: str, subtitle: str, sections: list[str]) -> str:
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>{html.escape(title)}</title><style>{STYLE}</style></head><body>"
        f"<header><h1>{html.escape(title)}</h1><p>{html.escape(subtitle)}</p></header>"
        f"<main>{''.join(sections)}</main></body></html>\n"
    )


def run_page(view: RunView) -> str:
    return page(
        f"depotbench run: {view.title}", str(view.metrics.get("sequence", "")), [run_section(view, "Run")]
    )


# -- sweeps --------------------------------------------------------------------

PARETO_HEADER = ["family", "configuration", "detector", "ATE (m)", "ms"]
CONFIG_HEADER = [
    "family",
    "strategy",
    "settings",
    "detector",
    "ATE (m)",
    "ρ (%)",
    "precision",
    "recall",
    "ms",
]


def _featured_runs(folder: Path, rows: list[dict[str, Any]], best: dict[str, dict]) -> list[RunView]:
    """Each family's best configuration, and its none run, tracked again from the cache."""
    from eval.cache import StageCache
    from eval.harness import track
    from eval.store import ResultStore
    from eval.sweep import jobs_for
    from eval.sweep_spec import SweepSpec, detector_configs, tracker_configs, variants

    with ResultStore(folder / "results.sqlite") as store:
        stored = store.meta("spec")
    if stored is None:
        return []
    spec = SweepSpec.model_validate_json(stored)
    source = str(folder / "results.sqlite")
    trackers, detectors, found = tracker_configs(spec, source), detector_configs(spec, source), variants(spec)
    views = []
    for family, config in sorted(best.items()):
        settings = json.dumps(config["settings"], sort_keys=True)
        chosen = next(
            (
                r
                for r in rows
                if r["family"] == family
                and r["strategy"] == config["strategy"]
                and r["detector"] == config["detector"]
                and r["tracker"] == config["tracker"]
                and json.dumps(json.loads(r["settings"]), sort_keys=True) == settings
            ),
            None,
        )
        if chosen is None or not Path(chosen["sequence"]).is_dir():
            continue
        jobs = {j.key: j for j in jobs_for(found, trackers, detectors, [(Path(chosen["sequence"]), family)])}
        wanted = [chosen["key"]]
        baseline = next(
            (
                r["key"]
                for r in rows
                if r["sequence"] == chosen["sequence"]
                and r["strategy"] == "none"
                and r["detector"] == chosen["detector"]
                and r["tracker"] == chosen["tracker"]
            ),
            None,
        )
        if baseline is not None and baseline != chosen["key"]:
            wanted.append(baseline)
        for key in wanted:
            job = jobs.get(key)
            if job is None:
                continue  # e.g. a search trial's settings: not in the spec's grid
            tracked = track(job.job, StageCache.from_env())
            label = "best" if key == chosen["key"] else "baseline (none)"
            shown = settings_text(config["settings"]) if label == "best" else ""
            views.append(
                view_of(
                    f"{family}: {label} — {job.job.tracker.kind.value} · {job.job.strategy} {shown} · "
                    f"{job.job.detector.label}",
                    tracked,
                )
            )
    return views


def sweep_page(folder: Path, featured: int = 3) -> str:
    from eval.store import ResultStore

    summary_path = folder / "summary.json"
    try:
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{summary_path}: cannot read the sweep's summary ({exc})") from None
    with ResultStore(folder / "results.sqlite") as store:
        rows = with_rho(store.rows())
    configs = summary["configurations"]
    best = summary["best"]
    sections = []
    best_rows = [
        [
            family,
            f"{c['strategy']} " + settings_text(c["settings"]),
            c["detector"],
            c["sequences"],
            c["ate_rmse_m"],
            percent(c["rho_percent"]),
            c["rejection_precision"],
            c["rejection_recall"],
            c["tracked_fraction"],
            c["track_ms_median"],
        ]
        for family, c in sorted(best.items())
    ]
    header = [
        "family",
        "configuration",
        "detector",
        "seqs",
        "ATE (m)",
        "ρ (%)",
        "precision",
        "recall",
        "tracked",
        "ms",
    ]
    sections.append(f"<section><h2>Best configuration per family</h2>{table(header, best_rows)}</section>")
    plots = [_img(figure_png(fig), name) for name, fig in threshold_figures(configs)]
    if plots:
        sections.append(f"<section><h2>Against each swept threshold</h2>{''.join(plots)}</section>")
    front = pareto_figure(configs)
    if front is not None:
        pareto_rows = [
            [
                c["family"],
                f"{c['strategy']} " + settings_text(c["settings"]),
                c["detector"],
                c["ate_rmse_m"],
                c["track_ms_median"],
            ]
            for c in summary["pareto"]
        ]
        sections.append(
            f"<section><h2>Accuracy against time</h2>{_img(figure_png(front), 'Pareto plot')}"
            f"<h3>Pareto set</h3>{table(PARETO_HEADER, pareto_rows)}</section>"
        )
    difficulty = _difficulty_rows(rows)
    if difficulty:
        sections.append(f"<section><h2>Scenario difficulty</h2>{difficulty}</section>")
    for view in _featured_runs(folder, rows, dict(sorted(best.items())[:featured])):
        sections.append(run_section(view, view.title))
    all_rows = [
        [
            c["family"],
            c["strategy"],
            settings_text(c["settings"]),
            c["detector"],
            c["ate_rmse_m"],
            percent(c["rho_percent"]),
            c["rejection_precision"],
            c["rejection_recall"],
            c["track_ms_median"],
        ]
        for c in configs
    ]
    sections.append(
        "<section><h2>Every configuration (means over each family's sequences)</h2>"
        f"{table(CONFIG_HEADER, all_rows)}"
        "</section>"
    )
    subtitle = (
        f"{len(rows)} runs, {len(configs)} configurations over {len({r['sequence'] for r in rows})} sequences"
    )
    return page(f"depotbench sweep: {folder.name}", subtitle, sections)


def _difficulty_rows(rows: list[dict[str, Any]]) -> str:
    table_rows, columns = [], []
    for sequence in sorted({r["sequence"] for r in rows}):
        opened = _open_sequence(sequence)
        difficulty = (opened.meta or {}).get("difficulty") if opened is not None else None
        if not isinstance(difficulty, dict):
            continue
        columns = columns or sorted(difficulty)
        table_rows.append([Path(sequence).name, *[difficulty.get(c) for c in columns]])
    return table(["sequence", *[c.replace("_", " ") for c in columns]], table_rows) if table_rows else ""


def render_report(source: Path) -> str:
    """The page for a run folder or a sweep folder."""
    if (source / "results.sqlite").is_file() and (source / "summary.json").is_file():
        return sweep_page(source)
    if (source / "metrics.json").is_file():
        return run_page(load_run(source))
    raise InputError(f"{source}: neither a run folder (metrics.json) nor a sweep folder (results.sqlite)")


def write_report(source: Path, out: Path) -> Path:
    """The page written atomically as OUT/index.html (OUT: a folder the caller owns)."""
    from sim.output import write_text_atomic

    text = render_report(source)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "index.html"
    write_text_atomic(path, text)
    return path
