"""The built-in SLAM beside the real ORB-SLAM3 on the TUM analogs, over seeds.

Usage: python benchmarks/fidelity.py [-o OUT] [--scenes ...] [--seeds 1 2 3] [--frames 200]
       [--orbslam3-runs 2] [--workers 2] [--vocabulary FILE]

For each scene and seed: the sequence is generated (kept in OUT/sequences, reused by
content), then tracked by the built-in pipeline with every strategy and ``mask`` (true
boxes), and by ORB-SLAM3 without rejection and with ``mask``, each ORB-SLAM3 setting
``--orbslam3-runs`` times (it is not deterministic). Prints, per scene and seed, ATE
RMSE, the tracked fraction and the median tracking time; then per scene the medians
over seeds and runs, the built-in/ORB-SLAM3 ratio of ``none``, and each strategy's rho
with its rejection precision and recall. Results stay in OUT/runs; a JSON summary in
OUT/fidelity.json.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

SCENES = (
    "walking_static",
    "walking_xyz",
    "walking_rpy",
    "walking_halfsphere",
    "sitting_static",
    "static_depot",
)
BUILTIN = ("none", "box_rule", "prior_flow", "box_epipolar_flow", "mask")


def _worker_init() -> None:
    os.environ["OMP_NUM_THREADS"] = "1"
    import cv2

    cv2.setNumThreads(1)


def _run(job: tuple[str, str, str, int, str, str | None]) -> tuple[str, str, str, int, dict]:
    sequence, tracker, strategy, repeat, out, vocabulary = job
    from depotbench.eval.run.harness import run_sequence
    from depotbench.eval.trackers.registry import TrackerConfig

    config = TrackerConfig(tracker, vocabulary=Path(vocabulary) if vocabulary else None)
    target = Path(out) / Path(sequence).name / f"{tracker}-{strategy}-{repeat}"
    metrics = run_sequence(Path(sequence), target, strategy, progress=False, overwrite=True, tracker=config)
    return Path(sequence).name, tracker, strategy, repeat, metrics


def _median(values: list[float]) -> float:
    finite = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.median(finite)) if finite else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("-o", "--output", type=Path, help="keep sequences and runs here (default: temporary)")
    parser.add_argument("--scenes", nargs="+", default=list(SCENES))
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--orbslam3-runs", type=int, default=2)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--vocabulary", type=Path)
    args = parser.parse_args()

    from depotbench.eval.trackers.orbslam3 import available
    from depotbench.eval.trackers.vocabulary import default_vocabulary
    from depotbench.scenes.generation import run_suite
    from depotbench.scenes.suite import Suite

    with tempfile.TemporaryDirectory() as tmp:
        out = args.output or Path(tmp)
        sequences = []
        for scene in args.scenes:
            suite = Suite(
                suite=scene,
                base=scene,
                overrides={"frames": args.frames, "duration_s": None},
                seeds=args.seeds,
            )
            index = run_suite(suite, Path(tmp) / "suite.yaml", out / "sequences", args.workers)
            sequences += [(scene, e["seed"], out / "sequences" / e["name"]) for e in index["sequences"]]
        orbslam3 = available()
        vocabulary = str(args.vocabulary or default_vocabulary()) if orbslam3 else None
        jobs = [(str(p), "builtin", s, 0, str(out / "runs"), None) for _, _, p in sequences for s in BUILTIN]
        if orbslam3:
            jobs += [
                (str(p), "orbslam3", s, r, str(out / "runs"), vocabulary)
                for _, _, p in sequences
                for s in ("none", "mask")
                for r in range(args.orbslam3_runs)
            ]
        else:
            print("orbslam3: not installed (pip install 'depotbench[orbslam3]'); built-in only")
        with ProcessPoolExecutor(
            args.workers, mp_context=get_context("spawn"), initializer=_worker_init
        ) as pool:
            results = list(pool.map(_run, jobs))
        table: dict[str, dict[tuple[str, str], list[dict]]] = {}
        for name, tracker, strategy, _, metrics in results:
            table.setdefault(name, {}).setdefault((tracker, strategy), []).append(metrics)
        _report(sequences, table, out)


def _ate(m: dict) -> float:
    return m.get("ate_m", {}).get("rmse", float("nan"))


def _report(sequences: list, table: dict, out: Path) -> None:
    columns = [("builtin", s) for s in BUILTIN] + [("orbslam3", "none"), ("orbslam3", "mask")]
    header = f"{'scene':20s}{'seed':>5s}" + "".join(f"{t[:3] + ' ' + s:>21s}" for t, s in columns)
    print("\nATE RMSE mm (tracked %, median track ms); ORB-SLAM3 columns: its runs, ' / '-joined")
    print(header)
    for scene, seed, path in sequences:
        cells = []
        for key in columns:
            runs = table[path.name].get(key, [])
            if not runs:
                cells.append(f"{'-':>21s}")
                continue
            ates = " / ".join(f"{_ate(m) * 1000:.1f}" for m in runs)
            tracked = min(m["tracked_frames"] / m["frames"] for m in runs) * 100
            cells.append(f"{ates + f' ({tracked:.0f}%)':>21s}")
        print(f"{scene:20s}{seed:5d}" + "".join(cells))
    print("\nper scene, medians over seeds (and ORB-SLAM3 runs)")
    print(
        f"{'scene':20s}{'orb none':>10s}{'orb mask':>10s}{'bi none':>10s}{'bi/orb':>8s}"
        + "".join(f"{'rho ' + s:>22s}" for s in BUILTIN[1:])
        + f"{'bi ms':>8s}{'orb ms':>8s}"
    )
    summary = {}
    for scene in dict.fromkeys(s for s, _, _ in sequences):
        names = [p.name for s, _, p in sequences if s == scene]

        def runs(key: tuple[str, str], names: list[str] = names) -> list[dict]:
            return [m for n in names for m in table[n].get(key, [])]

        orb_none = _median([_ate(m) for m in runs(("orbslam3", "none"))])
        orb_mask = _median([_ate(m) for m in runs(("orbslam3", "mask"))])
        bi_none = _median([_ate(m) for m in runs(("builtin", "none"))])
        cells, rhos = [], {}
        for strategy in BUILTIN[1:]:
            per_seed = []
            for n in names:
                base, mine = table[n][("builtin", "none")][0], table[n][("builtin", strategy)][0]
                per_seed.append((_ate(base) - _ate(mine)) / _ate(base) * 100)
            rejection = [m.get("rejection") or {} for m in runs(("builtin", strategy))]
            precision = _median([r.get("precision") for r in rejection])
            recall = _median([r.get("recall") for r in rejection])
            rhos[strategy] = {"rho_percent": _median(per_seed), "precision": precision, "recall": recall}
            cells.append(f"{_median(per_seed):8.1f}% p{precision:.2f} r{recall:.2f}")
        bi_ms = _median([m["stage_time"]["tracking_total"]["median_ms"] for m in runs(("builtin", "none"))])
        orb_ms = _median([m["stage_time"]["tracking_total"]["median_ms"] for m in runs(("orbslam3", "none"))])
        print(
            f"{scene:20s}{orb_none * 1000:10.1f}{orb_mask * 1000:10.1f}{bi_none * 1000:10.1f}"
            f"{bi_none / orb_none:8.2f}" + "".join(f"{c:>22s}" for c in cells) + f"{bi_ms:8.1f}{orb_ms:8.1f}"
        )
        summary[scene] = {
            "orbslam3_none_ate_m": orb_none,
            "orbslam3_mask_ate_m": orb_mask,
            "builtin_none_ate_m": bi_none,
            "builtin_over_orbslam3": bi_none / orb_none,
            "strategies": rhos,
            "builtin_none_track_ms": bi_ms,
            "orbslam3_none_track_ms": orb_ms,
        }
    (out / "fidelity.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    print("\nATE in mm; bi/orb: built-in none over ORB-SLAM3 none; rho: ATE improvement over built-in none,")
    print(
        "with rejection precision (p) and recall (r); ms: median tracking ms per frame (2 runs share 2 cores)"
    )


if __name__ == "__main__":
    main()
