"""Fit the mapping clock's cost model: how long each local-mapping step takes, by its size.

Usage: python benchmarks/mapping_costs.py --sequences PATH ... [--strategy none ...]

Tracks each sequence (a sequence folder, or a folder of them) with the built-in pipeline on
one pinned core, its mapper synchronous, and times every local-mapping step of every
keyframe together with the terms ``depotbench.slam.mapping_clock`` measures it by
(``new_points_terms``, ``fusion_terms``, ``iteration_terms`` times the adjustment's
iterations, ``culling_terms``), taken on the map as the step finds it. Then fits each
step's milliseconds to its terms by non-negative least squares (scipy's ``nnls``) and
prints the coefficients as ``MappingCosts`` holds them, each fit's R^2 and median relative
error, and every step's total time. Those defaults were fitted this way (the docstring of
``MappingCosts`` says on what); a machine several times faster or slower is modelled by
``mapper_time_scale``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

# depotbench first: numpy then runs the bench's code for the CPU (core/numerics.py)
import depotbench  # isort: skip  # noqa: E402, F401
import cv2  # noqa: E402
import numpy as np  # noqa: E402
from depotbench.detectors.config import DetectorConfig  # noqa: E402
from depotbench.eval.run.detections import detect_sequence  # noqa: E402
from depotbench.eval.trackers.builtin import BuiltinTracker  # noqa: E402
from depotbench.eval.trackers.frames import FrameSource  # noqa: E402
from depotbench.sim.sequence import Sequence  # noqa: E402
from depotbench.slam import kernels  # noqa: E402
from depotbench.slam import local_mapping as lm  # noqa: E402
from depotbench.slam.bundle import LevenbergMarquardt  # noqa: E402
from depotbench.slam.config import SlamConfig  # noqa: E402
from depotbench.slam.mapping_clock import (  # noqa: E402
    culling_terms,
    fusion_terms,
    iteration_terms,
    new_points_terms,
)
from depotbench.slam.rejection import STRATEGIES  # noqa: E402
from scipy.optimize import nnls  # noqa: E402
from tracking import _stored  # noqa: E402  (this folder's tracking benchmark)


def _timed_map_keyframe(samples: dict[str, list[tuple[np.ndarray, float]]]):
    """``LocalMapping.map_keyframe`` with each step timed beside its terms."""

    def timed(step: str, terms: np.ndarray, call) -> None:
        started = time.perf_counter()
        call()
        samples[step].append((terms, (time.perf_counter() - started) * 1e3))

    def map_keyframe(self: lm.LocalMapping, map_, keyframe_id: int) -> None:
        def new_points() -> None:
            map_.cull(keyframe_id, self.tc.recent_point_keyframes)
            self.create_new_map_points(map_, keyframe_id)

        timed("new_points", new_points_terms(map_, keyframe_id), new_points)
        targets = self.fusion_targets(map_, keyframe_id)
        timed("fusion", fusion_terms(map_, targets), lambda: self.search_in_neighbors(map_, keyframe_id))
        if len(map_.keyframes) > 2:
            window = self.local_window(map_, keyframe_id)  # built again inside: not timed here
            if window is not None:
                counted = {"iterations": 0}
                iterate = LevenbergMarquardt.iterate

                def counting(solver: LevenbergMarquardt) -> bool:
                    counted["iterations"] += 1
                    return iterate(solver)

                LevenbergMarquardt.iterate = counting
                try:
                    started = time.perf_counter()
                    self.local_bundle_adjustment(map_, keyframe_id)
                    elapsed = (time.perf_counter() - started) * 1e3
                finally:
                    LevenbergMarquardt.iterate = iterate
                terms = np.r_[1.0, counted["iterations"] * iteration_terms(window)]
                samples["adjustment"].append((terms, elapsed))
        timed("culling", culling_terms(map_, keyframe_id), lambda: self.keyframe_culling(map_, keyframe_id))

    return map_keyframe


def _fit(rows: list[tuple[np.ndarray, float]]) -> tuple[np.ndarray, float, float, float]:
    """Non-negative least-squares coefficients (a step takes no less time for being larger),
    R^2, median relative error and the total milliseconds."""
    x = np.array([terms for terms, _ in rows])
    y = np.array([ms for _, ms in rows])
    coefficients, _ = nnls(x, y)
    predicted = x @ coefficients
    r2 = 1 - float(np.sum((y - predicted) ** 2) / np.sum((y - y.mean()) ** 2))
    return coefficients, r2, float(np.median(np.abs(predicted - y) / y)), float(y.sum())


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument(
        "--sequences", type=Path, nargs="+", required=True, help="sequence folders or folders of them"
    )
    parser.add_argument(
        "--strategy", action="append", choices=STRATEGIES, help="a built-in strategy (default: none)"
    )
    args = parser.parse_args()
    sequences = _stored(args.sequences, parser)
    cv2.setNumThreads(1)
    kernels.warm_up()
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    samples: dict[str, list[tuple[np.ndarray, float]]] = {
        step: [] for step in ("new_points", "fusion", "adjustment", "culling")
    }
    lm.LocalMapping.map_keyframe = _timed_map_keyframe(samples)
    for path in sequences:
        seq = Sequence.open(path)
        frames = FrameSource(seq, detect_sequence(seq, DetectorConfig()).per_frame)
        for strategy in args.strategy or ["none"]:
            run = BuiltinTracker(SlamConfig(strategy=strategy)).run(frames, False)
            print(f"{path.name} {strategy}: {run.keyframes} keyframes", flush=True)
    header = f"{'step':12s} {'calls':>6s} {'total ms':>10s} {'R^2':>6s} {'median error':>13s}"
    print(f"{header}  coefficients (ms)")
    for step, rows in samples.items():
        if len(rows) < 4:
            print(f"{step:12s} {len(rows):6d}: too few calls to fit")
            continue
        coefficients, r2, error, total = _fit(rows)
        numbers = ", ".join(f"{c:.3g}" for c in coefficients)
        print(f"{step:12s} {len(rows):6d} {total:10.0f} {r2:6.2f} {error:12.0%}  ({numbers})")
    print(
        "adjustment: (set-up, per observation, per reduced-system block, per free keyframe cubed), "
        "each iteration's terms times its iterations"
    )


if __name__ == "__main__":
    main()
