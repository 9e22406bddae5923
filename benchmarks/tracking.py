"""Tracking time per frame and per stage, the built-in pipeline beside ORB-SLAM3.

Usage: python benchmarks/tracking.py [--scenario walking_xyz] [--frames 150] [--seed 11 ...]
       [--sequences PATH ...] [--strategy none ...] [--kernels numpy|numba|both] [--set NAME=VALUE ...]
       [--variant NAME=VALUE[,NAME=VALUE] ...] [--vocabulary FILE] [--orbslam3-pace P ...]
       [--orbslam3-runs N] [--no-orbslam3]

Generates the scenario once per seed (into a temporary folder), or opens each sequence of
``--sequences`` (a sequence folder, or a folder of them: a benchmark's or a suite's), then, on
that sequence in this run: the built-in pipeline with each strategy pinned to one core (tracking as ORB-SLAM
reports it: extraction + rejection + tracking; local mapping runs synchronously and is
reported apart), and ORB-SLAM3 (if the orbslam3 extra is installed) with its local-mapping
thread on the other core, as it is built to run: its time is that of ``track_rgbd``, and its
tracked frames are printed beside it. ORB-SLAM3 is fed at the camera's rate (``pace`` 1), as
its own ``rgbd_tum`` example feeds a sequence and times ``TrackRGBD``: fed back to back
(``--orbslam3-pace 0``), its mapping thread competes with tracking for the cores. Several
paces run one after the other on the same sequence. ORB-SLAM3 is not deterministic (its
keyframes and its mapping's cost vary from run to run), so ``--orbslam3-runs N`` runs it N
times at each pace and sets the median of its runs (per-frame times pooled; CPU, wall and
keyframes the median run's figure each, the runs' range of CPU and keyframes printed beside it)
beside the built-in. Mean and median milliseconds per frame;
per seed and over the seeds, each strategy's median over ORB-SLAM3's (issue 40's speed
criterion), for each pace.

Per-frame medians leave out what runs between frames, so each run also reports the whole
sequence's cost: CPU seconds (user + system, every thread) and wall seconds. The built-in's
are its process's over ``BuiltinTracker.run`` (``time.process_time``: tracking and its
synchronous mapping; it runs on one core, so its CPU cannot exceed its wall time), and its
per-frame column ``track+map`` adds mapping to tracking. ORB-SLAM3's are its worker process's
(``os.wait4``: tracking, the local-mapping thread and the rest) less its start-up, measured
alone in a fresh worker (interpreter, imports, vocabulary, ``Shutdown``): what a sequence
adds. Per seed, built-in / ORB-SLAM3 of tracking and track+map medians (ORB-SLAM3's
``track_rgbd``: its mapping is in another thread), CPU and wall, and the keyframes each
system's map holds at the end (ORB-SLAM3: its saved keyframe trajectory, after its culling);
over the seeds, each ratio's median and range. Each run's ATE RMSE against the sequence's
ground truth is printed beside its cost, and per seed at the end: a cheaper run that tracks
worse is no saving. ``--variant mapper_time_scale=1`` also runs each strategy with those
settings, in the same run (here: local mapping on ORB-SLAM3's thread's virtual clock,
``depotbench.slam.mapping_clock``).

``--kernels both`` tracks each strategy on the NumPy reference path and on the compiled
kernels (``DEPOTBENCH_KERNELS``, ``depotbench.slam.kernels``) in the order numpy, numba,
numba, numpy, so that a machine whose load drifts charges both alike; each path's figures
are over its two runs' frames, and a ratio row divides NumPy's median by Numba's. It first
measures what the kernels cost a process before its first frame: compiling them into an
empty cache, and loading them from that cache, each in a fresh interpreter. Every timed run
starts with the kernels loaded (``kernels.warm_up``).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

# depotbench first: numpy then runs the bench's code for the CPU (core/numerics.py)
import depotbench  # isort: skip  # noqa: E402, F401
import cv2  # noqa: E402
import numpy as np  # noqa: E402
from depotbench.core.errors import InputError  # noqa: E402
from depotbench.core.parameters import parameter_text  # noqa: E402
from depotbench.detectors.config import DetectorConfig  # noqa: E402
from depotbench.eval.metrics.evaluate import ComparisonOptions, compare  # noqa: E402
from depotbench.eval.metrics.trajectory import read_tum  # noqa: E402
from depotbench.eval.run.detections import detect_sequence  # noqa: E402
from depotbench.eval.trackers.base import TrackerRun  # noqa: E402
from depotbench.eval.trackers.builtin import STAGES, BuiltinTracker  # noqa: E402
from depotbench.eval.trackers.frames import FrameSource  # noqa: E402
from depotbench.eval.trackers.orbslam3 import PACE, orbslam_settings, pace_of  # noqa: E402
from depotbench.eval.trackers.registry import tracker_parameters  # noqa: E402
from depotbench.scenes import library  # noqa: E402
from depotbench.scenes.schema import to_scenario  # noqa: E402
from depotbench.sim.camera import orbslam_yaml  # noqa: E402
from depotbench.sim.generate import generate  # noqa: E402
from depotbench.sim.sequence import Sequence  # noqa: E402
from depotbench.slam import kernels  # noqa: E402
from depotbench.slam.config import ConfigError, SlamConfig, parse_settings  # noqa: E402
from depotbench.slam.kernels import Kernels  # noqa: E402
from depotbench.slam.rejection import STRATEGIES  # noqa: E402
from depotbench.slam.types import TrackingState  # noqa: E402

TRACKED = (TrackingState.OK, TrackingState.RELOCALIZED)
"""States of a tracked frame: ORB-SLAM3's tracked count is printed, since a lost run looks fast."""
ORDER = (Kernels.NUMPY, Kernels.NUMBA, Kernels.NUMBA, Kernels.NUMPY)
"""--kernels both: each path twice, mirrored, so that a linear drift in load cancels."""

_WARM_UP = (
    "import time; started = time.perf_counter(); import numba; imported = time.perf_counter()\n"
    "from depotbench.slam import kernels\n"
    "print(imported - started, kernels.warm_up())\n"
)


RATIOS = ("tracking", "track+map", "cpu", "wall", "keyframes")
"""Built-in / ORB-SLAM3: median ms per frame (ORB-SLAM3's ``track_rgbd`` for both), the
whole sequence's CPU and wall seconds, and the keyframes of the final map."""
COLUMNS = (*STAGES, "track+map")

_STARTUP = (
    "import sys, json, numpy, pyorbslam3\n"
    "from depotbench.core.processes import exit_with_parent\n"
    "from depotbench.sim.sequence import Sequence\n"
    "slam = pyorbslam3.Slam(sys.argv[1], sys.argv[2], pyorbslam3.Sensor.RGBD, use_viewer=False)\n"
    "slam.shutdown()\n"
)
"""What ORB-SLAM3's worker does before its first frame and after its last, with no frame."""


@dataclass(frozen=True)
class Cost:
    """One run: per-frame milliseconds and the whole sequence's CPU and wall seconds."""

    tracking_ms: np.ndarray
    track_map_ms: np.ndarray
    cpu_s: float
    wall_s: float
    keyframes: int | None
    ate_mm: float | None = None
    """ATE RMSE against the sequence's ground truth (SE(3)-aligned, as ``depotbench eval``)."""


def _cell(values: np.ndarray) -> str:
    return f"{values.mean():11.2f} /{np.median(values):10.2f}"


def _seconds(cpu_s: float, wall_s: float, keyframes: int | None = None, ate_mm: float | None = None) -> str:
    kf = "" if keyframes is None else f"  keyframes {keyframes:4d}"
    ate = "" if ate_mm is None else f"  ATE {ate_mm:7.1f} mm"
    return f"   cpu {cpu_s:8.3f} s  wall {wall_s:8.3f} s{kf}{ate}"


def _ate_mm(seq: Sequence, run: TrackerRun) -> float | None:
    """The run's ATE RMSE in mm against the sequence's ground truth (None: no ground truth, or
    no frame tracked)."""
    estimate = run.trajectory()
    truth = seq.root / "groundtruth.txt"
    if estimate is None or not truth.is_file():
        return None
    return 1e3 * compare(read_tum(truth), estimate, ComparisonOptions()).ate.statistics.rmse


def _spread(values: list[float]) -> str:
    """Median over the seeds, then their range: few seeds, so no quantiles."""
    return f"{float(np.median(values)):.2f}x [{min(values):.2f}-{max(values):.2f}]"


def _compile_cost() -> str:
    """Numba's import, then all kernels compiled into an empty cache, then loaded from it: each
    in a fresh interpreter, as a sweep's worker process meets them."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        seconds = []
        for _ in ("compile", "load"):
            result = subprocess.run(
                [sys.executable, "-c", _WARM_UP], env=env, capture_output=True, text=True, check=True
            )
            seconds.append([float(x) for x in result.stdout.split()])
    (import_s, compile_s), (_, load_s) = seconds
    return (
        f"kernels before the first frame: import numba {import_s:.2f} s, "
        f"compile all {compile_s:.2f} s (empty cache), load all {load_s:.2f} s (from the cache)"
    )


def _run(
    seq: Sequence, frames: FrameSource, config: SlamConfig, path: Kernels | None
) -> tuple[dict[str, np.ndarray], float, float, int | None, float | None]:
    """Per-frame stage times, then the run's CPU and wall seconds, mapping included, the
    keyframes of its final map and its ATE RMSE (mm)."""
    with kernels.using(path) if path is not None else contextlib.nullcontext():
        cpu, wall = time.process_time(), time.perf_counter()
        run = BuiltinTracker(config).run(frames, False)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    stage_ms = run.stage_ms
    track_map = stage_ms["tracking_total"] + stage_ms["mapping"]
    return {**stage_ms, "track+map": track_map}, cpu, wall, run.keyframes, _ate_mm(seq, run)


@contextlib.contextmanager
def _sequence(args: argparse.Namespace, seed: int | None, stored: Path | None):
    """The sequence to time: a stored one opened where it is, or the scenario generated for
    ``seed`` into a temporary folder."""
    if stored is not None:
        yield Sequence.open(stored)
        return
    with tempfile.TemporaryDirectory() as tmp:
        update = {"frames": args.frames, "duration_s": None}
        if seed is not None:
            update["seed"] = seed
        scenario = library.get(args.scenario).model_copy(update=update)
        yield Sequence.open(generate(to_scenario(scenario), Path(tmp) / "seq", progress=False))


def _stored(paths: list[Path], parser: argparse.ArgumentParser) -> list[Path]:
    """Sequence folders (with meta.json) given or held one level down, in name order; a
    folder with none is refused as any bad argument is (``parser.error``: its line names
    the script and the folder, exit 2)."""
    found = []
    for path in paths:
        if (path / "meta.json").is_file():
            found.append(path)
            continue
        inside = sorted(p.parent for p in path.glob("*/meta.json"))
        if not inside:
            parser.error(f"--sequences {path}: no meta.json there or one level down")
        found += inside
    return found


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenario", default="walking_xyz")
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--seed", type=int, nargs="+", help="scenario seeds (default: the library's)")
    parser.add_argument(
        "--sequences",
        type=Path,
        nargs="+",
        help="stored sequences instead of --scenario/--seed/--frames: sequence folders or folders of them",
    )
    parser.add_argument(
        "--strategy", action="append", choices=STRATEGIES, help="a built-in strategy (default: every one)"
    )
    parser.add_argument(
        "--kernels",
        choices=("numpy", "numba", "both"),
        help="the built-in's hot paths: NumPy, compiled, or both side by side (default: DEPOTBENCH_KERNELS)",
    )
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a SLAM setting")
    parser.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="NAME=VALUE[,NAME=VALUE]",
        help="also run each strategy with these settings on top of --set, in the same run "
        "(e.g. mapper_time_scale=1); repeat for more",
    )
    parser.add_argument("--vocabulary", type=Path, help="ORB-SLAM3's vocabulary (default: the bench's)")
    parser.add_argument(
        "--orbslam3-pace",
        type=float,
        nargs="+",
        default=[1.0],
        metavar="P",
        help="how ORB-SLAM3 is fed: P x the frames' gaps (1: the camera's rate, 0: back to back); "
        "several run one after the other (default: 1)",
    )
    parser.add_argument(
        "--orbslam3-runs", type=int, default=1, metavar="N", help="ORB-SLAM3 runs a pace; their median counts"
    )
    parser.add_argument("--no-orbslam3", action="store_true", help="the built-in pipeline only")
    args = parser.parse_args()
    if args.orbslam3_runs < 1:
        parser.error(f"--orbslam3-runs: at least 1, got {args.orbslam3_runs}")
    if args.sequences and args.seed:
        parser.error("--sequences and --seed: give one")
    stored: list[Path | None] = [None] * len(args.seed or [None])
    if args.sequences:
        stored = list(_stored(args.sequences, parser))
    try:
        settings = parse_settings(args.set)
        variants = [("", settings)] + [
            (text, settings | parse_settings(text.split(","))) for text in args.variant
        ]
    except ConfigError as exc:
        parser.error(f"--set/--variant: {exc}")
    for pace in args.orbslam3_pace:
        try:  # checked as the tracker checks its pace parameter
            pace_of(((PACE, parameter_text(pace)),))
        except InputError as exc:
            parser.error(f"--orbslam3-pace: {exc}")
    paths: tuple[Kernels | None, ...] = (None,)
    if args.kernels == "both":
        paths = ORDER
    elif args.kernels:
        paths = (Kernels(args.kernels),)
    strategies = args.strategy or list(STRATEGIES)
    cv2.setNumThreads(1)
    if Kernels.NUMBA in paths or (paths == (None,) and kernels.compiled()):
        if args.kernels == "both":
            print(_compile_cost())
        kernels.warm_up()
    every_core = os.sched_getaffinity(0)
    runs_of = [(f"{s} {text}".strip(), s, chosen) for s in strategies for text, chosen in variants]
    ratios: dict[str, list[float]] = {label: [] for label, _, _ in runs_of}
    to_orbslam3: dict[tuple[str, float], dict[str, list[float]]] = {}
    accuracy: dict[str, list[float | None]] = {}
    """ATE RMSE (mm) by system, one per sequence."""
    startup: dict[str, tuple[float, float]] = {}
    seeds: list[int | None] = list(args.seed or [None] * len(stored))
    for seed, path in zip(seeds, stored, strict=True):
        with _sequence(args, seed, path) as seq:
            frames = FrameSource(seq, detect_sequence(seq, DetectorConfig()).per_frame)
            meta = seq.meta or {}
            name = meta.get("scenario", {}).get("name", args.scenario if path is None else path.name)
            print(
                f"{name} (seed {meta.get('seed', '-')}), {len(seq)} frames, 640x480, 1000 ORB features; "
                f"built-in on core {min(every_core)}, cv2 threads {cv2.getNumThreads()}"
            )
            print(
                f"{'tracker / strategy':32s} "
                + " ".join(f"{s + ' mean/med ms':>24s}" for s in COLUMNS)
                + "   whole sequence"
            )
            os.sched_setaffinity(0, {min(every_core)})
            builtin: dict[str, Cost] = {}
            for strategy, base, chosen in runs_of:  # strategy: the row's label
                config = SlamConfig(strategy=base).with_settings(chosen)
                runs: dict[Kernels | None, list] = {}
                for path in paths:
                    runs.setdefault(path, []).append(_run(seq, frames, config, path))
                medians = {}
                for path, path_runs in runs.items():
                    stages = {s: np.concatenate([r[0][s] for r in path_runs]) for s in COLUMNS}
                    cpu_s = float(np.mean([r[1] for r in path_runs]))  # one run's, as ORB-SLAM3's
                    wall_s = float(np.mean([r[2] for r in path_runs]))
                    medians[path] = {s: float(np.median(v)) for s, v in stages.items()}
                    label = f"builtin {strategy}" + (f" [{path.value}]" if path else "")
                    print(
                        f"{label:32s} "
                        + " ".join(f"{_cell(stages[s]):>24s}" for s in COLUMNS)
                        + _seconds(cpu_s, wall_s, path_runs[0][3], path_runs[0][4])
                    )
                    if path == paths[0]:
                        accuracy.setdefault(f"builtin {strategy}", []).append(path_runs[0][4])
                        builtin[strategy] = Cost(
                            stages["tracking_total"],
                            stages["track+map"],
                            cpu_s,
                            wall_s,
                            path_runs[0][3],
                            path_runs[0][4],
                        )
                if len(runs) == 2:
                    ratio = {s: medians[Kernels.NUMPY][s] / medians[Kernels.NUMBA][s] for s in COLUMNS}
                    ratios[strategy].append(ratio["tracking_total"])
                    print(
                        f"{'  numpy / numba, medians':32s} "
                        + " ".join(f"{ratio[s]:>23.2f}x" for s in COLUMNS)
                    )
            os.sched_setaffinity(0, every_core)
            for pace in () if args.no_orbslam3 else args.orbslam3_pace:
                runs = [_orbslam3(args, seq, pace, startup) for _ in range(args.orbslam3_runs)]
                if runs[0] is None:
                    break
                measured = [run for run in runs if run is not None]
                orbslam3 = _median_cost(measured)
                accuracy.setdefault(f"orbslam3 pace {pace:g}", []).append(orbslam3.ate_mm)
                if len(runs) > 1:
                    print(
                        f"{f'orbslam3 none pace {pace:g}, median':32s} "
                        + " ".join(f"{'':>24s}" for _ in ("extract", "reject", "track"))
                        + f" {_cell(orbslam3.tracking_ms):>24s} {'':>24s} {_cell(orbslam3.tracking_ms):>24s}"
                        + _seconds(orbslam3.cpu_s, orbslam3.wall_s, orbslam3.keyframes, orbslam3.ate_mm)
                        + _spread_of_runs(measured)
                    )
                for strategy, cost in builtin.items():
                    ratio = _ratios(cost, orbslam3)
                    for name, value in ratio.items():
                        to_orbslam3.setdefault((strategy, pace), {}).setdefault(name, []).append(value)
                    print(
                        f"{f'  built-in / orbslam3 pace {pace:g}':32s} {strategy}: "
                        + ", ".join(f"{name} {value:.2f}x" for name, value in ratio.items())
                    )
    if args.kernels == "both":
        print("numpy / numba, median tracking_total per frame, by seed:")
        for strategy, values in ratios.items():
            print(f"  {strategy:20s} " + " ".join(f"{v:.2f}x" for v in values))
    if to_orbslam3:
        print("built-in / orbslam3 by seed; median [range] over seeds:")
        for (strategy, pace), by_name in to_orbslam3.items():
            for name, values in by_name.items():
                line = " ".join(f"{v:.2f}x" for v in values)
                print(f"  {strategy:20s} pace {pace:<4g} {name:10s} {line}; {_spread(values)}")
    if any(value is not None for values in accuracy.values() for value in values):
        print("ATE RMSE mm by seed (ORB-SLAM3: its median run); median [range] over seeds:")
        for system, values in accuracy.items():
            line = " ".join("-" if v is None else f"{v:.1f}" for v in values)
            known = [v for v in values if v is not None]
            spread = f"{np.median(known):.1f} [{min(known):.1f}-{max(known):.1f}]" if known else "-"
            print(f"  {system:40s} {line}; {spread}")
    print(
        "built-in: tracking_total = extract + reject + track; track+map adds the synchronous mapping; "
        "cpu and wall: the whole run, mapping included"
    )
    print(
        "orbslam3: track_rgbd per frame (extraction and tracking; mapping in its own thread); "
        "cpu and wall: its worker process, every thread, less its start-up"
    )


def _median_cost(runs: list[Cost]) -> Cost:
    """Several runs of one system as one: every frame's time pooled, and the median run's CPU,
    wall and keyframes each (the lower middle of an even count, a figure that was measured)."""

    def middle(values: list[float]) -> float:
        return sorted(values)[(len(values) - 1) // 2]

    keyframes = [run.keyframes for run in runs if run.keyframes is not None]
    ates = [run.ate_mm for run in runs if run.ate_mm is not None]
    return Cost(
        np.concatenate([run.tracking_ms for run in runs]),
        np.concatenate([run.track_map_ms for run in runs]),
        middle([run.cpu_s for run in runs]),
        middle([run.wall_s for run in runs]),
        int(middle(keyframes)) if keyframes else None,
        middle(ates) if ates else None,
    )


def _spread_of_runs(runs: list[Cost]) -> str:
    """The runs' range of CPU and keyframes, beside their median: ORB-SLAM3's keyframes on one
    walking_static sequence ranged 35-275 over seven runs, so a median of two says little."""
    cpu = [run.cpu_s for run in runs]
    text = f"   {len(runs)} runs: cpu {min(cpu):.3f}-{max(cpu):.3f} s"
    keyframes = [run.keyframes for run in runs if run.keyframes is not None]
    return text + (f", keyframes {min(keyframes)}-{max(keyframes)}" if keyframes else "")


def _ratios(builtin: Cost, orbslam3: Cost) -> dict[str, float]:
    """Built-in over ORB-SLAM3, by RATIOS: ORB-SLAM3 has one per-frame figure, track_rgbd."""
    values = (
        np.median(builtin.tracking_ms) / np.median(orbslam3.tracking_ms),
        np.median(builtin.track_map_ms) / np.median(orbslam3.track_map_ms),
        builtin.cpu_s / orbslam3.cpu_s if orbslam3.cpu_s > 0 else float("nan"),
        builtin.wall_s / orbslam3.wall_s if orbslam3.wall_s > 0 else float("nan"),
        builtin.keyframes / orbslam3.keyframes if builtin.keyframes and orbslam3.keyframes else float("nan"),
    )
    return dict(zip(RATIOS, (float(v) for v in values), strict=True))


def _startup(vocabulary: Path, seq: Sequence) -> tuple[float, float]:
    """CPU and wall seconds of ORB-SLAM3's worker with no frame (``_STARTUP``), each the
    median of three fresh processes timed as the worker is (``os.wait4``): one varies by
    about 0.2 s on this machine, as much as 60 frames' tracking differs."""
    cpu_s, wall_s = zip(*(_startup_once(vocabulary, seq) for _ in range(3)), strict=True)
    return float(np.median(cpu_s)), float(np.median(wall_s))


def _startup_once(vocabulary: Path, seq: Sequence) -> tuple[float, float]:
    with tempfile.TemporaryDirectory() as tmp:
        settings, log = Path(tmp) / "settings.yaml", Path(tmp) / "stderr.txt"
        settings.write_text(orbslam_yaml(seq.intrinsics, orbslam_settings(seq.fps, ())), encoding="utf-8")
        with log.open("wb") as stderr:  # a file, not a pipe: wait4 reads no pipe while it waits
            started = time.perf_counter()
            child = subprocess.Popen(
                [sys.executable, "-c", _STARTUP, str(vocabulary.resolve()), str(settings)],
                cwd=tmp,
                stdout=subprocess.DEVNULL,
                stderr=stderr,
            )
            _, status, usage = os.wait4(child.pid, 0)
            wall_s = time.perf_counter() - started
            child.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
        if child.returncode != 0:
            error = log.read_text(errors="replace").strip().splitlines() or ["no message"]
            raise SystemExit(f"tracking.py: ORB-SLAM3's start-up alone failed: {error[-1]}")
    return usage.ru_utime + usage.ru_stime, wall_s


def _orbslam3(
    args: argparse.Namespace, seq: Sequence, pace: float, startup: dict[str, tuple[float, float]]
) -> Cost | None:
    """ORB-SLAM3's run fed at ``pace`` (None where it is not installed), its start-up taken off
    its whole CPU and wall time (measured once per vocabulary, in ``startup``). Its tracked
    frames are printed beside it: a run that got lost tracks nothing and looks fast."""
    from depotbench.eval.trackers.orbslam3 import Orbslam3Tracker, available

    if not available():
        print("orbslam3: not installed (pip install 'depotbench[orbslam3]')")
        return None
    from depotbench.eval.trackers.vocabulary import default_vocabulary

    vocabulary = args.vocabulary or default_vocabulary()
    if str(vocabulary) not in startup:
        startup[str(vocabulary)] = _startup(vocabulary, seq)
        cpu_s, wall_s = startup[str(vocabulary)]
        blank = " ".join(f"{'':>24s}" for _ in COLUMNS)
        print(f"{'orbslam3 start-up, no frame':32s} {blank}{_seconds(cpu_s, wall_s)}")
    startup_cpu_s, startup_wall_s = startup[str(vocabulary)]
    parameters = tracker_parameters("orbslam3", {PACE: str(pace)})
    run = Orbslam3Tracker(vocabulary, parameters=parameters).run(FrameSource(seq), progress=False)
    if run.cpu_s is None:
        raise SystemExit("tracking.py: this system has no os.wait4, so ORB-SLAM3's CPU time is unknown")
    tracked = sum(state in TRACKED for state in run.states)
    cost = Cost(
        run.track_ms,
        run.track_ms,
        max(run.cpu_s - startup_cpu_s, 0.0),
        max(run.total_s - startup_wall_s, 0.0),
        run.keyframes,
        _ate_mm(seq, run),
    )
    blank = " ".join(f"{'':>24s}" for _ in ("extract", "reject", "track"))
    print(
        f"{f'orbslam3 none pace {pace:g}':32s} {blank} {_cell(run.track_ms):>24s} {'':>24s} "
        f"{_cell(run.track_ms):>24s}{_seconds(cost.cpu_s, cost.wall_s, cost.keyframes, cost.ate_mm)}"
        f"   tracked {tracked}/{len(run.states)} frames; whole process cpu {run.cpu_s:.3f} s, "
        f"wall {run.total_s:.3f} s"
    )
    return cost


if __name__ == "__main__":
    main()
